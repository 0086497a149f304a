"""The Pioneer session picks the robot model from the SYNC2 subclass (issue 17).

A robot that reports ``p3at-sh`` and drives 10 m straight must give 10 m of odometry through
the session; a configuration pinning ``p3at`` on that robot is refused, naming both. The robot
here is a minimal scripted P2OS robot on a pty (SYNC echoes, then SIPs that advance 100 mm
each), so the distance is known exactly and the test does not wait for a route.
"""

from __future__ import annotations

import itertools
import os
import select
import threading
import time
import tty
from collections.abc import Iterator

import pytest

from baromap.errors import DeviceError
from baromap.messages import DeviceState, Message, Odometry
from baromap.protocols import p2os
from baromap.protocols.robot_models import robot_model
from baromapd.clock import HostClock
from baromapd.config import BaseConfig, Retry
from baromapd.pioneer import PULSE_EVERY_S, PioneerSession, choose_model


class ScriptedRobot:
    """Answers the handshake as ``subclass``, then drives straight: 100 mm per SIP."""

    def __init__(
        self,
        subclass: str,
        sips: int = 101,
        step_mm: float = 100.0,
        power_cycle_after: int | None = None,
        off_s: float = 1.5,
    ) -> None:
        self.subclass = subclass
        #: after this many SIPs the robot loses power for ``off_s`` and counts from zero again
        self.power_cycle_after = power_cycle_after
        self.off_s = off_s
        self.power_cycles = 0
        self.model = robot_model(subclass)
        self.sips = sips
        self.step_mm = step_mm
        self.sent = 0
        self.commands: list[int] = []
        #: (wall time, command, argument) of every packet the host sent
        self.packets: list[tuple[float, int, int | bytes | None]] = []
        self.opened = False
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="scripted-robot")

    def __enter__(self) -> ScriptedRobot:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)
        os.close(self.master)
        os.close(self._slave)

    def _run(self) -> None:
        decoder = p2os.Decoder(source="host")
        is_open = synced = False
        origin = 0  # the SIP the counters count from (they restart at a power cycle)
        while not self._stop.is_set():
            if self.sent == self.power_cycle_after and not self.power_cycles:
                self.power_cycles += 1
                time.sleep(self.off_s)
                while select.select([self.master], [], [], 0)[0]:
                    os.read(self.master, 1024)  # what the host sent was lost
                decoder = p2os.Decoder(source="host")
                is_open = synced = False
                origin = self.sent
            ready, _, _ = select.select([self.master], [], [], 0.02)
            if ready:
                for cmd in decoder.feed(os.read(self.master, 1024)):
                    if not isinstance(cmd, p2os.CommandPacket):
                        continue
                    self.commands.append(cmd.command)
                    self.packets.append((time.monotonic(), cmd.command, cmd.argument))
                    if cmd.command in (0, 1) and not synced:
                        os.write(self.master, p2os.encode_sync_echo(cmd.command))
                    elif cmd.command == 2 and not synced:
                        info = p2os.Sync2Info("scripted", "Pioneer", self.subclass)
                        os.write(self.master, info.encode())
                        synced = True
                    elif cmd.command == p2os.Command.OPEN:
                        is_open = self.opened = True
                    elif cmd.command == p2os.Command.CLOSE:
                        is_open = synced = False
            if is_open:  # then stands still at the end, still reporting
                step = min(self.sent, self.sips - 1) - origin
                units = round(step * self.step_mm / self.model.dist_conv_factor)
                sip = p2os.StandardSip(
                    moving=self.sent < self.sips, x=units & 0x7FFF, y=0, theta=0, left_vel=1000,
                    right_vel=1000, battery_dv=130, stall_bumpers=0, control=0, flags=0,
                    compass=0,
                )  # fmt: skip
                os.write(self.master, sip.encode())
                self.sent += 1


@pytest.fixture
def odometry() -> list[Odometry]:
    return []


def _session(robot: ScriptedRobot, model: str, sink: list[Message], **kw: object) -> PioneerSession:
    config = BaseConfig(robot.path, model=model, retry=Retry(0.2, 1.0, 1.0, 1.0), **kw)  # type: ignore[arg-type]
    return PioneerSession(
        config, clock=HostClock(), publish=lambda m, _ns: sink.append(m), resolve=lambda p: p
    )


@pytest.fixture
def p3at_sh() -> Iterator[ScriptedRobot]:
    with ScriptedRobot("p3at-sh") as robot:
        yield robot


def test_a_p3at_sh_driven_10_m_gives_10_m_of_odometry(
    p3at_sh: ScriptedRobot, odometry: list[Message]
) -> None:
    session = _session(p3at_sh, "auto", odometry)
    session.start()
    try:
        deadline = time.monotonic() + 15
        while p3at_sh.sent < p3at_sh.sips and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.3)
        health = session.health(0)
    finally:
        session.stop()
    assert "p3at-sh" in health.detail  # health names the model and where it came from
    poses = [m for m in odometry if isinstance(m, Odometry)]
    assert p3at_sh.sent >= p3at_sh.sips
    assert session.identity["model"] == "p3at-sh"
    assert session.identity["subclass"] == "p3at-sh"
    travelled = poses[-1].x_m - poses[0].x_m
    assert travelled == pytest.approx(10.0, rel=0.01)
    assert p2os.Command.CLOSE in p3at_sh.commands  # and CLOSE on stop
    assert p2os.Command.ENABLE not in p3at_sh.commands  # motors never enabled by default


def test_a_power_cycled_robot_is_joined_at_its_last_pose_in_one_odom_frame() -> None:
    """The robot loses power 10 m into a 20 m drive and counts from zero again when the
    session has reconnected: the odometry goes on from 10 m, not from the robot's new zero
    (a jump back to where the run began), and the health counters say the track was joined.
    10 m: a P3-AT could not drive that far in the 8 s a slow reconnect may take."""
    odometry: list[Message] = []
    with ScriptedRobot("p3at-sh", sips=101, step_mm=200.0, power_cycle_after=50) as robot:
        session = _session(robot, "auto", odometry)
        session.start()
        try:
            deadline = time.monotonic() + 20
            while robot.sent < robot.sips + 5 and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(0.3)
            health = session.health(0)
        finally:
            session.stop()
    assert robot.power_cycles == 1
    poses = [m for m in odometry if isinstance(m, Odometry)]
    assert health.counters["connects"] == 2
    assert health.counters["odometry_tracks_joined"] == 1
    steps = [abs(b.x_m - a.x_m) for a, b in itertools.pairwise(poses)]
    assert max(steps) == pytest.approx(0.2, abs=1e-6)  # never a jump: 200 mm per SIP
    assert poses[-1].x_m == pytest.approx(20.0 - 0.2, abs=1e-6)  # the lost SIP's 0.2 m


def test_a_pinned_p3at_on_a_p3at_sh_robot_is_refused_naming_both(
    p3at_sh: ScriptedRobot, odometry: list[Message]
) -> None:
    session = _session(p3at_sh, "p3at", odometry)
    session.start()
    try:
        deadline = time.monotonic() + 10
        while session.state is not DeviceState.DOWN and time.monotonic() < deadline:
            time.sleep(0.05)
        health = session.health(0)
    finally:
        session.stop()
    assert health.state is DeviceState.DOWN
    assert "'p3at'" in health.detail and "'p3at-sh'" in health.detail
    assert not [m for m in odometry if isinstance(m, Odometry)]
    assert not p3at_sh.opened


def test_model_choice() -> None:
    assert choose_model("p3at-sh", "auto", False)[0].dist_conv_factor == 1.0
    assert choose_model("p3at", "auto", False)[0].dist_conv_factor == 0.465
    model, note = choose_model("p3at-sh", "p3at", True)
    assert model.name == "p3at" and "overrides" in note
    with pytest.raises(DeviceError, match="p3at-sh"):
        choose_model("p3at-sh", "p3at", False)
    with pytest.raises(DeviceError, match="'mystery'"):
        choose_model("mystery", "auto", False)


def test_motors_enabled_only_when_configured_and_disabled_last_on_stop(
    odometry: list[Message],
) -> None:
    """enable_motors: ENABLE 1 after OPEN; on stop STOP, ENABLE 0 (a SIP confirms it), CLOSE."""
    with ScriptedRobot("p3at-sh", sips=1000) as robot:
        session = _session(robot, "auto", odometry, enable_motors=True)
        session.start()
        try:
            _wait_up(session)
        finally:
            session.stop()
        health = session.health(0)
        time.sleep(0.2)  # the robot's thread reads what the session wrote last
        sent = [(command, argument) for _, command, argument in robot.packets]
    configured = sent.index((p2os.Command.CONFIG, 1))  # asked for right after OPEN
    assert (p2os.Command.ENABLE, 1) in sent[configured:]
    assert sent[-3:] == [
        (p2os.Command.STOP, None),
        (p2os.Command.ENABLE, 0),
        (p2os.Command.CLOSE, None),
    ]
    assert health.counters["motors_off"] == 1 and health.counters["motors_off_confirmed"] == 1


def test_pulse_keeps_the_robot_hearing_from_the_host(odometry: list[Message]) -> None:
    """While streaming, the host writes at least every PULSE_EVERY_S (plus a read's wait):
    far inside the robot's 2 s watchdog."""
    with ScriptedRobot("p3at-sh", sips=1000) as robot:
        session = _session(robot, "auto", odometry)
        session.start()
        try:
            _wait_up(session)
            up = time.monotonic()
            time.sleep(2.0)
        finally:
            session.stop()
        streaming = [(t, c) for t, c, _ in robot.packets if t > up]
    assert sum(c == p2os.Command.PULSE for _, c in streaming) >= 3
    gaps = [b - a for (a, _), (b, _) in itertools.pairwise(streaming[:-1])]
    assert max(gaps) < PULSE_EVERY_S + 0.4, gaps


def _wait_up(session: PioneerSession) -> None:
    deadline = time.monotonic() + 10
    while session.state is not DeviceState.UP and time.monotonic() < deadline:
        time.sleep(0.02)
    assert session.state is DeviceState.UP, session.detail
