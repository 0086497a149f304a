"""Wheel odometry from the P2OS position counters, integrated as ARIA does.

The robot reports 15-bit position counters that wrap and a heading in 1/4096 turn; only the
host knows the robot model's conversion factors. Integration is its own idea, apart from the
wire codec: the daemon, the simulator's recorder and any re-integration of a recording with
corrected factors (the raw counters are kept in every :class:`~baromap.messages.Odometry`)
share it.
"""

from __future__ import annotations

import math
from typing import Final

import structlog

from baromap.messages import Odometry, wrap_angle
from baromap.protocols.p2os import StandardSip
from baromap.protocols.robot_models import RobotModel

log = structlog.get_logger(__name__)

_WRAP: Final = 0x8000
_WRAP_GUARD: Final = 0x1000
_HEADING_UNITS: Final = 4096
#: In a recording, SIPs further apart than this are a break in the stream (the robot sends
#: one every 100 ms): a reconnect, after which the counters may count from zero again
BREAK_S: Final = 1.0
#: What the counters may move across a break beyond the model's top speed times its length
#: and still be the same track (the robot coasting to a stop, the stamps' jitter)
BREAK_SLACK_M: Final = 0.3
#: A robot that counts from zero again reads (0, 0, 0) at its first SIP. Counters this near
#: the origin after a break, from counters that were not, are a new track however near the
#: robot could have driven meanwhile (a power cycle of 12 s gives 15 m of reach, more than
#: the way back to the origin of a small floor)
ORIGIN_M: Final = 0.05
ORIGIN_RAD: Final = math.radians(2.0)


def position_delta(previous: int, current: int) -> int:
    """Change of a 15-bit position counter, unwrapped as ARIA does (|step| <= 0x1000)."""
    delta = current - previous
    if delta > _WRAP_GUARD:
        delta -= _WRAP
    if delta < -_WRAP_GUARD:
        delta += _WRAP
    return delta


def heading_delta(previous: int, current: int) -> int:
    """Change of heading in 1/4096 turn, taking the short way round."""
    return (current - previous + _HEADING_UNITS // 2) % _HEADING_UNITS - _HEADING_UNITS // 2


class OdometryIntegrator:
    """SIPs in, :class:`baromap.messages.Odometry` out, for one robot model.

    Positions accumulate in integer robot units, so hours of driving add no rounding, and
    are scaled only on output. As in ARIA, the first SIP places the robot at its counters
    times DistConvFactor (0, 0 after a SETO); ``origin_at_start`` puts it at 0, 0 instead.
    The heading is the robot's own (absolute, 1/4096 turn), wrapped to (-pi, pi].

    One ``odom`` frame for the whole run, across reconnects: after a :meth:`resume` (the
    host reconnected) the counters either went on (the robot kept its power: the track goes
    on, every tick counted) or read the origin, or moved further than the robot can drive in
    the time (it was power-cycled, or sent SETO, and counts from zero again). Then the
    robot's new frame is joined at the last pose: the motion across the break is lost, but
    the frame stays put, which is what the post-run SLAM and a ``/tf`` consumer need (a jump
    of tens of metres is a pose no robot took). A late SIP alone is no break: the host
    stalled, the robot went on counting (and a stalled demo, its twins playing the mission
    six times faster, would look too fast). ``break_s``: SIPs further apart are checked as
    after a reconnect, for a recording re-integrated without the reconnects' marks
    (:data:`BREAK_S`).
    """

    def __init__(
        self, model: RobotModel, *, origin_at_start: bool = False, break_s: float | None = None
    ) -> None:
        self.model = model
        self.origin_at_start = origin_at_start
        self.break_s = math.inf if break_s is None else break_s
        #: SIPs after which the robot's counters were found to have started again
        self.tracks_joined = 0
        self._last: StandardSip | None = None
        self._last_t_ns = 0
        self._resumed = False
        self._x_units = 0
        self._y_units = 0
        self._theta_units = 0
        # the current track's origin in the run's frame (m, m, rad): zero for the first
        self._anchor = (0.0, 0.0, 0.0)
        self._pose = (0.0, 0.0, 0.0)

    def resume(self, model: RobotModel | None = None) -> None:
        """The host reconnected (perhaps to a robot that reports another model): the next SIP
        is checked for a new track whatever the time since the last."""
        if model is not None and model != self.model:
            self._fold()
            self.model = model
        self._resumed = True

    def update(self, sip: StandardSip, t_ns: int) -> Odometry:
        last = self._last
        if last is None:
            start = not self.origin_at_start
            self._x_units = sip.x if start else 0
            self._y_units = sip.y if start else 0
            self._theta_units = sip.theta
        else:
            dx = position_delta(last.x, sip.x)
            dy = position_delta(last.y, sip.y)
            seconds = (t_ns - self._last_t_ns) / 1e9
            if (self._resumed or seconds > self.break_s) and (
                not self._drivable(dx, dy, seconds)
                or (self._at_origin(sip) and not self._at_origin(last))
            ):
                self._join(sip, seconds)
            else:
                self._x_units += dx
                self._y_units += dy
                self._theta_units += heading_delta(last.theta, sip.theta)
        self._last = sip
        self._last_t_ns = t_ns
        self._resumed = False
        model = self.model
        x, y, theta = self._pose = self._output()
        return Odometry(
            t_ns=t_ns,
            x_m=x,
            y_m=y,
            theta_rad=theta,
            v_mps=(sip.left_vel + sip.right_vel) / 2.0 * model.vel_conv_factor / 1000.0,
            omega_radps=self._omega(sip),
            raw_x=sip.x,
            raw_y=sip.y,
            raw_theta=sip.theta,
        )

    def _drivable(self, dx: int, dy: int, seconds: float) -> bool:
        metres = math.hypot(dx, dy) * self.model.dist_conv_factor / 1000.0
        return metres <= self.model.max_velocity_mmps / 1000.0 * max(seconds, 0.0) + BREAK_SLACK_M

    def _at_origin(self, sip: StandardSip) -> bool:
        ticks = ORIGIN_M * 1000.0 / self.model.dist_conv_factor

        def near(counter: int) -> bool:
            counter &= _WRAP - 1
            return min(counter, _WRAP - counter) <= ticks

        turn = abs(heading_delta(0, sip.theta)) * self.model.angle_conv_factor
        return near(sip.x) and near(sip.y) and turn <= ORIGIN_RAD

    def _join(self, sip: StandardSip, seconds: float) -> None:
        """The counters started again: the robot's new frame begins at the last pose."""
        self.tracks_joined += 1
        log.warning(
            "odometry counters started again: joined at the last pose",
            after_s=round(seconds, 1),
            raw=(sip.x, sip.y, sip.theta),
        )
        x, y, theta = self._pose
        self._anchor = (x, y, theta - sip.theta * self.model.angle_conv_factor)
        self._x_units = self._y_units = 0
        self._theta_units = sip.theta

    def _fold(self) -> None:
        """The track so far into the anchor (before the conversion factors change)."""
        if self._last is None:
            return
        x, y, theta = self._pose
        self._anchor = (x, y, theta - self._theta_units * self.model.angle_conv_factor)
        self._x_units = self._y_units = 0

    def _output(self) -> tuple[float, float, float]:
        model = self.model
        ax, ay, atheta = self._anchor
        ux = self._x_units * model.dist_conv_factor / 1000.0
        uy = self._y_units * model.dist_conv_factor / 1000.0
        if atheta == 0.0:
            x, y = ax + ux, ay + uy
        else:
            c, s = math.cos(atheta), math.sin(atheta)
            x, y = ax + c * ux - s * uy, ay + s * ux + c * uy
        return x, y, wrap_angle(atheta + self._theta_units * model.angle_conv_factor)

    def _omega(self, sip: StandardSip) -> float:
        if sip.rot_vel is not None:
            return math.radians(sip.rot_vel / 10.0)
        half_difference = (sip.right_vel - sip.left_vel) / 2.0 * self.model.vel_conv_factor
        return half_difference * self.model.diff_conv_factor
