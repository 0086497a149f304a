"""The P3-AT twin: the SYNC handshake, SIPs every 100 ms, keepalive watchdog, odometry.

The robot follows the scenario's route (as if an operator drove it with the joystick); the
host only listens. What the host controls is what ARCOS lets it control: SYNC0-2 and OPEN
start the SIPs, ENABLE switches the motors flag, CLOSE ends the session, CONFIG asks for the
whole CONFIG packet, SETO resets the odometry. It reports the subclass of the scenario's
:class:`~baromap.sim.scenario.TwinSettings` (default ``p3at-sh``) and counts positions with
that model's DistConvFactor, so both generations of P3-AT can be tested.

The open session, as on the real robot: a SYNC0 that arrives while the session is open is a
PULSE on the wire, answered by nothing but the SIPs that keep coming; CLOSE ends the session.
The watchdog: while a session is open and nothing arrives from the host for 2 s, the motors
stop (route time stands still for every twin, SIPs say "stopped") until the host is heard
again. The 2 s are wall seconds whatever the clock's speed: they judge the host, whose
keepalives come in wall time.

A host that enables the motors and sets a velocity (VEL, RVEL) takes the robot over, as a
hardware-in-the-loop test does on a desk: from then until ENABLE 0 or CLOSE the route stands
still and the odometry counts the commanded motion only (through the odometry error model, at
the model's DistConvFactor); STOP and the watchdog set the velocities to zero. Only the
odometry sees that motion; the laser and the barometer stay where the route left the robot.

One modelling choice: the route stands for a client driving the robot, so when bare SYNC0s
come faster than any keepalive needs (three, each within :data:`RESYNC_GAP_S` of the last), a
new client is
re-synchronising over a session whose driver died, and the motors stop at once instead of
after the watchdog. p2os_driver (CLOSE on the first SIP) is unaffected; ARIA, which closes an
old session only on a "stopped" SIP, reconnects within a second instead of never.
"""

from __future__ import annotations

import enum
import math
import time

import numpy as np

from baromap.odometry.errors import OdometryErrorModel
from baromap.protocols import p2os
from baromap.sim.odometry import (
    SIP_PERIOD_S,
    OdometryModel,
    counters,
    sip,
    true_increments,
)
from baromap.sim.scenario import STREAM_ODOMETRY
from baromap.sim.twins.base import Twin

WATCHDOG_S = 2.0
#: Three bare SYNC0s, each closer than this to the last, on an open session: a client is
#: re-synchronising (ARIA retries every 0.1-0.2 s; a keepalive needs one PULSE per 2 s).
RESYNC_GAP_S = 0.2
#: Largest setpoints the twin obeys (a P3-AT's MaxVelocity and MaxRVelocity).
MAX_HOST_MMPS = 1200
MAX_HOST_DEGPS = 300


class Session(enum.Enum):
    CLOSED = "closed"
    SYNCING = "syncing"
    SYNCED = "synced"
    OPEN = "open"


class P2osTwin(Twin):
    name = "p3at"
    initial_baud = 9600

    def setup(self) -> None:
        self.model = self.settings.robot_model
        rng = self.clock.scenario.rng(STREAM_ODOMETRY)
        self.errors = OdometryErrorModel.random(rng)
        self._rng = rng
        self.sips_sent = 0
        self.watchdog_trips = 0
        self.resyncs = 0

    def power_on(self) -> None:
        self.port.set_baud(self.settings.robot_baud)
        self.decoder = p2os.Decoder(source="host")
        self.session = Session.CLOSED
        self.sync_step = 0
        self.motors = False
        self.odometry = OdometryModel(self.errors, self._rng)
        self._prev = self._true_pose()
        self._next_sip = time.monotonic()
        self._last_heard = time.monotonic()
        self._last_bare_sync: float | None = None
        self._quick_syncs = 0
        self.stopped_for_resync = False
        #: The host's velocity setpoints (mm/s, deg/s), obeyed while the motors are enabled.
        self.commanded_mmps = 0
        self.commanded_degps = 0
        self._host_control = False  # a velocity was set with the motors enabled
        self._host_halted = False  # the route stands still because the host drives
        #: Commanded motion (m, rad) not yet in a SIP, and the simulated instant it runs to.
        self._driven = (0.0, 0.0)
        self._driven_to_s = self.clock.now()
        self.clock.resume()

    @property
    def identity(self) -> p2os.Sync2Info:
        """What the SYNC2 echo says: name, class, subclass."""
        return p2os.Sync2Info(
            self.settings.robot_name, self.model.robot_class, self.settings.robot_subclass
        )

    def _true_pose(self) -> tuple[float, float, float]:
        truth = self.clock.scenario.truth(np.array([self.clock.robot_time()]))
        return float(truth.x[0]), float(truth.y[0]), float(truth.theta[0])

    def on_bytes(self, data: bytes) -> None:
        for msg in self.decoder.feed(data):
            if not isinstance(msg, p2os.CommandPacket):
                continue
            now = time.monotonic()
            self._last_heard = now
            bare_sync = msg.command == p2os.Command.SYNC0 and msg.argument is None
            if self.session == Session.OPEN and bare_sync:
                quick = (
                    self._last_bare_sync is not None and now - self._last_bare_sync < RESYNC_GAP_S
                )
                self._quick_syncs = self._quick_syncs + 1 if quick else 0
                if self._quick_syncs >= 2 and not self.stopped_for_resync:
                    self.resyncs += 1
                    self.stopped_for_resync = True
                    self.clock.halt()
                self._last_bare_sync = now
            elif not bare_sync:
                self._last_bare_sync = None
                self._quick_syncs = 0
            if self.clock.halted and not self.stopped_for_resync and not self.host_driving:
                self.clock.resume()  # ARCOS revives on the next packet after a watchdog stop
            self._command(msg)
            self._follow_host()

    def _drive_until_now(self) -> tuple[float, float]:
        """The commanded motion since the last call (m, rad), at the setpoints in force."""
        now_s = self.clock.now()
        dt_s, self._driven_to_s = now_s - self._driven_to_s, now_s
        if not self.host_driving:
            return 0.0, 0.0
        return self.commanded_mmps / 1000.0 * dt_s, math.radians(self.commanded_degps) * dt_s

    def _command(self, c: p2os.CommandPacket) -> None:
        ds, dth = self._drive_until_now()  # the old setpoints held until this command
        self._driven = (self._driven[0] + ds, self._driven[1] + dth)
        cmd = c.command
        if self.session in (Session.CLOSED, Session.SYNCING) and c.argument is None and cmd <= 2:
            if cmd == self.sync_step:
                if cmd == 2:
                    self.port.send(self.identity.encode())
                    self.session = Session.SYNCED
                    self.sync_step = 0
                else:
                    self.port.send(p2os.encode_sync_echo(cmd))
                    self.session = Session.SYNCING
                    self.sync_step = cmd + 1
            else:
                self.sync_step = 0
                self.session = Session.CLOSED
            return
        if cmd == p2os.Command.OPEN and self.session == Session.SYNCED:
            self.session = Session.OPEN
            self.stopped_for_resync = False
            self._last_bare_sync = None
            self.clock.resume()
            self._next_sip = time.monotonic()
        elif cmd == p2os.Command.CLOSE:
            self.session = Session.CLOSED
            self.motors = False
            self.sync_step = 0
            self.commanded_mmps = self.commanded_degps = 0
            self._host_control = False
        elif cmd == p2os.Command.ENABLE:
            self.motors = bool(c.argument)
            if not self.motors:
                self.commanded_mmps = self.commanded_degps = 0
                self._host_control = False
        elif cmd == p2os.Command.VEL and isinstance(c.argument, int):
            self.commanded_mmps = max(-MAX_HOST_MMPS, min(MAX_HOST_MMPS, c.argument))
            self._host_control = self.motors
        elif cmd == p2os.Command.RVEL and isinstance(c.argument, int):
            self.commanded_degps = max(-MAX_HOST_DEGPS, min(MAX_HOST_DEGPS, c.argument))
            self._host_control = self.motors
        elif cmd == p2os.Command.STOP:
            self.commanded_mmps = self.commanded_degps = 0
        elif cmd == p2os.Command.SETO:
            self.odometry.x_m = self.odometry.y_m = self.odometry.theta = 0.0
        elif cmd == p2os.Command.CONFIG and self.session == Session.OPEN:
            self.port.send(self.config_packet())

    @property
    def host_driving(self) -> bool:
        """The host has the robot: it set a velocity with the motors enabled (open session)."""
        return self.session == Session.OPEN and self.motors and self._host_control

    def _follow_host(self) -> None:
        """Stop the route while the host drives; let it go on when the host stops."""
        if self.host_driving and not self._host_halted:
            self._host_halted = True
            self.clock.halt()
        elif not self.host_driving and self._host_halted:
            self._host_halted = False
            if not self.stopped_for_resync:
                self.clock.resume()

    def config_packet(self) -> bytes:
        """The whole CONFIG packet, every field ARCOS sends (ARIA reads them all)."""
        model = self.model
        values: dict[str, p2os.ConfigValue] = dict.fromkeys(p2os.CONFIG_FIELD_NAMES, 0)
        values.update(
            robot_type=model.robot_class,
            subtype=model.name,
            serial_number="SIM0001",
            four_mots=int(model.diff_conv_factor == 0.0034),  # the skid-steered bases
            rot_vel_top=round(model.max_rot_velocity_degps),
            trans_vel_top=round(model.max_velocity_mmps),
            rot_accel_top=300,
            trans_accel_top=300,
            pwm_max=1000,
            name=self.settings.robot_name,
            sip_cycle_ms=round(SIP_PERIOD_S * 1000),
            front_sonar=1,
            rear_sonar=1,
            low_battery=110,
            rev_count=16570,
            watchdog_ms=round(WATCHDOG_S * 1000),
            stall_val=255,
            stall_count=100,
            joy_vel=300,
            joy_rot_vel=50,
            rot_vel_max=round(model.max_rot_velocity_degps),
            trans_vel_max=round(model.max_velocity_mmps),
            rot_accel=100,
            rot_decel=100,
            trans_accel=300,
            trans_decel=300,
            front_bumps=5,
            rear_bumps=5,
            sonar_cycle=40,
            host_baud=p2os.HOST_BAUD_CODES[self.settings.robot_baud],
            reset_baud=2,
            ticks_mm=round(1.0 / model.dist_conv_factor),
            shutdown_voltage=105,
            firmware_version="baromap-sim",
            bootloader_version="",
            high_temperature_shutdown=-128,
        )
        return p2os.encode_config(values)

    def tick(self) -> None:
        now = time.monotonic()
        if self.session != Session.OPEN:
            return
        if now - self._last_heard > WATCHDOG_S:
            if self.host_driving:  # the robot stops where the host left it
                if self.commanded_mmps or self.commanded_degps:
                    self.watchdog_trips += 1
                self.commanded_mmps = self.commanded_degps = 0
            elif not self.clock.halted:
                self.watchdog_trips += 1
                self.clock.halt()
        if now < self._next_sip:
            return
        self._next_sip += self.clock.real_delay(SIP_PERIOD_S)
        if self._next_sip < now:
            self._next_sip = now + self.clock.real_delay(SIP_PERIOD_S)
        # The robot sends its pose as it takes it: the packet holds the pose of the instant
        # the truth log records and starts on the line then. A thread held up while it builds
        # the packet (a loaded machine) delivers it late, which the port's lateness counts.
        pose_ns = time.monotonic_ns()
        pose_s = self.clock.robot_time()
        if self.port.send(self.sip_packet(pose_s), at=pose_ns / 1e9):
            self.truth.record(pose_ns, pose_s, boot=self.boot)
        self.sips_sent += 1

    def sip_packet(self, robot_s: float) -> bytes:
        """The SIP of the robot's pose at route time ``robot_s``."""
        truth = self.clock.scenario.truth(np.array([robot_s]))
        ds, dth = true_increments(truth.x, truth.y, truth.theta, self._prev)
        self._prev = (float(truth.x[0]), float(truth.y[0]), float(truth.theta[0]))
        driving = self.host_driving
        step, turn = self._drive_until_now()
        step, turn = step + self._driven[0], turn + self._driven[1]
        self._driven = (0.0, 0.0)
        if step or turn:
            ds, dth = ds + step, dth + turn
        x, y, th = self.odometry.step(ds, dth)
        cx, cy, cth = counters(self.model, x, y, th)
        v = float(truth.v[0]) * (1.0 + self.errors.scale)
        w = float(truth.omega[0]) * (1.0 + self.errors.rotation_scale)
        if self.clock.halted:
            v = w = 0.0
        if driving:
            v = self.commanded_mmps / 1000.0 * (1.0 + self.errors.scale)
            w = math.radians(self.commanded_degps) * (1.0 + self.errors.rotation_scale)
        packet = sip(
            self.model,
            x=int(cx[0]),
            y=int(cy[0]),
            theta=int(cth[0]),
            v_mps=v,
            omega_radps=w,
            motors=self.motors,
            arcos_tail=True,
        )
        return packet.encode()
