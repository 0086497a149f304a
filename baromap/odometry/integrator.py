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

from baromap.messages import Odometry, wrap_angle
from baromap.protocols.p2os import StandardSip
from baromap.protocols.robot_models import RobotModel

_WRAP: Final = 0x8000
_WRAP_GUARD: Final = 0x1000
_HEADING_UNITS: Final = 4096


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
    """

    def __init__(self, model: RobotModel, *, origin_at_start: bool = False) -> None:
        self.model = model
        self.origin_at_start = origin_at_start
        self._last: StandardSip | None = None
        self._x_units = 0
        self._y_units = 0
        self._theta_units = 0

    def reset(self) -> None:
        """Forget the history: the next SIP starts a new track (after SETO or reconnect)."""
        self._last = None

    def update(self, sip: StandardSip, t_ns: int) -> Odometry:
        last = self._last
        if last is None:
            start = not self.origin_at_start
            self._x_units = sip.x if start else 0
            self._y_units = sip.y if start else 0
            self._theta_units = sip.theta
        else:
            self._x_units += position_delta(last.x, sip.x)
            self._y_units += position_delta(last.y, sip.y)
            self._theta_units += heading_delta(last.theta, sip.theta)
        self._last = sip
        model = self.model
        mm = model.dist_conv_factor
        return Odometry(
            t_ns=t_ns,
            x_m=self._x_units * mm / 1000.0,
            y_m=self._y_units * mm / 1000.0,
            theta_rad=wrap_angle(self._theta_units * model.angle_conv_factor),
            v_mps=(sip.left_vel + sip.right_vel) / 2.0 * model.vel_conv_factor / 1000.0,
            omega_radps=self._omega(sip),
            raw_x=sip.x,
            raw_y=sip.y,
            raw_theta=sip.theta,
        )

    def _omega(self, sip: StandardSip) -> float:
        if sip.rot_vel is not None:
            return math.radians(sip.rot_vel / 10.0)
        half_difference = (sip.right_vel - sip.left_vel) / 2.0 * self.model.vel_conv_factor
        return half_difference * self.model.diff_conv_factor
