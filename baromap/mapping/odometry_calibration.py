"""Odometry's systematic errors, learnt from the scans while mapping.

Wheel odometry errs in two ways: noise that differs step to step, and systematic errors that
stay the same all run long because they come from the robot itself: distance read long or
short by the tyres' radius (a percent or two on a P3-AT, more on an uncalibrated base),
turns read long or short by a skid-steer base's sideways slip (a few percent), a heading creep
per metre from unequal wheels. Scan matching measures the motion wherever the scan pins it
down; along a featureless corridor it does not, and there odometry alone decides, so a 2 %
scale error stretches a 30 m corridor by 60 cm unless it is known.

So every front-end match that pins both ends of a step (a keyframe and the one before it,
both matched with small uncertainty in the direction measured) is a sample of what odometry
got wrong, and the systematic part is fitted by weighted least squares over all of them:

- distance: matched travel along the odometric direction = ``c`` * odometric travel;
- rotation: matched turn - odometric turn = ``a`` * odometric turn + ``b`` * odometric travel.

Each sample is weighted by the inverse variance of the matched quantity (both ends' match
covariances added), so steps in corridors, where the match is weak along the travel, hardly
count. A correction is applied only once its own uncertainty is well below the error it
corrects, and within bounds no working odometry exceeds; until then odometry is used as read.

What is left once the systematic part is out is noise, and its size is measured on the same
steps (:func:`fit_noise`): the graph's last solve weighs odometry by it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import nnls

FloatArray = npt.NDArray[np.float64]

#: The distance factor is applied once its standard error is below this (0.3 %: 9 cm over a
#: 30 m corridor), the rotation terms once theirs are below 0.5 % of a turn and 0.1 deg/m.
SCALE_SIGMA = 0.003
TURN_SIGMA = 0.005
CREEP_SIGMA_RAD_PER_M = math.radians(0.1)
#: Beyond these the odometry is broken rather than miscalibrated: corrections are clipped.
MAX_SCALE_ERROR = 0.2
MAX_TURN_ERROR = 0.2
MAX_CREEP_RAD_PER_M = math.radians(5.0)
#: Steps shorter than this say nothing about the distance factor (the match's own noise is
#: the whole of the sample).
MIN_STEP_M = 0.05
#: A sample whose residual is beyond this many of its own sigmas from the current fit is a
#: bad match, not odometry: it is left out.
OUTLIER_SIGMAS = 4.0
#: ... beyond that and beyond what the fit so far may still be missing: a few percent of the
#: turn, a couple of degrees per metre (the synthetic logs' creep, twice a P3-AT's).
TURN_SLACK = 0.05
CREEP_SLACK_RAD_PER_M = math.radians(2.0)


class OdometryCalibration:
    """Running weighted least squares of odometry's distance factor and turn errors."""

    def __init__(self) -> None:
        # distance: sums of w * a * d and w * d^2
        self._wad = 0.0
        self._wdd = 0.0
        # rotation: normal equations of (a, b) over features (turn, travel)
        self._rot_h = np.zeros((2, 2))
        self._rot_g = np.zeros(2)
        self.samples = 0
        self.rejected = 0

    # ---------------------------------------------------------------- estimates

    def scale(self) -> float:
        """Factor taking odometric travel to true travel (1 until it is known)."""
        if self._wdd <= 0 or 1.0 / math.sqrt(self._wdd) > SCALE_SIGMA:
            return 1.0
        c = self._wad / self._wdd
        return min(1.0 + MAX_SCALE_ERROR, max(1.0 - MAX_SCALE_ERROR, c))

    def turn_terms(self) -> tuple[float, float]:
        """(a, b): true turn = odometric turn * (1 + a) + b * odometric travel."""
        h = self._rot_h
        if np.linalg.det(h) <= 1e-12 * max(1.0, float(np.trace(h)) ** 2):
            return 0.0, 0.0
        cov = np.linalg.inv(h)
        a, b = self._turn_fit()
        a = float(a) if math.sqrt(cov[0, 0]) < TURN_SIGMA else 0.0
        b = float(b) if math.sqrt(cov[1, 1]) < CREEP_SIGMA_RAD_PER_M else 0.0
        a = min(MAX_TURN_ERROR, max(-MAX_TURN_ERROR, a))
        b = min(MAX_CREEP_RAD_PER_M, max(-MAX_CREEP_RAD_PER_M, b))
        return a, b

    def correct(self, step: FloatArray) -> FloatArray:
        """An odometric step (dx, dy, dtheta in the frame of its start) as the robot moved."""
        c = self.scale()
        a, b = self.turn_terms()
        travel = math.hypot(step[0], step[1])
        return np.array(
            [step[0] * c, step[1] * c, step[2] * (1.0 + a) + b * travel], dtype=np.float64
        )

    # ---------------------------------------------------------------- samples

    def observe(self, odometric: FloatArray, matched: FloatArray, covariance: FloatArray) -> None:
        """One step as odometry read it and as matching measured it (same frame, the step's
        start), with the covariance of the matched step (3x3). A step whose travel or turn is
        far from what the fit so far expects is a wrong match, and neither part of it counts."""
        travel = math.hypot(odometric[0], odometric[1])
        distance: tuple[float, float] | None = None  # (weight, matched travel along)
        if travel >= MIN_STEP_M:
            u = np.asarray(odometric[:2]) / travel
            var = float(u @ covariance[:2, :2] @ u)
            if var > 0:
                along = float(u @ matched[:2])
                scale = self._wad / self._wdd if self._wdd > 0 else 1.0
                if abs(along - scale * travel) > OUTLIER_SIGMAS * math.sqrt(var) + 0.02 * travel:
                    self.rejected += 1
                    return
                distance = (1.0 / var, along)
        var_t = float(covariance[2, 2])
        turn: tuple[float, FloatArray, float] | None = None  # (weight, features, residual)
        if var_t > 0:
            x = np.array([odometric[2], travel])
            residual = float(math.remainder(matched[2] - odometric[2], math.tau))
            expected = float(x @ self._turn_fit())
            slack = TURN_SLACK * abs(odometric[2]) + CREEP_SLACK_RAD_PER_M * travel
            if abs(residual - expected) > OUTLIER_SIGMAS * math.sqrt(var_t) + slack:
                self.rejected += 1
                return
            turn = (1.0 / var_t, x, residual)
        if distance is not None:
            w, along = distance
            self._wad += w * along * travel
            self._wdd += w * travel * travel
        if turn is not None:
            w, x, residual = turn
            self._rot_h += w * np.outer(x, x)
            self._rot_g += w * x * residual
        if distance is not None or turn is not None:
            self.samples += 1

    def _turn_fit(self) -> FloatArray:
        """(a, b) fitted so far, whatever their uncertainty (zero before two samples)."""
        h = self._rot_h
        if np.linalg.det(h) <= 1e-12 * max(1.0, float(np.trace(h)) ** 2):
            return np.zeros(2)
        fit: FloatArray = np.asarray(np.linalg.solve(h, self._rot_g), dtype=np.float64)
        return fit


#: A step whose residual is beyond this many sigmas of the noise fitted so far is a wrong
#: match, not odometry: it is left out and the noise fitted again (a few rounds, starting from
#: all steps but the largest 2 % of residuals).
NOISE_OUTLIER_SIGMAS = 4.0
NOISE_START_TRIM = 0.02
NOISE_ROUNDS = 3
#: The noise fit's floor: a step is never known better than this (a standing robot's jitter).
NOISE_FLOOR_M = 0.002
NOISE_FLOOR_RAD = math.radians(0.05)


@dataclass(frozen=True, slots=True)
class OdometryNoise:
    """Variance of a corrected odometric step, as ``c + per_m * travel + per_rad * |turn|``
    (random slip grows with the distance driven and the angle turned), for position (per
    axis) and heading."""

    xy: tuple[float, float, float]
    theta: tuple[float, float, float]

    def sigmas(self, travel: float, turn: float) -> tuple[float, float]:
        """Position (per axis) and heading sigma of one step."""
        xy, theta = self.sigmas_many(np.array([travel]), np.array([turn]))
        return float(xy[0]), float(theta[0])

    def sigmas_many(self, travel: FloatArray, turn: FloatArray) -> tuple[FloatArray, FloatArray]:
        """:meth:`sigmas` of many steps at once."""
        features = np.stack([np.ones_like(travel), travel, np.abs(turn)], axis=1)
        var_xy = np.maximum(features @ np.array(self.xy), 0.0)
        var_theta = np.maximum(features @ np.array(self.theta), 0.0)
        return np.maximum(NOISE_FLOOR_M, np.sqrt(var_xy)), np.maximum(
            NOISE_FLOOR_RAD, np.sqrt(var_theta)
        )


def fit_noise(residuals: FloatArray, travel: FloatArray, turn: FloatArray) -> OdometryNoise:
    """What corrected odometry still gets wrong per step, from steps that matching measured
    at both ends: ``residuals`` (N, 3) matched minus corrected odometric step (its frame).

    The squared residuals are fitted by non-negative least squares on (1, travel, |turn|),
    again without the steps the fit so far calls wrong matches. They hold the matches' own
    errors too, so this is an upper bound of odometry's noise: it is what the steps show, not
    what a robot's data sheet promises.
    """
    x = np.stack([np.ones_like(travel), travel, np.abs(turn)], axis=1)

    def fit(y: FloatArray, features: FloatArray) -> tuple[float, float, float]:
        keep = y <= np.quantile(y, 1.0 - NOISE_START_TRIM)
        coef = np.zeros(3)
        for _ in range(NOISE_ROUNDS):
            coef, _ = nnls(features[keep], y[keep])
            var = np.maximum(features @ coef, 1e-12)
            keep = y <= NOISE_OUTLIER_SIGMAS**2 * var
        return float(coef[0]), float(coef[1]), float(coef[2])

    xy = fit(np.concatenate([residuals[:, 0] ** 2, residuals[:, 1] ** 2]), np.vstack([x, x]))
    theta = fit(residuals[:, 2] ** 2, x)
    return OdometryNoise(xy, theta)
