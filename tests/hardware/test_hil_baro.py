"""The barometer board on a real port: ``pytest -m hardware --baro-port PATH``.

Through the daemon's session: IDENTIFY/HELLO, rate and oversampling set, samples at the set
rate with no framing error and no lost sequence number, the board's STATUS counters, its clock
against the host's; the firmware's version and its watchdog; a second session after the first
closed the port (an Uno resets when its port opens).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable

import pytest
import serial
from hil import (
    QUICK_RETRY,
    Capture,
    assert_stream,
    describe,
    running,
    session_kwargs,
    stream_for,
    wait_until,
)

from baromap.messages import PressureSample
from baromap.protocols import baro
from baromap.protocols.framing import BadFrame
from baromapd.barometer import BarometerSession
from baromapd.clock import HostClock
from baromapd.config import BarometerConfig

pytestmark = pytest.mark.hardware

RATE_HZ = 50
#: The firmware this host speaks to: protocol 1, release 1.x.
FIRMWARE_MAJOR = 1
#: A board's clock against the host's: an Uno's ceramic resonator is within 0.5 %; a board
#: built for another clock (8 MHz firmware on a 16 MHz board) is 50 % off.
CLOCK_SKEW_MAX_PPM = 10_000
#: The test-build command that hangs the firmware's loop (PROTOCOL.md section 4).
HANG_COMMAND = 0xF0


def _session(port: str, capture: Capture, clock: HostClock) -> BarometerSession:
    config = BarometerConfig(port, rate_hz=RATE_HZ, retry=QUICK_RETRY)
    return BarometerSession(config, **session_kwargs(capture, clock))


def test_board_identifies_configures_and_streams_at_its_rate(
    baro_port: str, hil_seconds: float, host_clock: HostClock, report: Callable[[str, str], None]
) -> None:
    capture = Capture()
    session = _session(baro_port, capture, host_clock)
    with running(session):
        figures, before, after = stream_for(session, capture, PressureSample, hil_seconds, RATE_HZ)
        skew_ppm = session.fit.skew_ppm
    identity = session.identity
    counters = after.counters
    report("barometer", describe(identity))
    report("barometer", figures.line())
    report(
        "barometer",
        "board counters: "
        + ", ".join(f"{k}={v}" for k, v in sorted(counters.items()) if k.startswith("board_")),
    )
    report("barometer", f"board clock against the host's: {skew_ppm:+.0f} ppm")
    assert_stream(figures, before, after)
    assert int(identity["firmware_version"].split(".")[0]) == FIRMWARE_MAJOR
    assert identity["sensor"] != "NONE", "the board found no sensor"
    lost = counters.get("samples_lost", 0) - before.counters.get("samples_lost", 0)
    assert lost == 0, f"{lost} sample sequence numbers missing"
    assert counters.get("board_sensor_state") == baro.SensorState.RUNNING
    for key in ("board_frames_dropped", "board_i2c_errors", "board_rx_crc_errors"):
        assert counters.get(key, 0) == before.counters.get(key, 0), f"{key} grew"
    assert abs(skew_ppm) < CLOCK_SKEW_MAX_PPM


def _frame(frame_type: int, seq: int) -> bytes:
    raw = baro.HEADER.pack(baro.PROTOCOL_VERSION, frame_type, seq, 0)
    return b"\x00" + baro.cobs_encode(raw + baro.CRC.pack(baro.crc16(raw))) + b"\x00"


def test_firmware_reports_status_every_second_and_its_watchdog_works(
    baro_port: str, hil_seconds: float, report: Callable[[str, str], None]
) -> None:
    """STATUS once a second of board time with counters that only grow, no reset while it
    runs; the hang command of a test build (``make -C firmware hooks``) is answered by the
    watchdog's reset, the shipped firmware refuses it as an unknown command."""
    decoder = baro.Decoder()
    frames: list[tuple[float, baro.Frame]] = []
    bad: list[BadFrame] = []

    def pump(port: serial.Serial, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for item in decoder.feed(port.read(max(1, port.in_waiting))):
                if isinstance(item, BadFrame):
                    bad.append(item)
                else:
                    frames.append((time.monotonic(), item))

    with serial.serial_for_url(baro_port, baudrate=115200, timeout=0.05) as port:
        port.write(_frame(baro.FrameType.IDENTIFY, 1))
        wait_until(
            lambda: pump(port, 0.1) or any(isinstance(f, baro.HelloFrame) for _, f in frames),
            5.0,
            lambda: f"no HELLO after IDENTIFY ({len(frames)} frames, {len(bad)} bad)",
        )
        hello = next(f for _, f in frames if isinstance(f, baro.HelloFrame))
        streamed_from = len(frames)
        pump(port, max(hil_seconds, 2.5))
        streamed = [f for _, f in frames[streamed_from:]]
        sent = time.monotonic()
        port.write(_frame(HANG_COMMAND, 2))
        pump(port, 3.0)
        answers = [(t, f) for t, f in frames if t >= sent]
    cause = baro.ResetCause(hello.reset_cause)
    report("barometer", f"firmware {hello.firmware_version}, reset cause {cause!r}")
    statuses = [f for f in streamed if isinstance(f, baro.StatusFrame)]
    assert len(statuses) >= 2, f"{len(statuses)} STATUS frames in {hil_seconds:g} s"
    spacing = [baro.time_delta_us(a.time_us, b.time_us) for a, b in itertools.pairwise(statuses)]
    assert all(0.98e6 <= d <= 1.02e6 for d in spacing), f"STATUS spacing {spacing} us"
    for a, b in itertools.pairwise(statuses):
        assert b.frames_sent > a.frames_sent and b.rx_bytes >= a.rx_bytes
    assert not [f for f in streamed if isinstance(f, baro.HelloFrame) and f.seq == 0], (
        "the board reset while streaming"
    )
    acks = [f for _, f in answers if isinstance(f, baro.AckFrame) and f.command == HANG_COMMAND]
    resets = [f for _, f in answers if isinstance(f, baro.HelloFrame) and f.seq == 0]
    if acks and acks[0].result == baro.AckResult.UNKNOWN_COMMAND:
        report("barometer", "shipped firmware: the hang command is refused (no test hooks)")
        assert not resets, "the shipped firmware reset on an unknown command"
    else:
        assert resets, f"a test build hung its loop and the watchdog did not reset it: {acks}"
        assert resets[0].reset_cause & baro.ResetCause.WATCHDOG, resets[0]
        report("barometer", "test build: hung loop reset by the watchdog")


def test_a_second_session_after_the_port_is_closed_and_reopened(
    baro_port: str, hil_seconds: float, host_clock: HostClock, report: Callable[[str, str], None]
) -> None:
    for attempt in range(2):
        capture = Capture()
        session = _session(baro_port, capture, host_clock)
        with running(session):
            figures, before, after = stream_for(
                session, capture, PressureSample, hil_seconds / 2, RATE_HZ
            )
        report("barometer", f"session {attempt + 1}: {figures.line()}")
        assert_stream(figures, before, after)
