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
got wrong, and the systematic part is fitted over all of them:

- distance: matched travel along the odometric direction = ``c`` * odometric travel,
  weighted by the inverse variance of the matched travel (both ends' match covariances
  added), so steps in corridors, where the match is weak along the travel, hardly count; the
  factor is applied once its own uncertainty is well below the error it corrects;
- rotation: odometric turn - matched turn = ``r`` * matched turn + ``k`` * odometric travel,
  odometry's error as a function of the motion made (a wheelbase off by ``r``, wheels that
  creep ``k`` per metre), then inverted. It is fitted that way round because the odometric
  turn carries odometry's noise: on a straight step it is the creep plus the noise, and a
  fit against it takes the noise for a turn error and learns only part of a creep along
  corridors (55-75 % on a ring of long corridors, from perfect matches). Each sample is
  weighted by its whole variance, the match's and odometry's, odometry's found from how far
  the samples scatter; and the fit is a posterior with no error as its prior, applied from
  the first few samples as far as they have shown it (:func:`_fit_turn`).

Both are kept within bounds no working odometry exceeds.

What is left once the systematic part is out is noise, and its size is measured on the same
steps (:func:`fit_noise`): the graph's last solve weighs odometry by it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from baromap.arrays import FloatArray

#: The distance factor is applied once its standard error is below this (0.3 %: 9 cm over a
#: 30 m corridor).
SCALE_SIGMA = 0.003
#: Beyond these the odometry is broken rather than miscalibrated: corrections are clipped.
#: A skid-steer base (the P3-AT) reads turns long by its tyres' sideways slip, tens of
#: percent on a floor other than the one its turn was calibrated on: a calibration to learn
#: (docs/decisions.md, "Odometry calibration").
MAX_SCALE_ERROR = 0.2
MAX_TURN_ERROR = 0.5
MAX_CREEP_RAD_PER_M = math.radians(5.0)
#: Steps shorter than this say nothing about the distance factor (the match's own noise is
#: the whole of the sample).
MIN_STEP_M = 0.05
#: A sample whose residual is beyond this many of its own sigmas from the current fit is a
#: bad match, not odometry: it is left out.
OUTLIER_SIGMAS = 4.0
#: ... beyond that and beyond what the fit so far may still be missing: a few percent of the
#: turn, a couple of degrees per metre (the synthetic logs' creep, twice a P3-AT's). These are
#: also the prior sigmas of the turn terms: the size working odometry's errors have.
TURN_SLACK = 0.05
CREEP_SLACK_RAD_PER_M = math.radians(2.0)


class OdometryCalibration:
    """Running fits of odometry's distance factor (weighted least squares) and turn errors
    (weighted by the samples' whole variance, shrunk towards no error; see :meth:`_fit_turn`)."""

    def __init__(self) -> None:
        # distance: sums of w * a * d and w * d^2
        self._wad = 0.0
        self._wdd = 0.0
        # rotation: every sample kept (one per matched keyframe step, a few thousand at most),
        # since its weight depends on odometry's noise, which is fitted from them all
        # (odometric turn, matched turn, travel, match's heading variance) per sample
        self._turn_samples: list[tuple[float, float, float, float]] = []
        self._turn = np.zeros(2)  # (r, k) as last fitted, see _fit_turn
        self._turn_fitted_at = 0
        #: odometry's turn variance per unit of _turn_noise_feature, as last fitted
        self.turn_noise = 0.0
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
        self._refit_turn()
        r, k = (float(v) for v in self._turn)
        # odometric = true * (1 + r) + k * travel, inverted
        return 1.0 / (1.0 + r) - 1.0, -k / (1.0 + r)

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
        turn_ok = False
        if var_t > 0:
            self._refit_turn()
            r, k = self._turn
            error = float(math.remainder(odometric[2] - matched[2], math.tau))
            expected = r * float(matched[2]) + k * travel
            noise = self.turn_noise * _turn_noise_feature(travel, float(matched[2]))
            slack = TURN_SLACK * abs(odometric[2]) + CREEP_SLACK_RAD_PER_M * travel
            if abs(error - expected) > OUTLIER_SIGMAS * math.sqrt(var_t + noise) + slack:
                self.rejected += 1
                return
            turn_ok = True
        if distance is not None:
            w, along = distance
            self._wad += w * along * travel
            self._wdd += w * travel * travel
        if turn_ok:
            self._turn_samples.append((float(odometric[2]), float(matched[2]), travel, var_t))
        if distance is not None or turn_ok:
            self.samples += 1

    def _refit_turn(self) -> None:
        """Fit the turn terms again once the samples have grown by REFIT_GROWTH (every sample
        while they are few): the fit is over them all, and this keeps its cost near linear."""
        n = len(self._turn_samples)
        if n == self._turn_fitted_at:
            return
        if n >= REFIT_EVERY_SAMPLE_UNTIL and n < self._turn_fitted_at * REFIT_GROWTH:
            return
        self._turn_fitted_at = n
        self._turn, self.turn_noise = _fit_turn(*np.array(self._turn_samples).T)


#: The turn fit waits for this many samples: fewer cannot say how far they scatter.
MIN_TURN_SAMPLES = 5
#: Refit at every sample until there are this many, then when they have grown by this factor.
REFIT_EVERY_SAMPLE_UNTIL = 100
REFIT_GROWTH = 1.05
#: Rounds of the fit (weights from the last round's odometry noise and turn factor).
TURN_FIT_ROUNDS = 3


def _turn_noise_feature(travel: float | FloatArray, turn: float | FloatArray) -> FloatArray:
    """What odometry's turn variance grows with: slip accrues with the distance driven and the
    angle turned, a metre and a radian alike within a factor of two (a P3-AT-sized model's
    0.5 deg a metre against 2 % of the turn, 1.1 deg a radian), as a random walk over a
    step's readings."""
    return np.asarray(np.add(travel, np.abs(turn)), dtype=np.float64)


def _fit_turn(
    odometric: FloatArray, matched: FloatArray, travel: FloatArray, match_var: FloatArray
) -> tuple[FloatArray, float]:
    """(r, k) of odometric turn = matched turn * (1 + r) + k * travel, and odometry's turn
    noise per unit of :func:`_turn_noise_feature` (a variance).

    Odometry's error is fitted against the matched turn, not the odometric one: the odometric
    turn carries odometry's noise, and on a straight step the error to explain is exactly
    minus that noise, so a fit on it takes the noise for a turn error and learns only part of
    a creep along corridors. Each sample is weighted by its whole variance, the match's plus
    odometry's; odometry's is what makes the samples scatter as much as their variances say
    (a reduced chi-square of one, the way a between-sample variance is found in a
    meta-analysis). A sample weighted by the match's variance alone counts as if odometry had
    no noise, so a few early samples from well-pinned rooms pass for a sure fit.

    The fit is a posterior: no turn error is the prior (TURN_SLACK and CREEP_SLACK_RAD_PER_M
    its sigmas, the sizes working odometry has), so a term is applied as far as the samples
    have shown it, early and partly rather than late and at once."""
    n = len(travel)
    if n < MIN_TURN_SAMPLES:
        return np.zeros(2), 0.0
    error = np.remainder(odometric - matched + math.pi, math.tau) - math.pi
    x = np.stack([matched, travel], axis=1)
    feature = _turn_noise_feature(travel, matched)
    prior = np.diag([1.0 / TURN_SLACK**2, 1.0 / CREEP_SLACK_RAD_PER_M**2])
    fit = np.zeros(2)
    noise = 0.0
    for _ in range(TURN_FIT_ROUNDS):
        inflate = (1.0 + fit[0]) ** 2
        residual = error - x @ fit
        noise = _excess_variance(residual**2, inflate * match_var, feature, n - 2)
        w = 1.0 / (inflate * match_var + noise * feature)
        h = (x * w[:, None]).T @ x + prior
        g = (x * w[:, None]).T @ error
        fit = np.linalg.solve(h, g)
    fit[0] = min(MAX_TURN_ERROR, max(-MAX_TURN_ERROR, float(fit[0])))
    fit[1] = min(MAX_CREEP_RAD_PER_M, max(-MAX_CREEP_RAD_PER_M, float(fit[1])))
    return fit, noise


def _excess_variance(
    squared: FloatArray, known: FloatArray, feature: FloatArray, dof: int
) -> float:
    """q >= 0 with sum(squared / (known + q * feature)) = dof: the variance per unit of
    feature the known variances leave unexplained (0 if they explain it all)."""

    def chi2(q: float) -> float:
        return float(np.sum(squared / (known + q * feature)))

    if dof <= 0 or chi2(0.0) <= dof:
        return 0.0
    low, high = 0.0, 1e-6
    while chi2(high) > dof and high < 1e3:
        low, high = high, high * 4.0
    for _ in range(40):
        mid = 0.5 * (low + high)
        if chi2(mid) > dof:
            low = mid
        else:
            high = mid
    return high


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
