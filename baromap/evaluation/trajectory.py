"""Trajectory error measures shared by every mapping evaluation.

An estimated trajectory lives in a frame of its own (SLAM fixes its first pose, not the world's
axes), so it is compared with a reference only after the one rigid 2D motion that brings the
two closest together (least squares over the positions, Umeyama without scale). What remains
is the error the map itself carries: a floor turned against the others, a corridor bent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from baromap.arrays import FloatArray
from baromap.mapping import se2


def fit_rigid(src: FloatArray, dst: FloatArray) -> FloatArray:
    """The 2D rigid transform (x, y, theta) taking points ``src`` onto ``dst`` (least squares)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - cs, dst - cd
    theta = math.atan2(
        float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])),
        float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])),
    )
    c, s = math.cos(theta), math.sin(theta)
    t = cd - np.array([c * cs[0] - s * cs[1], s * cs[0] + c * cs[1]])
    return np.array([t[0], t[1], theta])


@dataclass(frozen=True, slots=True)
class TrajectoryError:
    """Position error after the best rigid alignment (absolute trajectory error, ATE)."""

    rms_m: float
    max_m: float
    alignment: FloatArray  # the rigid motion estimated -> reference frame
    errors_m: FloatArray  # per pose

    def summary(self) -> str:
        return f"{self.rms_m:.3f} m RMS, max {self.max_m:.3f} m"


def trajectory_error(estimated: FloatArray, reference: FloatArray) -> TrajectoryError:
    """ATE of poses (N, 3) against reference poses (N, 3), after a rigid 2D alignment."""
    est = np.asarray(estimated, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    align = fit_rigid(est[:, :2], ref[:, :2])
    moved = se2.transform_points(align, est[:, :2])
    errors = np.hypot(moved[:, 0] - ref[:, 0], moved[:, 1] - ref[:, 1])
    return TrajectoryError(
        rms_m=float(np.sqrt(np.mean(errors**2))) if len(errors) else float("nan"),
        max_m=float(errors.max()) if len(errors) else float("nan"),
        alignment=align,
        errors_m=errors,
    )


def similarity_error(estimated: FloatArray, reference: FloatArray) -> tuple[float, float]:
    """Position RMS of poses (N, 3) against reference poses (N, 3) after the similarity (a
    rigid 2D motion and one scale, Umeyama) that brings them closest, and that scale: what
    of an ATE a uniform stretch of the whole trajectory explains (a scale below 1: the
    estimate is the larger)."""
    est = np.asarray(estimated, dtype=np.float64)[:, :2]
    ref = np.asarray(reference, dtype=np.float64)[:, :2]
    a, b = ref - ref.mean(axis=0), est - est.mean(axis=0)
    u, d, vt = np.linalg.svd(a.T @ b / len(a))
    flip = np.diag([1.0, -1.0 if np.linalg.det(u) * np.linalg.det(vt) < 0 else 1.0])
    rotation = u @ flip @ vt
    scale = float(np.trace(np.diag(d) @ flip) / b.var(axis=0).sum())
    fitted = scale * b @ rotation.T + ref.mean(axis=0)
    return float(np.sqrt(np.mean(np.sum((fitted - ref) ** 2, axis=1)))), scale


def mean_pose_error(estimated: FloatArray, true: FloatArray) -> tuple[float, float]:
    """Mean distance [m] and mean absolute heading difference [deg] of matched poses.

    In the common frame, and magnitudes before the mean: an error expressed in each pose's own
    heading (``se2.between``) turns with the robot, and a constant offset seen from a robot
    that turns round in the lobby would average out to nothing.
    """
    d = np.asarray(estimated, dtype=np.float64) - np.asarray(true, dtype=np.float64)
    distance = float(np.mean(np.hypot(d[:, 0], d[:, 1])))
    return distance, math.degrees(float(np.mean(np.abs(se2.wrap(d[:, 2])))))
