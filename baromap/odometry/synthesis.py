"""Odometry made from reference poses: what a public log with only corrected poses lacks.

Each step between two reference poses is expressed in the frame of the first, degraded by an
:class:`~baromap.odometry.errors.OdometryErrorModel` and integrated from the first reference
pose, so errors accumulate the way odometry does; a seed makes it reproducible.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray
from baromap.errors import ConfigError
from baromap.odometry.errors import OdometryErrorModel


def synthesize_odometry(
    reference: npt.ArrayLike, seed: int, model: OdometryErrorModel | None = None
) -> FloatArray:
    """Odometry poses (N, 3) made from reference poses (N, 3) by a seeded error model."""
    if seed < 0:
        raise ConfigError(f"the odometry seed must not be negative, got {seed}")
    model = model or OdometryErrorModel()
    ref = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    out = np.empty_like(ref)
    if len(ref) == 0:
        return out
    rng = np.random.default_rng(seed)
    dx_w = np.diff(ref[:, 0])
    dy_w = np.diff(ref[:, 1])
    c, s = np.cos(ref[:-1, 2]), np.sin(ref[:-1, 2])
    forward = c * dx_w + s * dy_w
    side = -s * dx_w + c * dy_w
    dtheta = np.angle(np.exp(1j * np.diff(ref[:, 2])))
    forward_o, side_o, dtheta_o = model.degrade(forward, side, dtheta, rng)
    out[0] = ref[0]
    x, y, theta = ref[0]
    for i in range(len(forward_o)):
        ci, si = math.cos(theta), math.sin(theta)
        x += ci * forward_o[i] - si * side_o[i]
        y += si * forward_o[i] + ci * side_o[i]
        theta = math.remainder(theta + dtheta_o[i], math.tau)
        out[i + 1] = (x, y, theta)
    return out
