"""Rigid motions in the plane, vectorised over rows of (x, y, theta).

Poses are composed everywhere (odometry, scan matching, pose graph, relations); one
implementation keeps the sign conventions in one place.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray


def wrap(theta: npt.ArrayLike) -> FloatArray:
    """Angles to [-pi, pi)."""
    return np.asarray((np.asarray(theta, dtype=np.float64) + np.pi) % (2 * np.pi) - np.pi)


def compose(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """a (+) b: b expressed in a's frame, moved into a's parent frame."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return np.stack([x, y, wrap(a[..., 2] + b[..., 2])], axis=-1)


def inverse(a: npt.ArrayLike) -> FloatArray:
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return np.stack([x, y, wrap(-a[..., 2])], axis=-1)


def between(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """(-)a (+) b: where b is, seen from a."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx = b[..., 0] - a[..., 0]
    dy = b[..., 1] - a[..., 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, wrap(b[..., 2] - a[..., 2])], axis=-1)


def transform_points(pose: npt.ArrayLike, points: npt.ArrayLike) -> FloatArray:
    """Points (N, 2) in the frame of ``pose`` into its parent frame."""
    pose = np.asarray(pose, dtype=np.float64)
    pts = np.asarray(points, dtype=np.float64)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    out = np.empty_like(pts)
    out[:, 0] = pose[0] + c * pts[:, 0] - s * pts[:, 1]
    out[:, 1] = pose[1] + s * pts[:, 0] + c * pts[:, 1]
    return out
