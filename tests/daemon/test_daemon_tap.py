"""The tap process: stamps taken when the bytes were there, flushes exact, a hang-up seen."""

from __future__ import annotations

import contextlib
import os
import termios
import time
import tty
from collections.abc import Iterator

import numpy as np
import pytest

from baromap.messages import LaserScan, Message
from baromap.protocols import lms200
from daemon.clock import HostClock
from daemon.config import LaserConfig
from daemon.lms200 import Lms200Session
from daemon.tap import Tap


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
def tap(pty_pair: tuple[int, int]) -> Iterator[Tap]:
    tap = Tap(pty_pair[1], "test")
    yield tap
    tap.close()


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
