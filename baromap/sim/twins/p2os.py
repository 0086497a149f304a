"""The P3-AT twin: the SYNC handshake, SIPs every 100 ms, keepalive watchdog, odometry.

The robot follows the scenario's route (as if an operator drove it with the joystick); the
host only listens. What the host controls is what P2OS lets it control: SYNC0-2 and OPEN
start the SIPs, ENABLE switches the motors flag, CLOSE ends the session, CONFIG asks for a
CONFIG packet, SETO resets the odometry. The watchdog: while a session is open and nothing
arrives from the host for 2 s, the robot stops (route time stands still for every twin)
until the host is heard again. The 2 s are wall seconds whatever the clock's speed: they judge
the host, whose keepalives come in wall time. Before SYNC, the robot echoes the handshake; a
SYNC0 that arrives while the session is open is a PULSE, as on the real robot, so a client
that finds SIPs streaming sends CLOSE and starts again.
"""

from __future__ import annotations

import enum
import time
from pathlib import Path

import numpy as np

from baromap.protocols import p2os
from baromap.protocols.robot_models import P3AT
from baromap.sim.odometry import (
    SIP_PERIOD_S,
    OdometryErrors,
    OdometryModel,
    counters,
    sip,
    true_increments,
)
from baromap.sim.scenario import STREAM_ODOMETRY
from baromap.sim.twins.base import SimClock, Twin

WATCHDOG_S = 2.0
NAME = ("baromap-sim", "Pioneer", "p3at")


class Session(enum.Enum):
    CLOSED = "closed"
    SYNCING = "syncing"
    SYNCED = "synced"
    OPEN = "open"


class P2osTwin(Twin):
    name = "p3at"
    initial_baud = 9600

    def __init__(self, clock: SimClock, link: str | Path | None = None) -> None:
        super().__init__(clock, link)
        rng = clock.scenario.rng(STREAM_ODOMETRY)
        self.errors = OdometryErrors.random(rng)
        self._rng = rng
        self.sips_sent = 0
        self.watchdog_trips = 0

    def power_on(self) -> None:
        self.port.set_baud(9600)
        self.decoder = p2os.Decoder(source="host")
        self.session = Session.CLOSED
        self.sync_step = 0
        self.motors = False
        self.odometry = OdometryModel(self.errors, self._rng)
        self._prev = self._true_pose()
        self._next_sip = time.monotonic()
        self._last_heard = time.monotonic()
        self.clock.resume()

    def _true_pose(self) -> tuple[float, float, float]:
        truth = self.clock.scenario.truth(np.array([self.clock.robot_time()]))
        return float(truth.x[0]), float(truth.y[0]), float(truth.theta[0])

    def on_bytes(self, data: bytes) -> None:
        for msg in self.decoder.feed(data):
            if not isinstance(msg, p2os.CommandPacket):
                continue
            self._last_heard = time.monotonic()
            if self.clock.halted:
                self.clock.resume()
            self._command(msg)

    def _command(self, c: p2os.CommandPacket) -> None:
        cmd = c.command
        if self.session in (Session.CLOSED, Session.SYNCING) and c.argument is None and cmd <= 2:
            if cmd == self.sync_step:
                if cmd == 2:
                    self.port.send(p2os.Sync2Info(*NAME).encode())
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
            self._next_sip = time.monotonic()
        elif cmd == p2os.Command.CLOSE:
            self.session = Session.CLOSED
            self.motors = False
            self.sync_step = 0
        elif cmd == p2os.Command.ENABLE:
            self.motors = bool(c.argument)
        elif cmd == p2os.Command.SETO:
            self.odometry.x_m = self.odometry.y_m = self.odometry.theta = 0.0
        elif cmd == p2os.Command.CONFIG and self.session == Session.OPEN:
            self.port.send(self.config_packet())

    def config_packet(self) -> bytes:
        return p2os.encode_config(
            {
                "robot_type": "Pioneer",
                "subtype": "p3at",
                "serial_number": "SIM0001",
                "four_mots": 1,
                "rot_vel_top": 300,
                "trans_vel_top": 1200,
                "rot_accel_top": 300,
                "trans_accel_top": 300,
                "pwm_max": 1000,
                "name": NAME[0],
                "sip_cycle_ms": round(SIP_PERIOD_S * 1000),
                "host_baud": 0,
                "aux1_baud": 0,
                "has_gripper": 0,
                "front_sonar": 1,
                "rear_sonar": 1,
                "low_battery": 110,
                "rev_count": 16570,
                "watchdog_ms": round(WATCHDOG_S * 1000),
            }
        )

    def tick(self) -> None:
        now = time.monotonic()
        if self.session != Session.OPEN:
            return
        if now - self._last_heard > WATCHDOG_S and not self.clock.halted:
            self.watchdog_trips += 1
            self.clock.halt()
        if now < self._next_sip:
            return
        self._next_sip += self.clock.real_delay(SIP_PERIOD_S)
        if self._next_sip < now:
            self._next_sip = now + self.clock.real_delay(SIP_PERIOD_S)
        self.port.send(self.sip_packet())
        self.sips_sent += 1

    def sip_packet(self) -> bytes:
        truth = self.clock.scenario.truth(np.array([self.clock.robot_time()]))
        ds, dth = true_increments(truth.x, truth.y, truth.theta, self._prev)
        self._prev = (float(truth.x[0]), float(truth.y[0]), float(truth.theta[0]))
        x, y, th = self.odometry.step(ds, dth)
        cx, cy, cth = counters(P3AT, x, y, th)
        v = float(truth.v[0]) * (1.0 + self.errors.scale)
        w = float(truth.omega[0]) * (1.0 + self.errors.rotation_scale)
        if self.clock.halted:
            v = w = 0.0
        packet = sip(
            P3AT,
            x=int(cx[0]),
            y=int(cy[0]),
            theta=int(cth[0]),
            v_mps=v,
            omega_radps=w,
            motors=self.motors,
        )
        return packet.encode()
