"""What the hardware tests share: a device session run for a while, and the figures of its stream.

The tests drive the daemon's own sessions (``baromapd.lms200``, ``.pioneer``, ``.barometer``)
against the port given on the command line: the code that records a run is the code under
test. A session's messages come with the instant their last byte was read; from those the
figures are taken over a window that starts once the device is up (computed by
``baromapd.bench``, as for the bench command):

- rate and gaps: messages per second, the longest silence and how many intervals exceed 1.5
  times the expected period;
- offset and jitter between device and host: the stamp the session gave each message (the
  device's clock for the barometer board, the line position for the laser and the base) minus
  the host's read instant, its median and its spread (95th minus 5th percentile). The offset
  includes the line time of the frame; the spread is what a recording's timestamps wander by.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from baromap.messages import DeviceHealth, DeviceState, Message
from baromapd.bench import StreamFigures, stream_figures
from baromapd.clock import HostClock
from baromapd.config import Retry
from baromapd.session import DeviceSession

#: Quick retries: a test waits seconds, not the daemon's half-minute backoff.
QUICK_RETRY = Retry(initial_s=0.2, max_s=1.0, silence_s=1.0, garbage_s=1.0)
#: How long a device may take from the port's opening to streaming (an Uno's bootloader, a
#: laser's baud search over four speeds).
UP_TIMEOUT_S = 20.0


@dataclass(frozen=True, slots=True)
class Received:
    message: Message
    read_ns: int  # host monotonic ns when its last byte was read


class Capture:
    """The ``publish`` of a session: keeps every message with its read instant."""

    def __init__(self) -> None:
        self.items: list[Received] = []
        self._lock = threading.Lock()

    def __call__(self, message: Message, read_ns: int) -> None:
        with self._lock:
            self.items.append(Received(message, read_ns))

    def of(self, kind: type, since_ns: int = 0, until_ns: int | None = None) -> list[Received]:
        with self._lock:
            items = list(self.items)
        end = until_ns if until_ns is not None else 1 << 62
        return [r for r in items if isinstance(r.message, kind) and since_ns <= r.read_ns <= end]


def session_kwargs(capture: Capture, clock: HostClock) -> dict[str, Any]:
    return {"clock": clock, "publish": capture}


def wait_until(what: Callable[[], bool], timeout_s: float, message: Callable[[], str]) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if what():
            return
        time.sleep(0.02)
    pytest.fail(f"timed out after {timeout_s:g} s: {message()}", pytrace=False)


def wait_up(session: DeviceSession, timeout_s: float = UP_TIMEOUT_S) -> None:
    wait_until(
        lambda: session.state is DeviceState.UP,
        timeout_s,
        lambda: f"{session.name} is not up: {session.state.value} ({session.detail})",
    )


@contextlib.contextmanager
def running(session: DeviceSession, up_timeout_s: float = UP_TIMEOUT_S) -> Iterator[DeviceSession]:
    """The session started and up; stopped (its shutdown sequence sent) on leaving."""
    session.start()
    try:
        wait_up(session, up_timeout_s)
        yield session
    finally:
        session.stop()


def describe(identity: dict[str, str]) -> str:
    """A device's identity on one report line."""
    return ", ".join(f"{key}={value}" for key, value in identity.items())


def bad_frames(health: DeviceHealth) -> dict[str, int]:
    return {k: v for k, v in health.counters.items() if k.startswith("bad_") and v}


def stream_for(
    session: DeviceSession, capture: Capture, kind: type, seconds: float, expected_hz: float
) -> tuple[StreamFigures, DeviceHealth, DeviceHealth]:
    """Let an up session stream ``seconds`` after a short settling; its figures and the health
    before and after the window (counters are compared across it)."""
    time.sleep(0.3)  # the first frames after a handshake may still be settling the line
    before = session.health(0)
    start = time.monotonic_ns()
    time.sleep(seconds)
    end = time.monotonic_ns()
    after = session.health(0)
    received = capture.of(kind)
    stamps = [getattr(r.message, "t_ns", 0) for r in received]
    reads = [r.read_ns for r in received]
    figures = stream_figures(stamps, reads, session.clock, (start, end), expected_hz)
    return figures, before, after


def new_bad_frames(before: DeviceHealth, after: DeviceHealth) -> dict[str, int]:
    """Bad frames counted between two health snapshots, by reason."""
    grown = {k: v - before.counters.get(k, 0) for k, v in bad_frames(after).items()}
    return {k: v for k, v in grown.items() if v}


def assert_stream(figures: StreamFigures, before: DeviceHealth, after: DeviceHealth) -> None:
    """Zero framing errors, the expected rate within 15 %, no pause, no reconnection."""
    bad = new_bad_frames(before, after)
    assert not bad, f"framing errors while streaming: {bad}; {figures.line()}"
    assert after.state is DeviceState.UP, (
        f"not streaming at the end: {after.device} {after.state.value}: {after.detail}"
    )
    assert after.counters.get("connects") == before.counters.get("connects"), "it reconnected"
    low, high = 0.85 * figures.expected_hz, 1.15 * figures.expected_hz
    assert low <= figures.rate_hz <= high, f"rate off: {figures.line()}"
    # A pause the host's scheduler makes is not the device's: on a loaded test machine reads
    # stall for half a second. A device that stops for longer, or loses what a rate shows, fails.
    pause_s = max(3.0 / figures.expected_hz, 1.0)
    assert figures.longest_gap_s < pause_s, f"stream paused: {figures.line()}"
