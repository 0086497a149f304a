"""The tap process: stamps taken when the bytes were there, flushes exact, a hang-up seen.

Every test of the process runs both implementations (``daemon/baromapd/tap.py`` and
``daemon/tap.c``, the ``tap_program`` fixture), the wire format checked byte for byte on each.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import os
import re
import shutil
import signal
import subprocess
import sys
import termios
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from structlog.testing import capture_logs

from baromap.messages import LaserScan, Message
from baromap.protocols import lms200
from baromapd.clock import HostClock
from baromapd.config import LaserConfig
from baromapd.lms200 import Lms200Session
from baromapd.tap import EXPECT, FLUSH_REQUEST, RECORD, Tap, default_program

UNIT = Path(__file__).resolve().parents[2] / "systemd" / "baromapd.service"


@pytest.fixture
def pty_pair() -> Iterator[tuple[int, int]]:
    """(device end, port end): what the device writes on one the tap reads from the other."""
    device, port = os.openpty()
    tty.setraw(port)
    yield device, port
    for fd in (device, port):
        with contextlib.suppress(OSError):
            os.close(fd)


@pytest.fixture
def tap(pty_pair: tuple[int, int], tap_program: list[str]) -> Iterator[Tap]:
    tap = Tap(pty_pair[1], "test", tap_program)
    yield tap
    tap.close()


@pytest.fixture
def raw_tap(pty_pair: tuple[int, int], tap_program: list[str]) -> Iterator[subprocess.Popen[bytes]]:
    """The tap process itself, its pipes in the test's hands."""
    proc = subprocess.Popen(
        [*tap_program, str(pty_pair[1]), "raw"],
        pass_fds=(pty_pair[1],),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        bufsize=0,
    )
    yield proc
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    for stream in (proc.stdin, proc.stdout, proc.stderr):
        if stream is not None:
            stream.close()


def _read_exactly(proc: subprocess.Popen[bytes], size: int) -> bytes:
    assert proc.stdout is not None
    data = b""
    while len(data) < size:
        more = proc.stdout.read(size - len(data))
        assert more, f"the tap's pipe ended after {data!r}"
        data += more
    return data


def _records(proc: subprocess.Popen[bytes], size: int) -> list[tuple[int, bytes]]:
    """Records from the tap's pipe until ``size`` bytes of data came: (stamp, bytes) each."""
    out: list[tuple[int, bytes]] = []
    while sum(len(d) for _, d in out) < size:
        stamp, length = RECORD.unpack(_read_exactly(proc, RECORD.size))
        out.append((stamp, _read_exactly(proc, length)))
    return out


def _read_all(tap: Tap, size: int, timeout_s: float = 5.0) -> list[tuple[bytes, int]]:
    records: list[tuple[bytes, int]] = []
    deadline = time.monotonic() + timeout_s
    while sum(len(d) for d, _ in records) < size and time.monotonic() < deadline:
        record = tap.read(50)
        if record is not None:
            records.append(record)
    return records


def test_every_read_is_stamped_between_the_write_and_its_arrival(
    pty_pair: tuple[int, int], tap: Tap
) -> None:
    tap.expect(40)
    before = time.monotonic_ns()
    os.write(pty_pair[0], bytes(range(40)))
    records = _read_all(tap, 40)
    after = time.monotonic_ns()
    assert b"".join(d for d, _ in records) == bytes(range(40))
    assert all(before <= stamp <= after for _, stamp in records)


def test_a_line_that_never_goes_quiet_is_handed_over_though_no_frame_size_was_said(
    pty_pair: tuple[int, int], tap: Tap
) -> None:
    """A laser just switched to streaming at 38400 baud fills its line: scans follow each
    other closer than the quiet that ends a hand-over, and the frame size is not known until
    a first scan is decoded. The tap must hand bytes over all the same, or the daemon hears a
    silence and restarts a sensor that streams."""
    device = pty_pair[0]
    sent = bytearray()
    first: int | None = None
    end = time.monotonic() + 1.0
    while time.monotonic() < end:  # 8 bytes every 2 ms: 38400 baud, never 4 ms quiet
        chunk = bytes([len(sent) % 251] * 8)
        os.write(device, chunk)
        sent += chunk
        if first is None and tap.read(0) is not None:
            first = len(sent)
        time.sleep(0.002)
    assert first is not None, f"nothing handed over while {len(sent)} bytes streamed for 1 s"
    # 20 ms is ten writes; a loaded machine may hold the tap up for a few hundred ms
    assert first <= len(sent) // 2, f"the first hand-over came after {first} of {len(sent)} bytes"


def test_a_flush_drops_everything_read_before_it(pty_pair: tuple[int, int], tap: Tap) -> None:
    device, port = pty_pair
    os.write(device, b"old bytes at the wrong speed")
    time.sleep(0.05)  # wherever they are now: the port, the tap, the pipe
    termios.tcflush(port, termios.TCIFLUSH)  # what the session does first
    tap.discard()
    os.write(device, b"new")
    records = _read_all(tap, 3)
    assert b"".join(d for d, _ in records) == b"new"


def test_a_port_that_hangs_up_ends_the_tap_and_says_so(pty_pair: tuple[int, int], tap: Tap) -> None:
    os.close(pty_pair[0])  # the adapter is gone
    with pytest.raises(OSError):
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            tap.read(50)


def test_the_wire_format_byte_for_byte(
    pty_pair: tuple[int, int], raw_tap: subprocess.Popen[bytes]
) -> None:
    """Records of a little-endian int64 monotonic stamp and uint32 length, the bytes after;
    a flush answered by stamp -1, length 0, and nothing else on the pipe; stdin closed: exit 0
    with nothing on stderr."""
    assert raw_tap.stdin is not None and raw_tap.stdout is not None
    raw_tap.stdin.write(EXPECT.pack(b"E", 8))  # a frame's worth forwards at once
    data = bytes(range(1, 21))
    before = time.monotonic_ns()
    os.write(pty_pair[0], data)
    records = _records(raw_tap, len(data))
    after = time.monotonic_ns()
    assert b"".join(d for _, d in records) == data
    assert all(before <= stamp <= after for stamp, _ in records)
    raw_tap.stdin.write(FLUSH_REQUEST)
    assert _read_exactly(raw_tap, RECORD.size) == b"\xff" * 8 + b"\x00" * 4
    raw_tap.stdin.close()
    assert raw_tap.wait(5) == 0
    assert raw_tap.stdout.read() == b""  # the rest of the pipe: nothing after the answer
    assert raw_tap.stderr is not None and raw_tap.stderr.read() == b""


def test_requests_split_across_writes_are_put_together(
    pty_pair: tuple[int, int], raw_tap: subprocess.Popen[bytes]
) -> None:
    """A frame size that arrives a byte at a time is still one request, and the flush after
    it is answered once."""
    assert raw_tap.stdin is not None
    for byte in EXPECT.pack(b"E", 4) + FLUSH_REQUEST:
        raw_tap.stdin.write(bytes([byte]))
        time.sleep(0.01)  # separate reads of the tap's stdin, most likely
    assert _read_exactly(raw_tap, RECORD.size) == RECORD.pack(-1, 0)
    os.write(pty_pair[0], b"abcd")
    assert b"".join(d for _, d in _records(raw_tap, 4)) == b"abcd"


def test_a_port_that_hangs_up_ends_the_tap_with_exit_0(
    pty_pair: tuple[int, int], raw_tap: subprocess.Popen[bytes]
) -> None:
    os.close(pty_pair[0])  # the pty's other end: the port hangs up (a read of nothing)
    assert raw_tap.wait(5) == 0
    assert raw_tap.stdout is not None and raw_tap.stdout.read() == b""


def test_the_tap_is_named_after_its_device_in_the_os(
    raw_tap: subprocess.Popen[bytes],
) -> None:
    assert raw_tap.stdin is not None
    raw_tap.stdin.write(FLUSH_REQUEST)  # answered: the tap is past its start-up
    assert _read_exactly(raw_tap, RECORD.size) == RECORD.pack(-1, 0)
    comm = Path(f"/proc/{raw_tap.pid}/comm").read_text().strip()
    assert comm == "baromapd-tap-raw"[:15]


def test_a_bad_command_line_is_exit_1_and_nothing_on_the_pipe(tap_program: list[str]) -> None:
    result = subprocess.run([*tap_program, "not-a-descriptor"], capture_output=True, check=False)
    assert result.returncode == 1
    assert result.stdout == b""
    assert result.stderr != b""


_PR_SET_CHILD_SUBREAPER = 36


@contextlib.contextmanager
def _subreaper() -> Iterator[None]:
    """Orphans of this process's children become its children (not init's, which in a
    container may never reap them), so a test can wait for them."""
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) != 0:
        pytest.skip("cannot become a child subreaper here")
    try:
        yield
    finally:
        libc.prctl(_PR_SET_CHILD_SUBREAPER, 0, 0, 0, 0)


def _reap(pid: int, timeout_s: float) -> int | None:
    """The wait status of ``pid`` (a child, or an orphan of one), None while it still runs."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return status
        time.sleep(0.02)
    return None


def test_the_tap_dies_with_its_daemon_though_its_pipes_stay_open(tap_program: list[str]) -> None:
    """The daemon killed (SIGKILL: it closes nothing): the kernel kills the tap with it
    (``PR_SET_PDEATHSIG``), though both its pipes are still open at their other ends (held
    here). When a daemon dies its ends close, and the tap's stdin closing ends it too."""
    control_r, control_w = os.pipe()
    out_r, out_w = os.pipe()
    device, port = os.openpty()
    daemon = (
        "import os, subprocess, sys\n"
        "c, o, p = (int(a) for a in sys.argv[1:4])\n"
        "t = subprocess.Popen(sys.argv[4:] + [str(p), 'x'], pass_fds=(p,), stdin=c, stdout=o)\n"
        "print(t.pid, flush=True)\n"
        "sys.stdin.readline()\n"
        "os.kill(os.getpid(), 9)\n"
    )
    with _subreaper():
        parent = subprocess.Popen(
            [sys.executable, "-c", daemon, str(control_r), str(out_w), str(port), *tap_program],
            pass_fds=(control_r, out_w, port),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,  # the tap would hold a captured stderr open
            text=True,
        )
        pid = None
        try:
            assert parent.stdout is not None and parent.stdin is not None
            pid = int(parent.stdout.readline())
            os.write(control_w, FLUSH_REQUEST)  # answered: the tap is past its start-up
            assert os.read(out_r, RECORD.size) == RECORD.pack(-1, 0)
            parent.stdin.write("die\n")
            parent.stdin.flush()
            assert parent.wait(5) == -signal.SIGKILL
            status = _reap(pid, 5.0)
            assert status is not None, "the tap outlived its daemon"
            pid = None  # reaped
            # killed by the kernel, not ended by its once-a-second look at its parent
            assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL
        finally:
            parent.kill()
            parent.communicate()
            for fd in (control_r, control_w, out_r, out_w, device, port):
                os.close(fd)  # a tap still running sees its stdin close and ends
            if pid is not None:
                _reap(pid, 5.0)


@functools.cache
def _syscall_group(name: str) -> frozenset[str]:
    """A systemd system call group's calls, its groups in it expanded."""
    text = subprocess.run(
        ["systemd-analyze", "syscall-filter", name], capture_output=True, text=True, check=True
    ).stdout
    calls: set[str] = set()
    for line in text.splitlines()[1:]:  # the first names the group
        item = line.strip()
        if item and not item.startswith("#"):
            calls |= _syscall_group(item) if item.startswith("@") else {item}
    return frozenset(calls)


def _unit_allows() -> set[str]:
    """The calls the unit's ``SystemCallFilter=`` lines let through, read in order as systemd
    does: the first allows a list, ``~`` takes away, a later plain one adds."""
    allowed: set[str] = set()
    for line in UNIT.read_text().splitlines():
        if not line.startswith("SystemCallFilter="):
            continue
        value = line.partition("=")[2]
        named: set[str] = set()
        for item in value.lstrip("~").split():
            named |= _syscall_group(item) if item.startswith("@") else {item}
        allowed = allowed - named if value.startswith("~") else allowed | named
    return allowed


@pytest.mark.skipif(
    shutil.which("strace") is None or shutil.which("systemd-analyze") is None,
    reason="needs strace and systemd-analyze",
)
def test_the_taps_system_calls_pass_the_units_filter(
    tmp_path: Path, pty_pair: tuple[int, int], tap_program: list[str]
) -> None:
    """Under the unit a call outside ``SystemCallFilter=`` fails with EPERM: every call the tap
    makes (start-up, realtime, reads, requests, exit) must be let through."""
    probe = subprocess.run(
        ["strace", "-qq", "-o", os.devnull, "true"], capture_output=True, check=False
    )
    if probe.returncode != 0:
        pytest.skip(f"strace cannot trace here: {probe.stderr.decode(errors='replace')[:200]}")
    trace = tmp_path / "trace"
    proc = subprocess.Popen(
        ["strace", "-f", "-qq", "-o", str(trace), *tap_program, str(pty_pair[1]), "laser"],
        pass_fds=(pty_pair[1],),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        bufsize=0,
    )
    assert proc.stdin is not None and proc.stdout is not None
    try:
        proc.stdin.write(EXPECT.pack(b"E", 8))
        proc.stdin.write(FLUSH_REQUEST)
        assert _read_exactly(proc, RECORD.size) == RECORD.pack(-1, 0)
        os.write(pty_pair[0], bytes(20))
        _records(proc, 20)
        proc.stdin.close()
        code = proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
    assert code == 0
    calls = {m.group(1) for m in re.finditer(r"^\d+\s+(\w+)\(", trace.read_text(), re.M)}
    assert {"read", "write", "poll", "prctl"} <= calls  # the trace saw the tap's work
    assert calls - _unit_allows() == set()


def test_the_c_tap_runs_when_built_beside_the_interpreter_and_the_log_says_which(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(sys, "executable", str(tmp_path / "python"))
    choose = default_program.__wrapped__  # not the process's cached choice
    with capture_logs() as logs:
        assert choose() == (str(tmp_path / "python"), "-m", "baromapd.tap")
        native = tmp_path / "baromapd-tap"
        native.write_bytes(b"")
        assert choose() == (str(tmp_path / "python"), "-m", "baromapd.tap")  # not executable
        native.chmod(0o755)
        assert choose() == (str(native),)
    assert [e["implementation"] for e in logs] == ["python", "python", "c"]


def _laser_session(published: list[tuple[Message, int]]) -> Lms200Session:
    session = Lms200Session(
        LaserConfig(port="unused", baud=500_000),
        clock=HostClock(wall_ns=lambda: 0, mono_ns=lambda: 0),
        publish=lambda message, read_ns: published.append((message, read_ns)),
        resolve=lambda spec: spec,
    )
    session.streaming = True
    return session


def _scan_records(scans: int, packet: int) -> list[tuple[bytes, int]]:
    """A line of scans cut into packets as a tap reads them, each stamped when a 500 kbaud
    line would have delivered its last byte, with the line idle for 6 ms between scans."""
    rng = np.random.default_rng(7)
    records: list[tuple[bytes, int]] = []
    t_ns = 1_000_000_000
    for _ in range(scans):
        telegram = lms200.encode_scan(rng.integers(100, 8000, 181, dtype=np.uint16))
        for start in range(0, len(telegram), packet):
            piece = telegram[start : start + packet]
            t_ns += len(piece) * 20_000  # 20 us a byte at 500 kbaud
            records.append((piece, t_ns + 30_000))  # read 30 us after the packet came
        t_ns += 6_000_000
    return records


def test_a_taps_records_decoded_together_give_the_stamps_of_one_at_a_time() -> None:
    """``Lms200Session.handle_reads`` (a pipe read's records in one decoder call) publishes
    the same scans with the same stamps as one ``handle`` per record, backlog included (more
    records at once than ``LinePosition`` remembers reads)."""
    records = _scan_records(scans=60, packet=100)  # 4 records a scan, 240 in all
    one_at_a_time: list[tuple[Message, int]] = []
    single = _laser_session(one_at_a_time)
    for data, read_ns in records:
        single.handle(data, read_ns)
    together: list[tuple[Message, int]] = []
    batched = _laser_session(together)
    batched.handle_reads(records[:4])  # one scan: what a tap writes at once
    batched.handle_reads(records[4:])  # a backlog of 59 scans
    assert len(one_at_a_time) == len(together) == 60
    assert all(isinstance(m, LaserScan) for m, _ in together)
    assert [m.t_ns for m, _ in together] == [m.t_ns for m, _ in one_at_a_time]
    assert [m for m, _ in together] == [m for m, _ in one_at_a_time]
