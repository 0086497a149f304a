"""Every keyframe against the finished map at once: the last few millimetres of consistency.

The pose graph's match edges were each measured against the map as it stood then, a submap
a few metres long, and their small errors add up along chains; a loop closure ties two
passes through a place together at a few keyframes only. Once the graph has converged, each
keyframe is matched again, now against the finished map of its floor made from all other
keyframes: every revisit of a place constrains it, not just the closures that were found.
The result enters a last solve as an edge from a node of its floor's own frame (one per
floor: the floor keeps its shape and may still turn as a whole against the others), with the
information of its fit (weak along a corridor, where odometry keeps deciding), beside the
odometry, the elevator edges and the matches of the elevator core across floors.

A keyframe must not be matched against a field that holds its own points (it would only find
itself where it already is), so the keyframes of a floor are split in two by parity, and each
half is matched against the field of the other half: a keyframe's neighbours along the run
and every other pass through the place are in the other half.

Gauss-Newton runs for all keyframes of a half at once, their points concatenated: one field
lookup for all of them per iteration, and 3x3 normal equations per keyframe summed with
``np.bincount``, which is what makes a whole run cost a fraction of a second.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray, IntArray
from baromap.mapping import se2
from baromap.mapping.scan_matcher import LikelihoodField

#: Gauss-Newton iterations per refinement (from poses already within a centimetre or two).
ITERATIONS = 6
#: Least share of a keyframe's points that must land on the other half's map for its refined
#: pose to count (a keyframe looking into a room nobody else saw has nothing to agree with).
MIN_SCORE = 0.3
MIN_POINTS = 20
#: A refinement starts within centimetres of the answer; a fit that ends further from its
#: start than the front end's widest search (1.5 m, 45 deg) found other walls, not the
#: same ones better: a scan with little to turn it by (one wall, a corner seen from afar)
#: can be turned anywhere along the field's ridges, and Levenberg-Marquardt with its damping
#: relaxed will go there (keyframes turned by a hundred degrees and more, held there
#: against their odometry, metres off). Such a fit is not usable.
MAX_SHIFT_M = 1.5
MAX_TURN_RAD = np.radians(45.0)


@dataclass(frozen=True, slots=True)
class Refined:
    """Per keyframe of the batch: refined pose, information of the fit (world frame) and
    whether the fit is usable."""

    poses: FloatArray  # (K, 3)
    information: FloatArray  # (K, 3, 3)
    usable: npt.NDArray[np.bool_]


def _normal_equations(
    field: LikelihoodField, points: FloatArray, owner: IntArray, poses: FloatArray, count: int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Per-keyframe J^T J (K, 3, 3), J^T r (K, 3), sum of r^2 (K,) and mean field value."""
    theta = poses[owner, 2]
    c, s = np.cos(theta), np.sin(theta)
    px, py = points[:, 0], points[:, 1]
    world = np.stack([poses[owner, 0] + c * px - s * py, poses[owner, 1] + s * px + c * py], 1)
    value, gx, gy = field.interpolate(world)
    residual = 1.0 - value
    jt = gx * (-s * px - c * py) + gy * (c * px - s * py)
    jac = (gx, gy, jt)
    hessian = np.empty((count, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            hessian[:, a, b] = np.bincount(owner, weights=jac[a] * jac[b], minlength=count)
            hessian[:, b, a] = hessian[:, a, b]
    gradient: FloatArray = np.stack(
        [np.bincount(owner, weights=jac[a] * residual, minlength=count) for a in range(3)], 1
    ).astype(np.float64)
    cost = np.bincount(owner, weights=residual**2, minlength=count)
    score: FloatArray = np.bincount(owner, weights=value, minlength=count) / np.maximum(
        np.bincount(owner, minlength=count), 1
    )
    return hessian, gradient, cost.astype(np.float64), score


@dataclass(frozen=True, slots=True)
class Pull:
    """A soft pull of each pose towards where it started (odometry's opinion), in sigmas: it
    decides where the scan cannot (a corridor).

    Weighed against the scan as two Gaussian measurements are: the scan's squared residuals
    over their own variance (the variance :attr:`Refined.information` uses, taken at the
    start), the deviation from the start over the pull's sigma squared. A fixed weight per
    point (scan_matcher.Prior's 0.01) makes the pull of the scans between keyframes several
    times stronger than its sigmas say, holding them to the interpolation between keyframes,
    which is worse than their fit; with the weighting of a Gaussian and odometry's fitted
    noise as sigmas the local accuracy is better (docs/decisions.md, "The last alignment
    against a finer field").
    """

    sigma_xy: FloatArray  # (K,)
    sigma_theta: FloatArray  # (K,)


def refine_batch(
    field: LikelihoodField,
    points: FloatArray,
    owner: IntArray,
    poses: FloatArray,
    pull: Pull | None = None,
) -> Refined:
    """Levenberg-Marquardt of many poses against one field, each independently.

    ``points`` (M, 2) are in their own pose's frame, ``owner`` (M,) says whose they are.
    """
    count = len(poses)
    sizes = np.bincount(owner, minlength=count)
    start = np.asarray(poses, dtype=np.float64)
    current = start.copy()
    lam = np.full(count, 1e-3)
    scan_h, scan_g, scan_c, score = _normal_equations(field, points, owner, current, count)
    dof = np.maximum(sizes - 3, 1)
    stiff = np.zeros((count, 3))

    if pull is not None:
        # in the scan's units: its cost is the squared residuals, not over their variance
        variance = np.maximum(scan_c / dof, 1e-6)
        stiff = variance[:, None] / np.stack(
            [pull.sigma_xy**2, pull.sigma_xy**2, pull.sigma_theta**2], 1
        )

    def pulled(
        h: FloatArray, g: FloatArray, c: FloatArray, at: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        dev = at - start
        dev[:, 2] = se2.wrap(dev[:, 2])
        h = h.copy()
        h[:, [0, 1, 2], [0, 1, 2]] += stiff
        return h, g - stiff * dev, c + np.sum(stiff * dev**2, axis=1)

    hessian, gradient, cost = pulled(scan_h, scan_g, scan_c, current)
    eye = np.eye(3)
    for _ in range(ITERATIONS):
        damped = hessian + lam[:, None, None] * (hessian * eye + 1e-9 * eye)
        try:
            delta = np.linalg.solve(damped, gradient[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            break
        candidate = current + delta
        h2, g2, c2, s2 = _normal_equations(field, points, owner, candidate, count)
        ph, pg, pc = pulled(h2, g2, c2, candidate)
        better = pc < cost
        current[better] = candidate[better]
        hessian[better], gradient[better], cost[better] = ph[better], pg[better], pc[better]
        scan_h[better], scan_c[better], score[better] = h2[better], c2[better], s2[better]
        lam = np.where(better, np.maximum(lam / 10, 1e-7), np.minimum(lam * 10, 1e3))
    # the information of the scan's own fit (the pull is odometry's, not the scan's)
    sigma2 = np.maximum(scan_c / dof, 1e-6)
    information = scan_h / sigma2[:, None, None]
    current[:, 2] = se2.wrap(current[:, 2])
    moved = np.hypot(current[:, 0] - start[:, 0], current[:, 1] - start[:, 1])
    turned = np.abs(se2.wrap(current[:, 2] - start[:, 2]))
    usable = (
        (sizes >= MIN_POINTS)
        & (score >= MIN_SCORE)
        & (moved <= MAX_SHIFT_M)
        & (turned <= MAX_TURN_RAD)
    )
    return Refined(current, information, usable)


def concatenate(clouds: list[FloatArray]) -> tuple[FloatArray, IntArray]:
    """Clouds as one point array and the index of the cloud each point came from."""
    sizes = np.array([len(c) for c in clouds], dtype=np.int64)
    owner = np.repeat(np.arange(len(clouds)), sizes)
    points = np.concatenate(clouds) if clouds else np.zeros((0, 2))
    return points, owner
