"""Clocks: one Unix mapping of the monotonic clock; the barometer's clock fitted to it."""

from __future__ import annotations

import numpy as np
import pytest

from baromap.messages import LaserScan
from baromap.protocols import lms200
from baromapd.clock import DeviceClockFit, HostClock, LinePosition, transmission_ns
from baromapd.config import parse_config
from baromapd.lms200 import Lms200Session
from baromapd.session import READ_PAUSE_OVERSHOOT_NS


def test_a_wall_clock_step_after_start_changes_nothing() -> None:
    wall = [1_700_000_000_000_000_000]
    mono = [5_000_000_000]
    clock = HostClock(wall_ns=lambda: wall[0], mono_ns=lambda: mono[0])
    before = clock.unix_ns(mono[0] + 1_000_000_000)
    wall[0] -= 3600 * 10**9  # someone sets the date back an hour
    assert clock.unix_ns(mono[0] + 1_000_000_000) == before
    assert before == 1_700_000_001_000_000_000


def test_line_time_at_8n1() -> None:
    assert transmission_ns(372, 500000) == 7_440_000
    assert transmission_ns(12, 115200) == 1_041_666


def _receive_times(
    rng: np.random.Generator, n: int, rate_hz: float, skew_ppm: float, start_us: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Device stamps (u32, wrapping), true host times and receive times (delays >= 0)."""
    true_ns = 1_000_000_000 + np.arange(n) * round(1e9 / rate_hz)
    device_us = start_us + np.round((true_ns - true_ns[0]) / 1000 * (1 + skew_ppm * 1e-6))
    delays = rng.exponential(1.5e6, n) + rng.uniform(0, 2e6, n)  # USB and scheduling, 0..10 ms
    return device_us.astype(np.int64) % 2**32, true_ns, true_ns + delays.astype(np.int64)


def test_the_fit_recovers_true_times_through_jitter_skew_and_a_wrap() -> None:
    rng = np.random.default_rng(7)
    # 5000 ppm: a ceramic resonator's worst case; starts 20 s before the u32 wrap.
    raw, true_ns, received = _receive_times(rng, 50 * 120, 50, 5000, 2**32 - 20_000_000)
    fit = DeviceClockFit()
    estimates = np.array([fit.update(int(r), int(h)) for r, h in zip(raw, received, strict=True)])
    errors = np.abs(estimates - true_ns)[50 * 30 :] / 1e6  # after 30 s of warm-up
    naive = (received - true_ns)[50 * 30 :] / 1e6
    assert np.percentile(errors, 99) < 1.0  # ms; the receive times themselves are ~3 ms late
    assert np.percentile(naive, 50) > 2.0
    assert fit.resets == 0  # the wrap was unwrapped, not taken for a reset
    assert abs(fit.skew_ppm - 5000 / 1.005) < 50  # against the host: 4975 ppm
    assert np.all(estimates <= received)  # never later than the frame arrived
    assert np.all(np.diff(estimates) > 0)


def test_a_device_reset_restarts_the_fit() -> None:
    rng = np.random.default_rng(1)
    raw, true_ns, received = _receive_times(rng, 1000, 50, 100, 40_000_000)
    fit = DeviceClockFit()
    for r, h in zip(raw[:500], received[:500], strict=True):
        fit.update(int(r), int(h))
    # The board resets: its clock starts again near zero while host time goes on.
    after = [
        fit.update(int(r - raw[500] + 1000), int(h))
        for r, h in zip(raw[500:], received[500:], strict=True)
    ]
    assert fit.resets == 1
    assert abs(after[-1] - true_ns[-1]) < 3_000_000


def test_a_late_read_does_not_make_a_frame_late() -> None:
    """A 372-byte telegram at 500 kbaud (7.44 ms) from t=0: 100 bytes read promptly at 2 ms,
    the rest read 6 ms late at 13.44 ms together with 50 bytes of the next telegram."""
    line = LinePosition()
    line.chunk(100, 2_000_000)
    line.chunk(272 + 50, 13_440_000)
    end = line.end_ns(372, 500_000)
    # read time minus the 50 bytes after it says 12.44 ms; the earlier read bounds it tighter
    assert end == 2_000_000 + transmission_ns(272, 500_000) == 7_440_000


def test_one_prompt_read_anywhere_in_a_frame_stamps_it() -> None:
    """A 372-byte telegram at 500 kbaud from t=0 in four reads: the first came 1.2 ms late (the
    GIL held elsewhere), the second was prompt (its 200th byte arrived at 4 ms), the third and
    the last came late. The end is what the prompt read says, whichever read it was."""
    line = LinePosition()
    line.chunk(40, 2_000_000)  # late: byte 40 arrived at 0.8 ms
    line.chunk(160, 4_000_000)  # prompt: byte 200 arrived at 4 ms
    line.chunk(100, 7_500_000)  # late: byte 300 arrived at 6 ms
    line.chunk(72 + 30, 12_000_000)  # late, with 30 bytes of what followed
    assert line.end_ns(372, 500_000) == 4_000_000 + transmission_ns(172, 500_000) == 7_440_000
    # The next frame starts in the last read: only that read and later ones can bound it.
    line.chunk(342, 13_000_000)
    assert line.end_ns(372, 500_000) == 13_000_000


def test_a_read_before_a_frame_began_does_not_bound_it() -> None:
    """The line may idle between frames: a read that ended where a frame starts says nothing."""
    line = LinePosition()
    line.chunk(10, 1_000_000)
    assert line.end_ns(10, 500_000) == 1_000_000
    line.chunk(10, 9_000_000)  # the next frame, 8 ms later, in one read
    assert line.end_ns(10, 500_000) == 9_000_000


def test_a_frame_within_one_read_ends_before_the_bytes_after_it() -> None:
    line = LinePosition()
    line.chunk(30, 5_000_000)
    line.skip(10)  # a discarded run, then a 20-byte frame
    assert line.end_ns(20, 115_200) == 5_000_000
    line.chunk(40, 9_000_000)
    assert line.end_ns(22, 115_200) == 9_000_000 - transmission_ns(18, 115_200)


def test_a_laser_reader_sleeps_through_the_rest_of_a_scan_but_stamps_it_as_before() -> None:
    """A scan in progress: the reader may sleep for the rest of it (less the margin that keeps
    the completing read a prompt one); the scan's stamp is what the reads say either way."""
    scans: list[LaserScan] = []
    config = parse_config('robot = "r"\n[laser]\nport = "loop://"\nbaud = 500000\n').laser
    assert config is not None
    session = Lms200Session(config, clock=HostClock(), publish=lambda m, t: scans.append(m))
    session.streaming = True
    telegram = lms200.encode_scan(np.full(181, 1000, dtype=np.uint16))
    size = len(telegram)
    assert session.read_pause_ns() == 0  # nothing in progress
    session.handle(telegram, 10_000_000)  # a whole scan in one read: its size is known
    assert len(scans) == 1 and session.read_pause_ns() == 0
    session.handle(telegram[:100], 20_000_000)  # the next one begins
    rest_ns = transmission_ns(size - 100, 500_000)
    assert session.read_pause_ns() == rest_ns
    assert rest_ns > READ_PAUSE_OVERSHOOT_NS  # worth a sleep at 500 kbaud
    session.handle(telegram[100:], 20_000_000 + rest_ns + 2_000_000)  # read 2 ms late
    assert len(scans) == 2 and session.read_pause_ns() == 0
    start = session.clock.unix_ns(20_000_000 + rest_ns - transmission_ns(size, 500_000))
    assert scans[1].t_ns == start  # bounded by the prompt read at its start, not the late one


@pytest.mark.parametrize("speed", [1.0, 6.0])
def test_stamps_never_go_back_when_the_fit_learns_a_lower_envelope(speed: float) -> None:
    """The first frames after the port opens sat in its buffer, some reads come late by more
    than a frame's period (so a frame can seem sent after the next one), and the fit's line
    moves at each new bucket while it is young (most of all when the device's clock runs at
    another rate, as the demo's twins do at 6x): the stamps must still increase (a
    recording's time order and the live detector's sample order depend on it)."""
    rng = np.random.default_rng(3)
    n = 1500
    period_ns = int(20_000_000 / speed)  # 50 Hz of device time
    device_us = np.arange(n) * 20_000 + 5_000_000
    true_ns = np.arange(n) * period_ns + 7_000_000_000
    late = rng.exponential(0.3e6, size=n)
    late[:12] += np.linspace(40e6, 0.0, 12)  # a backlog read at once when the port opened
    late[rng.random(n) < 0.02] += 5e6  # a read late by more than a period at 6x
    sent = (true_ns + late).astype(np.int64)
    fit = DeviceClockFit()
    stamps = np.array([fit.update(int(d), int(t)) for d, t in zip(device_us, sent, strict=True)])
    assert np.all(np.diff(stamps) > 0)
    # never later than the latest send time seen yet (+1 ns a frame at most)
    assert np.all(stamps <= np.maximum.accumulate(sent) + np.arange(n))
    assert np.percentile(np.abs(stamps - true_ns)[500:], 99) < 3_000_000
