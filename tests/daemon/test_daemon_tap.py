"""The tap process: stamps taken when the bytes were there, flushes exact, a hang-up seen."""

from __future__ import annotations

import contextlib
import os
import termios
import time
import tty
from collections.abc import Iterator

import pytest

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
