"""What a P3-AT believes about its own motion, and the SIPs it reports it in.

A skid-steered P3-AT misjudges distance a little (tyre wear, load: a translation scale error
of a percent or two) and rotation a lot (the wheels slip sideways when it turns in place: a
rotation scale error of a few percent), and it drifts in heading while driving straight
(uneven tyres: a fraction of a degree per metre). On top comes random slip that grows with
the square root of the distance. :meth:`OdometryErrorModel.random` draws such a robot; these
are what the odometry of a real run looks like and what scan matching has to correct.

The robot integrates its belief in its own units and reports it every SIP cycle (100 ms) as
15-bit position counters (wrapping at 0x8000, about every 15 m on a P3-AT) and a 12-bit
heading; the host unwraps them (``baromap.protocols.OdometryIntegrator``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from baromap.arrays import FloatArray, IntArray
from baromap.odometry.errors import OdometryErrorModel
from baromap.protocols import p2os
from baromap.protocols.robot_models import RobotModel

SIP_PERIOD_S = 0.1


class OdometryModel:
    """The robot's dead reckoning: true increments in, believed pose out (stateful, chunked).

    Errors come from :class:`~baromap.odometry.errors.OdometryErrorModel` (usually
    :meth:`~baromap.odometry.errors.OdometryErrorModel.random`); the belief integrates each
    step along the arc's mean heading, as the robot's controller does between SIPs.
    """

    def __init__(
        self,
        errors: OdometryErrorModel,
        rng: np.random.Generator,
    ) -> None:
        self.errors = errors
        self.rng = rng
        self.x_m = 0.0
        self.y_m = 0.0
        self.theta = 0.0

    def step(self, ds: FloatArray, dtheta: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Believed poses after each of the true increments (forward metres, radians)."""
        ds = np.asarray(ds, dtype=np.float64)
        ds_o, _, dth_o = self.errors.degrade(ds, np.zeros_like(ds), dtheta, self.rng)
        n = ds.shape[0]
        theta = self.theta + np.cumsum(dth_o)
        mid = theta - dth_o / 2.0
        x = self.x_m + np.cumsum(ds_o * np.cos(mid))
        y = self.y_m + np.cumsum(ds_o * np.sin(mid))
        if n:
            self.x_m, self.y_m, self.theta = float(x[-1]), float(y[-1]), float(theta[-1])
        return x, y, theta


def true_increments(
    x: FloatArray, y: FloatArray, theta: FloatArray, prev: tuple[float, float, float]
) -> tuple[FloatArray, FloatArray]:
    """Forward distance and heading change between consecutive true poses (after ``prev``)."""
    xs = np.concatenate([[prev[0]], x])
    ys = np.concatenate([[prev[1]], y])
    ths = np.concatenate([[prev[2]], theta])
    dx, dy = np.diff(xs), np.diff(ys)
    heading = ths[:-1]
    ds = dx * np.cos(heading) + dy * np.sin(heading)
    dth = np.angle(np.exp(1j * np.diff(ths)))
    return ds, dth


def counters(
    model: RobotModel, x_m: FloatArray, y_m: FloatArray, theta: FloatArray
) -> tuple[IntArray, IntArray, IntArray]:
    """The SIP's wrapped 15-bit position counters and its heading in 1/4096 turn (signed)."""
    units = model.dist_conv_factor / 1000.0
    cx = np.round(np.asarray(x_m) / units).astype(np.int64) & p2os.POSITION_MASK
    cy = np.round(np.asarray(y_m) / units).astype(np.int64) & p2os.POSITION_MASK
    th = np.round(np.asarray(theta) / model.angle_conv_factor).astype(np.int64)
    th = (th + 2048) % 4096 - 2048
    return cx, cy, th


def sip(
    model: RobotModel,
    *,
    x: int,
    y: int,
    theta: int,
    v_mps: float,
    omega_radps: float,
    motors: bool,
    battery_dv: int = 128,
    arcos_tail: bool = False,
) -> p2os.StandardSip:
    """One standard SIP with wheel speeds from the believed velocities.

    ``arcos_tail`` appends what ARCOS firmware sends after the sonar readings (timer, analog
    and digital I/O, battery in 0.1 V, charge state, rotational velocity in 0.1 deg/s, fault
    flags), which ARIA reads when the bytes are there.
    """
    v_mm = v_mps * 1000.0 / model.vel_conv_factor
    half_diff = omega_radps / model.diff_conv_factor / model.vel_conv_factor
    left = round(v_mm - half_diff)
    right = round(v_mm + half_diff)
    tail: dict[str, Any] = {}
    if arcos_tail:
        tail = dict(
            timer=0,
            analog=0,
            digital_in=0,
            digital_out=0,
            battery_x10=battery_dv,
            charge_state=0,
            rot_vel=round(math.degrees(omega_radps) * 10.0),
            fault_flags=0,
        )
    return p2os.StandardSip(
        moving=bool(left or right),
        x=int(x),
        y=int(y),
        theta=int(theta),
        left_vel=int(left),
        right_vel=int(right),
        battery_dv=battery_dv,
        stall_bumpers=0,
        control=int(theta),
        flags=0x01 if motors else 0x00,
        compass=0,
        **tail,
    )
