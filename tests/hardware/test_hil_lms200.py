"""The SICK LMS200 on a real port: ``pytest -m hardware --lms-port PATH [--lms-baud 500000]``.

Reset (0x10) and the power-on wait for the boot telegram 0x90, then the daemon's session from
that power-on state; scans at the rate the line and the mirror allow, with no framing error
and a healthy status byte, in each mode the driver supports; the baud search finding a sensor
left streaming at another speed by a client that died, which is also the reconnect after the
port was closed and opened again.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest
import serial
from hil import QUICK_RETRY, Capture, assert_stream, describe, running, session_kwargs, stream_for

from baromap.messages import LaserScan
from baromap.protocols import lms200
from baromapd.bench import laser_hz
from baromapd.clock import HostClock
from baromapd.config import LaserConfig
from baromapd.lms200 import SEARCH_BAUDS, Lms200Session

pytestmark = pytest.mark.hardware

#: Drivers wait up to a minute for the power-on telegram after a reset.
BOOT_WAIT_S = 60.0


def _session(
    port: str, baud: int, capture: Capture, clock: HostClock, **settings: object
) -> Lms200Session:
    config = LaserConfig(port, baud=baud, retry=QUICK_RETRY, **settings)  # type: ignore[arg-type]
    return Lms200Session(config, **session_kwargs(capture, clock))


def _telegrams(port: serial.Serial, decoder: lms200.Decoder, seconds: float) -> list[object]:
    out: list[object] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        out += decoder.feed(port.read(max(1, port.in_waiting)))
    return out


def _find_baud(path: str) -> tuple[int, lms200.StatusReport | None]:
    """The sensor's speed: the first at which a status request gets a good telegram back; and
    the status reply, when that telegram was one (a sensor left streaming may answer with a
    scan first)."""
    for baud in SEARCH_BAUDS:
        with serial.serial_for_url(path, baudrate=baud, timeout=0.05) as port:
            port.reset_input_buffer()
            port.write(lms200.status_request())
            decoder = lms200.Decoder(at_boundary=False)
            found = False
            for item in _telegrams(port, decoder, 0.4 + 2 * 9000 / baud):
                found = found or isinstance(item, lms200.Telegram | lms200.ScanTelegram)
                if isinstance(item, lms200.Telegram) and item.command == lms200.Reply.STATUS:
                    return baud, lms200.parse_status_reply(item)
            if found:
                return baud, None
    pytest.fail(f"no LMS200 answers at {SEARCH_BAUDS} baud", pytrace=False)


def test_reset_waits_for_the_power_on_telegram_then_the_session_starts_from_power_on(
    lms_port: str,
    request: pytest.FixtureRequest,
    hil_seconds: float,
    host_clock: HostClock,
    report: Callable[[str, str], None],
) -> None:
    found, status = _find_baud(lms_port)
    assert status is not None, "no status reply to a status request"
    report(
        "laser",
        f"status: software {status.software_version.strip()}, operating mode "
        f"0x{status.operating_mode:02x}, device status {status.device_status} (0 ok), measuring "
        f"mode {status.measuring_mode}, {status.angle_deg} deg / {status.resolution_cdeg / 100} "
        f"deg, units {'mm' if status.units == 1 else 'cm'}, laser on {status.laser_on}",
    )
    assert status.device_status == 0, f"the sensor reports device status {status.device_status}"
    with serial.serial_for_url(lms_port, baudrate=found, timeout=0.05) as port:
        port.reset_input_buffer()
        port.write(lms200.reset())
        sent = time.monotonic()
        replies = _telegrams(port, lms200.Decoder(), 1.0)
        assert any(isinstance(t, lms200.Ack) for t in replies), f"no ACK to reset: {replies}"
        assert any(
            isinstance(t, lms200.Telegram) and t.command == lms200.Reply.RESET for t in replies
        ), f"no 0x91 reply to reset: {replies}"
        port.baudrate = 9600  # the sensor restarts at its power-on speed
        decoder = lms200.Decoder(at_boundary=False)
        power_on = None
        while power_on is None and time.monotonic() - sent < BOOT_WAIT_S:
            for item in _telegrams(port, decoder, 0.2):
                if isinstance(item, lms200.Telegram) and item.command == lms200.Reply.POWER_ON:
                    power_on = item
        booted_s = time.monotonic() - sent
    assert power_on is not None, f"no power-on telegram 0x90 within {BOOT_WAIT_S:g} s"
    text = power_on.data.decode("ascii", "replace").strip()
    report(
        "laser", f"found at {found} baud; reset, power-on telegram {text!r} after {booted_s:.1f} s"
    )

    baud = int(request.config.getoption("--lms-baud"))
    capture = Capture()
    session = _session(lms_port, baud, capture, host_clock)
    with running(session):
        figures, before, after = stream_for(
            session, capture, LaserScan, hil_seconds, laser_hz(baud, 180, 100)
        )
    status = after.counters.get("status_not_ok", 0) - before.counters.get("status_not_ok", 0)
    report("laser", describe(session.identity))
    report("laser", figures.line())
    assert_stream(figures, before, after)
    assert status == 0, f"{status} scans whose status byte is not 'ok'"
    assert session.identity["software_version"], "the status reply named no software version"


@pytest.mark.parametrize(
    ("angle_deg", "resolution_cdeg", "units"),
    [(180, 100, "mm"), (180, 50, "cm"), (100, 25, "mm")],
    ids=["180deg-1deg-mm", "180deg-0.5deg-cm", "100deg-0.25deg-mm"],
)
def test_each_mode_streams_its_beams_at_its_rate(
    lms_port: str,
    request: pytest.FixtureRequest,
    hil_seconds: float,
    host_clock: HostClock,
    report: Callable[[str, str], None],
    angle_deg: int,
    resolution_cdeg: int,
    units: str,
) -> None:
    baud = int(request.config.getoption("--lms-baud"))
    capture = Capture()
    session = _session(
        lms_port, baud, capture, host_clock,
        angle_deg=angle_deg, resolution_deg=resolution_cdeg / 100, units=units,
    )  # fmt: skip
    rate = laser_hz(baud, angle_deg, resolution_cdeg)
    with running(session):
        figures, before, after = stream_for(
            session, capture, LaserScan, max(hil_seconds / 2, 12 / rate), rate
        )
    scans = [r.message for r in capture.of(LaserScan)]
    report("laser", f"{angle_deg} deg / {resolution_cdeg / 100} deg, {units}: {figures.line()}")
    assert_stream(figures, before, after)
    beams = angle_deg * 100 // resolution_cdeg + 1
    assert {len(s.ranges_m) for s in scans} == {beams}
    span = scans[-1].angle_increment_rad * (beams - 1)
    assert span == pytest.approx(angle_deg * 3.141592653589793 / 180, abs=1e-3)
    range_max = {"mm": 8.191, "cm": 81.91}[units]
    assert scans[-1].range_max_m == pytest.approx(range_max, rel=0.01)


def test_baud_search_finds_a_sensor_left_streaming_by_a_client_that_died(
    lms_port: str,
    request: pytest.FixtureRequest,
    hil_seconds: float,
    host_clock: HostClock,
    report: Callable[[str, str], None],
) -> None:
    """A first session leaves the sensor streaming at 19200 baud and closes the port without
    its shutdown (a crash); a second, configured for another speed, opens the port again,
    finds the sensor by searching and sets it up."""
    baud = int(request.config.getoption("--lms-baud"))
    left_at = 19200 if baud != 19200 else 9600
    dead = _session(lms_port, left_at, Capture(), host_clock, restore_9600=False)
    dead.shutdown = lambda: None  # type: ignore[method-assign]
    with running(dead):
        time.sleep(0.3)
    assert _find_baud(lms_port)[0] == left_at, "the first session did not leave it at its speed"

    capture = Capture()
    session = _session(lms_port, baud, capture, host_clock)
    with running(session):
        figures, before, after = stream_for(
            session, capture, LaserScan, hil_seconds / 2, laser_hz(baud, 180, 100)
        )
    report("laser", f"left streaming at {left_at}, found and set to {baud}: {figures.line()}")
    assert after.counters.get("baud") == baud
    assert_stream(figures, before, after)
