"""The Pioneer base on a real port: ``pytest -m hardware --p2os-port PATH [--allow-motion]``.

Without ``--allow-motion`` nothing here enables the motors: the handshake, the CONFIG packet,
SIPs at the robot's cycle with no framing error, the PULSE keepalive inside the robot's
watchdog, and a reconnect to a robot a dead client left open. With it: the motors disabled
however the session ends (stop, SIGTERM, an exception, the port lost), a 10 cm drive forward
and back at 100 mm/s whose odometry must match the model's scale, and the robot's watchdog
stopping a drive when the host falls silent. The drives are bounded: the test stops the motors
if the base goes 20 cm from where it started, and after a few seconds in any case.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

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
    wait_up,
)

from baromap.messages import DeviceState, Odometry
from baromap.odometry.integrator import OdometryIntegrator
from baromap.protocols import p2os
from baromap.protocols.robot_models import robot_model
from baromapd.clock import HostClock
from baromapd.config import BaseConfig, Retry
from baromapd.pioneer import PULSE_EVERY_S, PioneerSession

pytestmark = pytest.mark.hardware

#: Slow enough to stop within a centimetre or two; far below a P3-AT's 1200 mm/s.
SPEED_MMPS = 100
DRIVE_S = 1.0
#: The drives stop the motors when the base is this far from its start, whatever happens.
BOUND_M = 0.20
#: A retry slow enough that a test can look at the robot between two connections.
SLOW_RETRY = Retry(initial_s=5.0, max_s=5.0, silence_s=1.0, garbage_s=1.0)


class RecordingPioneer(PioneerSession):
    """The daemon's session, keeping what it wrote and the SIPs it read; it can be made to
    fail mid-stream the way a bug (an exception) or a pulled adapter (the port lost) would."""

    def __init__(self, config: BaseConfig, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        self.writes: list[tuple[float, bytes]] = []
        self.sips: list[p2os.StandardSip] = []
        self.fail: str | None = None
        self.failed_at: float | None = None

    def write(self, data: bytes) -> None:
        if self.fail == "port_lost" and self.failed_at is not None:
            raise serial.SerialException("write failed: [Errno 5] Input/output error")
        self.writes.append((time.monotonic(), data))
        super().write(data)

    def read(self, timeout_ms: int = 50) -> tuple[bytes, int]:
        if self.fail == "port_lost" and self.failed_at is None and self.state is DeviceState.UP:
            self.failed_at = time.monotonic()
            raise serial.SerialException("device reports readiness to read but returned no data")
        return super().read(timeout_ms)

    def _odometry(self, sip: p2os.StandardSip, sent_ns: int, read_ns: int) -> None:
        self.sips.append(sip)
        if self.fail == "exception" and self.failed_at is None and self.state is DeviceState.UP:
            self.failed_at = time.monotonic()
            raise RuntimeError("a fault injected into the session's SIP handling")
        super()._odometry(sip, sent_ns, read_ns)

    def commands(self, since: float = 0.0) -> list[p2os.CommandPacket]:
        decoder = p2os.Decoder(source="host")
        sent = b"".join(data for t, data in self.writes if t >= since)
        return [m for m in decoder.feed(sent) if isinstance(m, p2os.CommandPacket)]


def _session(
    port: str,
    capture: Capture,
    clock: HostClock,
    *,
    motors: bool = False,
    retry: Retry = QUICK_RETRY,
) -> RecordingPioneer:
    config = BaseConfig(port, enable_motors=motors, retry=retry)
    return RecordingPioneer(config, **session_kwargs(capture, clock))


def _sip_hz(session: PioneerSession) -> float:
    return 1000.0 / float(session.identity.get("sip_cycle_ms", 100))


def _ending(commands: list[p2os.CommandPacket]) -> list[tuple[int, int | bytes | None]]:
    return [(c.command, c.argument) for c in commands][-3:]


SAFE_ENDING = [(p2os.Command.STOP, None), (p2os.Command.ENABLE, 0), (p2os.Command.CLOSE, None)]


# ---- a client of the test's own, for what the daemon never does: drive ------------------------
class Client:
    """SYNC, OPEN and commands over the port; SIPs integrated with the robot's own model."""

    def __init__(self, path: str) -> None:
        self.port = serial.serial_for_url(path, baudrate=9600, timeout=0.02)
        self.decoder = p2os.Decoder()
        self.sips: list[tuple[float, p2os.StandardSip]] = []
        self.integrator: OdometryIntegrator | None = None
        self.poses: list[Odometry] = []
        self.last_write = 0.0

    def send(self, packet: bytes) -> None:
        self.port.write(packet)
        self.last_write = time.monotonic()

    def pump(self, seconds: float) -> list[object]:
        out: list[object] = []
        end = time.monotonic() + seconds
        while True:
            for message in self.decoder.feed(self.port.read(max(1, self.port.in_waiting))):
                out.append(message)
                if isinstance(message, p2os.StandardSip):
                    self.sips.append((time.monotonic(), message))
                    if self.integrator is not None:
                        self.poses.append(self.integrator.update(message, time.time_ns()))
            if time.monotonic() >= end:
                return out

    def answer(self, kinds: tuple[type, ...], timeout_s: float = 0.6) -> object | None:
        """The first message of one of ``kinds`` within ``timeout_s``, or None."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            for message in self.pump(0.02):
                if isinstance(message, kinds):
                    return message
        return None

    def connect(self) -> p2os.Sync2Info:
        for _ in range(6):
            self.send(p2os.sync(0))
            if isinstance(self.answer((p2os.SyncEcho, p2os.StandardSip)), p2os.StandardSip):
                self.send(p2os.close_controller())  # still open from an earlier client
                self.pump(0.3)
                continue
            self.send(p2os.sync(1))
            self.answer((p2os.SyncEcho,))
            self.send(p2os.sync(2))
            info = self.answer((p2os.Sync2Info,))
            if isinstance(info, p2os.Sync2Info):
                self.integrator = OdometryIntegrator(robot_model(info.subclass))
                self.send(p2os.open_controller())
                self.send(p2os.pulse())
                self.answer((p2os.StandardSip,), 1.0)
                return info
        pytest.fail("no SYNC handshake with the robot", pytrace=False)

    def pose(self) -> Odometry:
        assert self.poses, "no SIP since the handshake"
        return self.poses[-1]

    def close(self) -> None:
        try:
            for packet in (p2os.stop(), p2os.enable_motors(False), p2os.close_controller()):
                self.send(packet)
        finally:
            self.port.close()


def _take_control(client: Client) -> None:
    """Motors on, velocity zero: the base holds still under the host's control (an operator's
    joystick no longer drives it), so the next SIPs give the pose the drive starts from."""
    client.send(p2os.enable_motors(True))
    client.send(p2os.vel(0))
    client.pump(0.4)


def _along(start: Odometry, pose: Odometry) -> float:
    return (pose.x_m - start.x_m) * math.cos(start.theta_rad) + (pose.y_m - start.y_m) * math.sin(
        start.theta_rad
    )


def _drive(client: Client, origin: Odometry, mmps: int, seconds: float) -> float:
    """VEL every 100 ms for ``seconds`` (each one a keepalive too), then STOP and settle;
    stops at once past :data:`BOUND_M` from ``origin``. The seconds from the first VEL to
    the STOP."""
    start = time.monotonic()
    end = start + seconds
    try:
        while time.monotonic() < end:
            client.send(p2os.vel(mmps))
            client.pump(0.1)
            if abs(_along(origin, client.pose())) > BOUND_M:
                pytest.fail(f"the base went past {BOUND_M} m: stopped", pytrace=False)
    finally:
        client.send(p2os.stop())
        driven_s = time.monotonic() - start
    settle_end = time.monotonic() + 0.6
    while time.monotonic() < settle_end:
        client.send(p2os.pulse())
        client.pump(0.2)
    return driven_s


# ---- without motion ---------------------------------------------------------------------------
def test_handshake_config_and_sips_at_the_robots_cycle(
    p2os_port: str, hil_seconds: float, host_clock: HostClock, report: Callable[[str, str], None]
) -> None:
    capture = Capture()
    session = _session(p2os_port, capture, host_clock)
    with running(session):
        figures, before, after = stream_for(
            session, capture, Odometry, max(hil_seconds, 2.5), _sip_hz(session)
        )
        streaming_from = time.monotonic() - max(hil_seconds, 2.5)
    identity = session.identity
    writes = [t for t, _ in session.writes if t >= streaming_from]
    pauses = [b - a for a, b in itertools.pairwise(writes)]
    watchdog_s = int(identity.get("watchdog_ms", 2000)) / 1000
    report("base", describe(identity))
    report("base", figures.line())
    last = session.sips[-1]
    report(
        "base",
        f"last SIP: flags 0x{last.flags:04x} (motors {'on' if last.motors_enabled else 'off'}), "
        f"stall and bumpers 0x{last.stall_bumpers:04x}",
    )
    report(
        "base",
        f"battery {after.counters.get('battery_dv', 0) / 10:.1f} V; host writes at most "
        f"{max(pauses, default=0) * 1000:.0f} ms apart (robot watchdog {watchdog_s * 1000:.0f} ms)",
    )
    assert_stream(figures, before, after)
    assert identity["model"] == identity["subclass"], "the model is the one the robot reports"
    assert "watchdog_ms" in identity and "sip_cycle_ms" in identity, "no CONFIG packet read"
    assert after.counters.get("battery_dv", 0) > 0, "the SIPs carry no battery voltage"
    assert not any(s.motors_enabled for s in session.sips), "motors enabled without asking"
    # The keepalive: PULSE after 500 ms without another command, well inside the watchdog.
    assert watchdog_s / 2 > PULSE_EVERY_S
    assert pauses and max(pauses) < min(1.0, watchdog_s / 2), f"writes {max(pauses):.2f} s apart"
    assert p2os.Command.PULSE in {c.command for c in session.commands(streaming_from)}


def test_reconnect_to_a_robot_a_dead_client_left_open(
    p2os_port: str, hil_seconds: float, host_clock: HostClock, report: Callable[[str, str], None]
) -> None:
    """The first session closes its port without CLOSE (a crash): the robot keeps its session
    open and answers the next SYNC0 with SIPs; the next session closes it and syncs again."""
    dead = _session(p2os_port, Capture(), host_clock)
    dead.shutdown = lambda: None  # type: ignore[method-assign]
    with running(dead):
        time.sleep(0.3)
    capture = Capture()
    session = _session(p2os_port, capture, host_clock)
    with running(session):
        figures, before, after = stream_for(
            session, capture, Odometry, hil_seconds / 2, _sip_hz(session)
        )
    first = [c.command for c in session.commands()][:3]
    report("base", f"reopened: first commands {first}; {figures.line()}")
    assert first[:2] == [p2os.Command.SYNC0, p2os.Command.CLOSE], "the open session was not closed"
    assert_stream(figures, before, after)


# ---- with motion ------------------------------------------------------------------------------
@pytest.mark.usefixtures("allow_motion")
@pytest.mark.parametrize("how", ["stop", "exception", "port_lost"])
def test_motors_are_disabled_however_the_session_ends(
    p2os_port: str, host_clock: HostClock, report: Callable[[str, str], None], how: str
) -> None:
    session = _session(p2os_port, Capture(), host_clock, motors=True, retry=SLOW_RETRY)
    session.start()
    try:
        wait_up(session)
        wait_until(
            lambda: any(s.motors_enabled for s in session.sips[-3:]),
            3.0,
            lambda: "the robot's SIPs never said the motors are enabled",
        )
        ended = time.monotonic()
        if how == "stop":
            session.stop()
        else:
            session.fail = how
            wait_until(
                lambda: session.state is DeviceState.DOWN,
                5.0,
                lambda: f"the session did not end: {session.state.value} {session.detail}",
            )
        health = session.health(0)
        ending = _ending(session.commands(ended))
        if how == "port_lost":
            report("base", f"{how}: {health.detail}; commands after: {ending}")
            assert health.counters.get("motors_off_failed") == 1
            _robot_stops_by_itself(p2os_port, session, report)
            return
        report("base", f"{how}: last commands {ending}; {health.detail}")
        assert ending == SAFE_ENDING
        assert health.counters.get("motors_off_confirmed") == 1, "no SIP said 'motors off'"
        if how == "exception":
            assert "internal error" in health.detail
    finally:
        session.stop()


def _robot_stops_by_itself(
    path: str, session: RecordingPioneer, report: Callable[[str, str], None]
) -> None:
    """After the port was lost the robot's session is still open, its motors enabled: its own
    watchdog must hold it still, which its SIPs say (no wheel moving) within the watchdog."""
    watchdog_s = int(session.identity.get("watchdog_ms", 2000)) / 1000
    assert session.failed_at is not None
    client = Client(path)
    try:
        client.pump(max(0.0, session.failed_at + watchdog_s + 0.5 - time.monotonic()) + 0.5)
        last = [s for _, s in client.sips][-3:]
    finally:
        client.close()
    report(
        "base",
        f"port lost; SIPs {watchdog_s + 1:.1f} s later: wheels "
        f"{[(s.left_vel, s.right_vel) for s in last]}",
    )
    assert last, "the robot sent no SIP after the host lost its port"
    assert all(s.left_vel == 0 and s.right_vel == 0 for s in last)


@pytest.mark.usefixtures("allow_motion")
def test_sigterm_disables_the_motors_and_closes_the_robot(
    p2os_port: str, tmp_path: Path, report: Callable[[str, str], None]
) -> None:
    config = tmp_path / "baromapd.toml"
    config.write_text(
        f'robot = "hil"\n[zenoh]\nenabled = false\n[recording]\ndirectory = "{tmp_path / "rec"}"\n'
        f'min_free_mb = 0\n[base]\nport = "{p2os_port}"\nenable_motors = true\n'
        "retry_initial_s = 0.2\nretry_max_s = 1.0\n"
    )
    log_path = tmp_path / "daemon.log"
    with log_path.open("wb") as log_file:
        daemon = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "baromapd.main",
                "--config",
                str(config),
                "--log-format",
                "json",
            ],
            stdout=subprocess.DEVNULL,
            stderr=log_file,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        try:

            def events() -> list[dict[str, Any]]:
                lines = log_path.read_text().splitlines()
                return [json.loads(line) for line in lines if line.startswith("{")]

            wait_until(
                lambda: any(e.get("state") == "up" for e in events()),
                20.0,
                lambda: f"baromapd's base is not up: {log_path.read_text()[-2000:]}",
            )
            time.sleep(0.5)
            daemon.send_signal(signal.SIGTERM)
            assert daemon.wait(20) == 0
        finally:
            if daemon.poll() is None:
                daemon.kill()
                daemon.wait()
    disabled = [e for e in events() if e.get("event") == "motors disabled"]
    confirmed = [e.get("confirmed_by_robot") for e in disabled]
    report(
        "base",
        f"SIGTERM: baromapd exited 0; 'motors disabled', confirmed by the robot: {confirmed}",
    )
    assert disabled and disabled[-1]["confirmed_by_robot"] is True
    client = Client(p2os_port)
    try:
        client.send(p2os.sync(0))
        answer = client.pump(0.6)
    finally:
        client.port.close()
    assert any(isinstance(m, p2os.SyncEcho) for m in answer), f"robot left open: {answer[:3]}"


@pytest.mark.usefixtures("allow_motion")
def test_a_slow_10_cm_drive_forward_and_back_matches_the_models_scale(
    p2os_port: str, report: Callable[[str, str], None]
) -> None:
    """100 mm/s for 1 s forward, then back: the odometry, read with the model the robot's
    subclass names, must say about 10 cm each way (the wrong generation's factors say 4.7 or
    21.5 cm) and end where it began."""
    client = Client(p2os_port)
    try:
        info = client.connect()
        _take_control(client)
        origin = client.pose()
        forward_s = _drive(client, origin, SPEED_MMPS, DRIVE_S)
        forward = _along(origin, client.pose())
        _drive(client, origin, -SPEED_MMPS, DRIVE_S)
        back = _along(origin, client.pose())
    finally:
        client.close()
    expected = SPEED_MMPS / 1000 * forward_s
    report(
        "base",
        f"{info.subclass}: {SPEED_MMPS} mm/s for {forward_s:.2f} s: forward "
        f"{forward * 100:.1f} cm (commanded {expected * 100:.1f}), back to {back * 100:+.1f} cm",
    )
    assert 0.7 * expected <= forward <= 1.3 * expected
    assert abs(back) <= 0.3 * expected


@pytest.mark.usefixtures("allow_motion")
def test_the_robots_watchdog_stops_a_drive_when_the_host_falls_silent(
    p2os_port: str, report: Callable[[str, str], None]
) -> None:
    client = Client(p2os_port)
    try:
        client.connect()
        client.send(p2os.config_request())
        config = [m for m in client.pump(0.5) if isinstance(m, p2os.ConfigPacket)]
        watchdog_s = (config[0].watchdog_ms or 2000) / 1000 if config else 2.0
        _take_control(client)
        origin = client.pose()
        started = time.monotonic()
        for _ in range(5):  # half a second at half the test speed, then silence
            client.send(p2os.vel(SPEED_MMPS // 2))
            client.pump(0.1)
        silent_from = time.monotonic()
        while time.monotonic() < silent_from + watchdog_s + 1.0:
            client.pump(0.1)
            if abs(_along(origin, client.pose())) > BOUND_M:
                pytest.fail("the base did not stop: motors stopped by the test", pytrace=False)
        moving = [s for t, s in client.sips if silent_from < t < silent_from + 0.3]
        stopped = [s for t, s in client.sips if t > silent_from + watchdog_s + 0.5]
        travelled = _along(origin, client.pose())
    finally:
        client.close()
    most = SPEED_MMPS / 2000 * (silent_from - started + watchdog_s + 0.3)
    report(
        "base",
        f"host silent after {silent_from - started:.2f} s of driving: stopped by the robot's "
        f"{watchdog_s:g} s watchdog, {travelled * 100:.1f} cm in all (at most {most * 100:.1f})",
    )
    assert any(s.left_vel or s.right_vel for s in moving), "the base never moved"
    assert travelled <= most * 1.15, "the base drove on past its watchdog"
    assert stopped and all(s.left_vel == 0 and s.right_vel == 0 for s in stopped)
