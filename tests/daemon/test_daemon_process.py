"""``baromapd`` as a process: systemd's notify protocol, SIGTERM, SIGKILL.

A fake ``NOTIFY_SOCKET`` (a datagram socket of the test) receives what systemd would.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from daemon_rig import Rig, config_text

from baromap import messages
from baromap.recording import read_messages, topics


def _start(rig: Rig, tmp_path: Path, env: dict[str, str]) -> subprocess.Popen[bytes]:
    config = tmp_path / "baromapd.toml"
    config.write_text(config_text(rig))
    return subprocess.Popen(
        [sys.executable, "-m", "baromapd.main", "--config", str(config), "--log-format", "json"],
        env={**os.environ, **env},
        stdout=subprocess.DEVNULL,
        stderr=(tmp_path / "daemon.log").open("wb"),
    )


def _files(rig: Rig) -> list[Path]:
    return sorted((rig.directory / "rec").glob("*.mcap"))


def _wait_for_file(rig: Rig, proc: subprocess.Popen[bytes], timeout: float = 15) -> Path:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, "baromapd exited early"
        if _files(rig):
            return _files(rig)[0]
        time.sleep(0.1)
    pytest.fail("no recording appeared")


def test_notify_watchdog_and_sigterm_finish_the_file(rig: Rig, tmp_path: Path) -> None:
    address = str(tmp_path / "notify.sock")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind(address)
        sock.settimeout(0.2)
        proc = _start(rig, tmp_path, {"NOTIFY_SOCKET": address, "WATCHDOG_USEC": "2000000"})
        received: list[str] = []
        try:
            deadline = time.monotonic() + 25
            while time.monotonic() < deadline:
                with contextlib.suppress(TimeoutError):
                    received.append(sock.recv(4096).decode())
                statuses = [m for m in received if "STATUS=" in m]
                if (
                    statuses
                    and all(f"{d} up" in statuses[-1] for d in ("laser", "base", "barometer"))
                    and sum("WATCHDOG=1" in m for m in received) >= 3
                ):
                    break
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(20) == 0
            while True:
                try:
                    received.append(sock.recv(4096).decode())
                except TimeoutError:
                    break
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    ready = [i for i, m in enumerate(received) if "READY=1" in m]
    assert len(ready) == 1
    assert ready[0] == 0, "READY=1 comes first, once the sessions run"
    assert sum("WATCHDOG=1" in m for m in received) >= 3
    statuses = [m for m in received if "STATUS=" in m]
    assert any(all(f"{d} up" in s for d in ("laser", "base", "barometer")) for s in statuses)
    # STOPPING=1 once, as the last word: after READY=1 and every ping, before the file closes
    stopping = [i for i, m in enumerate(received) if "STOPPING=1" in m]
    assert stopping == [len(received) - 1], received[-3:]

    # SIGTERM finished the file: it has its summary, so it is read without recovery.
    from mcap.reader import make_reader

    (path,) = _files(rig)
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count > 0


def test_sigkill_leaves_all_but_the_last_second_readable(rig: Rig, tmp_path: Path) -> None:
    proc = _start(rig, tmp_path, {})
    try:
        path = _wait_for_file(rig, proc)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:  # until the barometer has streamed for a while
            time.sleep(0.5)
            baro = [r for r in read_messages(path, [topics.BARO])]
            if len(baro) > 150:
                break
        time.sleep(2.0)
        killed_ns = time.time_ns()
        proc.kill()
        proc.wait()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    samples = [r.message for r in read_messages(path, [topics.BARO])]
    assert isinstance(samples[-1], messages.PressureSample)
    # Flushed and fsynced every second: at most about the last second (plus slack) is lost.
    assert killed_ns - samples[-1].t_ns < 2.0e9
    seqs = [s.seq for s in samples]
    assert all((b - a) % 65536 == 1 for a, b in itertools.pairwise(seqs))
