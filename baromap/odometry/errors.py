"""How wheel odometry goes wrong: one error model for every part that needs bad odometry.

Two parts degrade true motion into odometry: the simulated P3-AT (its dead reckoning between
SIPs) and the synthesis of odometry for public logs that carry only corrected poses. Both use
this model, step by step in the robot's frame of the previous pose.

Systematic errors: distance read long by ``scale`` (tyre radius off, load), rotation read long
by ``rotation_scale`` (a skid-steered base slips sideways when it turns in place), and a heading
creep of ``drift_rad_per_m`` per metre travelled (unequal wheels). Random errors: zero-mean
Gaussian noise per step whose standard deviation has a part proportional to the step (the
classic odometry motion model: ``sigma_*_per_m``, ``sigma_rot_per_rad``) and a part growing
with the square root of it (a random walk, independent of how finely the motion is sampled:
``sigma_*_per_sqrt_*``); lateral slip only if ``sigma_side_per_m`` is set.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from baromap.arrays import FloatArray
from baromap.errors import ConfigError


@dataclass(frozen=True, slots=True)
class OdometryErrorModel:
    """Systematic and random odometry errors; the defaults are the synthesis model.

    Defaults: 5 % scale, 2 deg/m heading drift, 2 % translation and lateral noise per metre,
    0.5 deg/m and 2 % of the rotation as rotation noise: an uncalibrated skid-steer base, what
    ``baromap import carmen --synth-odometry`` applies. :meth:`random` draws one simulated
    robot's errors instead.
    """

    scale: float = 0.05
    rotation_scale: float = 0.0
    drift_rad_per_m: float = math.radians(2.0)
    sigma_trans_per_m: float = 0.02
    sigma_trans_per_sqrt_m: float = 0.0
    sigma_side_per_m: float = 0.02
    sigma_rot_per_m: float = math.radians(0.5)
    sigma_rot_per_rad: float = 0.02
    sigma_rot_per_sqrt_rad: float = 0.0

    def __post_init__(self) -> None:
        values = [getattr(self, name) for name in self.__slots__]
        if not all(math.isfinite(v) for v in values):
            raise ConfigError("odometry error parameters must be finite")
        if min(values[3:]) < 0:
            raise ConfigError("odometry noise levels must not be negative")

    @classmethod
    def exact(cls) -> OdometryErrorModel:
        """No error at all: odometry that reads the true motion."""
        return cls(
            scale=0.0,
            drift_rad_per_m=0.0,
            sigma_trans_per_m=0.0,
            sigma_side_per_m=0.0,
            sigma_rot_per_m=0.0,
            sigma_rot_per_rad=0.0,
        )

    @classmethod
    def random(cls, rng: np.random.Generator) -> OdometryErrorModel:
        """One simulated P3-AT: scale 0.5-2 %, rotation 1-4 %, drift 0.2-0.8 deg/m, random walk."""

        def signed(lo: float, hi: float) -> float:
            return float(rng.choice([-1.0, 1.0]) * rng.uniform(lo, hi))

        return cls(
            scale=signed(0.005, 0.02),
            rotation_scale=signed(0.01, 0.04),
            drift_rad_per_m=signed(math.radians(0.2), math.radians(0.8)),
            sigma_trans_per_m=0.0,
            sigma_trans_per_sqrt_m=0.01,
            sigma_side_per_m=0.0,
            sigma_rot_per_m=0.0,
            sigma_rot_per_rad=0.0,
            sigma_rot_per_sqrt_rad=math.radians(1.0),
        )

    def correction(self) -> tuple[float, float, float]:
        """What undoes the systematic part, in the terms odometry calibration learns
        (``SlamResult.odometry_correction``): the factor taking odometric travel to true
        travel, the turn factor minus one, and the creep in radians per odometric metre
        (true turn = odometric turn * (1 + a) + creep * odometric travel). Odometry reads
        a turn as ``turn * (1 + rotation_scale) + drift * travel``, travel ``1 + scale``
        times long: so the creep is the drift, divided by both."""
        gain = 1.0 + self.scale
        turn = 1.0 + self.rotation_scale
        return 1.0 / gain, 1.0 / turn - 1.0, -self.drift_rad_per_m / (turn * gain)

    def as_dict(self) -> dict[str, float]:
        """For metadata: angles in degrees."""
        return {
            "scale": self.scale,
            "rotation_scale": self.rotation_scale,
            "drift_deg_per_m": math.degrees(self.drift_rad_per_m),
            "sigma_trans_per_m": self.sigma_trans_per_m,
            "sigma_trans_per_sqrt_m": self.sigma_trans_per_sqrt_m,
            "sigma_side_per_m": self.sigma_side_per_m,
            "sigma_rot_deg_per_m": math.degrees(self.sigma_rot_per_m),
            "sigma_rot_per_rad": self.sigma_rot_per_rad,
            "sigma_rot_deg_per_sqrt_rad": math.degrees(self.sigma_rot_per_sqrt_rad),
        }

    def degrade(
        self, forward: FloatArray, side: FloatArray, dtheta: FloatArray, rng: np.random.Generator
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Steps as odometry reads them: (forward, lateral, rotation) of each step.

        Noise is drawn forward first, then lateral (only when the model has lateral noise),
        then rotation, one value per step each.
        """
        forward = np.asarray(forward, dtype=np.float64)
        side = np.asarray(side, dtype=np.float64)
        dtheta = np.asarray(dtheta, dtype=np.float64)
        n = forward.shape[0]
        dist = np.hypot(forward, side)
        gain = 1.0 + self.scale
        walk = np.sqrt(dist)
        noise = rng.standard_normal(n)
        forward_o = (
            forward * gain
            + noise * self.sigma_trans_per_m * dist
            + noise * self.sigma_trans_per_sqrt_m * walk
        )
        side_o = side * gain
        if self.sigma_side_per_m > 0:
            side_o = side_o + rng.standard_normal(n) * self.sigma_side_per_m * dist
        turn = np.abs(dtheta)
        rot_sigma = self.sigma_rot_per_m * dist + self.sigma_rot_per_rad * turn
        noise = rng.standard_normal(n)
        dtheta_o = (
            dtheta * (1.0 + self.rotation_scale)
            + self.drift_rad_per_m * dist
            + noise * rot_sigma
            + noise * self.sigma_rot_per_sqrt_rad * np.sqrt(turn)
        )
        return forward_o, side_o, dtheta_o
