"""Correlative scan matching (Olson 2009) with a Gauss-Newton finish.

A scan is matched against a likelihood field: each cell holds how plausible it is that a laser
endpoint lands there, exp(-d^2 / 2 sigma^2) with d the distance to the nearest endpoint of the
reference points. The search evaluates every pose of a window (rotations x translations) at
once with numpy gathers, which is robust to the bad starting guesses odometry gives after a
turn; Gauss-Newton on the bilinearly interpolated field then takes the pose below the grid's
quantisation. For the wide windows of loop closure the same search runs first on a
max-filtered copy of the field at a coarser translation step (an upper bound of the fine score,
Olson's multi-resolution trick), and only the best coarse cells are searched finely.

The score of a pose is the mean field value over the scan's points, in [0, 1]: a fraction of
points explained, comparable between scans and so usable as an acceptance threshold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from baromap.mapping import se2

FloatArray = npt.NDArray[np.float64]
Float32Array = npt.NDArray[np.float32]


@dataclass(frozen=True, slots=True)
class LikelihoodField:
    """Endpoint likelihood on a grid; cell (row i, col j) is centred at origin + res * (j, i)."""

    data: Float32Array
    origin_xy: tuple[float, float]
    resolution: float

    @classmethod
    def from_points(
        cls,
        points: FloatArray,
        resolution: float,
        sigma: float,
        bounds: tuple[float, float, float, float] | None = None,
    ) -> LikelihoodField:
        """Stamp a Gaussian kernel around every point (cells keep the largest value).

        ``bounds`` (xmin, ymin, xmax, ymax) limits the grid to where a scan can land; points
        outside it are dropped.
        """
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        radius = max(1, math.ceil(3.0 * sigma / resolution))
        if bounds is None:
            if len(pts) == 0:
                bounds = (0.0, 0.0, 1.0, 1.0)
            else:
                lo = pts.min(axis=0)
                hi = pts.max(axis=0)
                bounds = (lo[0], lo[1], hi[0], hi[1])
        pad = (radius + 2) * resolution
        x0, y0 = bounds[0] - pad, bounds[1] - pad
        width = math.ceil((bounds[2] - bounds[0] + 2 * pad) / resolution) + 1
        height = math.ceil((bounds[3] - bounds[1] + 2 * pad) / resolution) + 1
        data = np.zeros((height, width), dtype=np.float32)
        if len(pts):
            # exact distances from each cell centre to each point, so the field keeps the
            # points' sub-cell positions (quantising them would cost up to half a cell)
            u = (pts[:, 0] - x0) / resolution
            v = (pts[:, 1] - y0) / resolution
            cols = np.rint(u).astype(np.int64)
            rows = np.rint(v).astype(np.int64)
            keep = (
                (cols >= radius)
                & (cols < width - radius)
                & (rows >= radius)
                & (rows < height - radius)
            )
            cols, rows, u, v = cols[keep], rows[keep], u[keep], v[keep]
            offsets = np.arange(-radius, radius + 1)
            di, dj = (a.ravel() for a in np.meshgrid(offsets, offsets, indexing="ij"))
            target_r = rows[:, None] + di[None, :]
            target_c = cols[:, None] + dj[None, :]
            d2 = ((target_c - u[:, None]) ** 2 + (target_r - v[:, None]) ** 2) * resolution**2
            values = np.exp(-d2 / (2 * sigma**2)).astype(np.float32)
            np.maximum.at(data.reshape(-1), (target_r * width + target_c).ravel(), values.ravel())
        return cls(data=data, origin_xy=(x0, y0), resolution=resolution)

    def max_filtered(self, step: int) -> LikelihoodField:
        """Upper bound of the field over any shift of less than ``step`` cells."""
        data = ndimage.maximum_filter(self.data, size=2 * step - 1, mode="constant", cval=0.0)
        return LikelihoodField(data=data, origin_xy=self.origin_xy, resolution=self.resolution)

    def cell_coords(self, xy: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Continuous (col, row) coordinates of world points."""
        return (
            (xy[..., 0] - self.origin_xy[0]) / self.resolution,
            (xy[..., 1] - self.origin_xy[1]) / self.resolution,
        )

    def interpolate(self, xy: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Bilinear value and its world-frame gradient at points (N, 2); zero outside."""
        u, v = self.cell_coords(xy)
        j0 = np.floor(u).astype(np.int64)
        i0 = np.floor(v).astype(np.int64)
        fu = u - j0
        fv = v - i0
        h, w = self.data.shape
        inside = (j0 >= 0) & (j0 < w - 1) & (i0 >= 0) & (i0 < h - 1)
        j0 = np.where(inside, j0, 0)
        i0 = np.where(inside, i0, 0)
        d = self.data
        v00 = d[i0, j0].astype(np.float64)
        v01 = d[i0, j0 + 1].astype(np.float64)
        v10 = d[i0 + 1, j0].astype(np.float64)
        v11 = d[i0 + 1, j0 + 1].astype(np.float64)
        value = (v00 * (1 - fu) + v01 * fu) * (1 - fv) + (v10 * (1 - fu) + v11 * fu) * fv
        du = ((v01 - v00) * (1 - fv) + (v11 - v10) * fv) / self.resolution
        dv = ((v10 - v00) * (1 - fu) + (v11 - v01) * fu) / self.resolution
        zero = ~inside
        value[zero] = 0.0
        du[zero] = 0.0
        dv[zero] = 0.0
        return value, du, dv


@dataclass(frozen=True, slots=True)
class MatchResult:
    pose: FloatArray  # (3,) world pose of the scan's frame
    score: float  # mean field value over the points at ``pose``, in [0, 1]
    information: FloatArray  # (3, 3) Gauss-Newton information of the fit, world frame
    runner_up: float = 0.0  # best score of a clearly different pose (ambiguity), 0 if none


@dataclass(frozen=True, slots=True)
class Prior:
    """Odometry's opinion of the pose: a soft pull towards ``pose`` (Cartographer's
    translation and rotation weights). Where the scan cannot decide, along a featureless
    corridor, the prior decides; where the scan can, a 1 sigma deviation costs only
    ``weight / 2`` of score (a score is a mean likelihood in [0, 1])."""

    pose: FloatArray
    sigma_xy: float
    sigma_theta: float
    weight: float = 0.01


@dataclass(frozen=True, slots=True)
class SearchWindow:
    """Half-widths of the search around the initial guess, and its steps."""

    linear_m: float
    angular_rad: float
    angle_step_rad: float
    coarse_step_cells: int = 1


def _score_grid(
    field: LikelihoodField,
    points: FloatArray,
    center: FloatArray,
    angles: FloatArray,
    offsets: npt.NDArray[np.int64],
) -> Float32Array:
    """Mean field value for every (angle, dy, dx) of the window: shape (A, T, T)."""
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    x = center[0] + c * points[None, :, 0] - s * points[None, :, 1]
    y = center[1] + s * points[None, :, 0] + c * points[None, :, 1]
    cols = np.rint((x - field.origin_xy[0]) / field.resolution).astype(np.int64)
    rows = np.rint((y - field.origin_xy[1]) / field.resolution).astype(np.int64)
    h, w = field.data.shape
    # pad the field once so shifted indices never leave it
    pad = int(np.abs(offsets).max()) + 1
    padded = np.pad(field.data, pad)
    # beyond the field a point sits on the zero border, which shifts cannot cross
    cols = np.clip(cols, -1, w) + pad
    rows = np.clip(rows, -1, h) + pad
    padded_w = w + 2 * pad
    flat = rows * padded_w + cols  # (A, N)
    shift = offsets[:, None] * padded_w + offsets[None, :]  # (T, T): dy rows, dx cols
    values = padded.reshape(-1)[flat[:, :, None, None] + shift[None, None, :, :]]
    scores: Float32Array = values.mean(axis=1, dtype=np.float32)
    return scores


def _prior_penalty(
    prior: Prior | None, angles: FloatArray, dx: FloatArray, dy: FloatArray
) -> FloatArray | float:
    """Score penalty over an (angle, dy, dx) lattice, broadcastable against its scores."""
    if prior is None:
        return 0.0
    da = se2.wrap(angles - prior.pose[2])[:, None, None] / prior.sigma_theta
    ex = (dx[None, None, :] - prior.pose[0]) / prior.sigma_xy
    ey = (dy[None, :, None] - prior.pose[1]) / prior.sigma_xy
    out: FloatArray = 0.5 * prior.weight * (da**2 + ex**2 + ey**2)
    return out


#: How much score a prior-weighted refinement may give up for agreement with odometry.
PRIOR_SCORE_SLACK = 0.01
#: Two lattice poses farther apart than this are different answers, not one blurred peak.
DISTINCT_M = 0.3


def correlative_search(
    field: LikelihoodField,
    points: FloatArray,
    guess: FloatArray,
    window: SearchWindow,
    *,
    coarse_field: LikelihoodField | None = None,
    prior: Prior | None = None,
    keep: int = 6,
) -> tuple[FloatArray, float, float]:
    """Best pose on the window's lattice, its score, and the best score of a distinct pose."""
    res = field.resolution
    half_angles = max(0, round(window.angular_rad / window.angle_step_rad))
    angles = guess[2] + window.angle_step_rad * np.arange(-half_angles, half_angles + 1)
    step = max(1, window.coarse_step_cells)
    half_cells = max(0, math.ceil(window.linear_m / res))
    if step == 1 or coarse_field is None:
        offsets = np.arange(-half_cells, half_cells + 1)
        scores = _score_grid(field, points, guess, angles, offsets)
        xs, ys = guess[0] + offsets * res, guess[1] + offsets * res
        objective = scores - _prior_penalty(prior, angles, xs, ys)
        a, iy, ix = np.unravel_index(int(np.argmax(objective)), objective.shape)
        pose = np.array([xs[ix], ys[iy], angles[a]])
        return pose, float(scores[a, iy, ix]), 0.0
    coarse_half = math.ceil(half_cells / step)
    coarse_offsets = np.arange(-coarse_half, coarse_half + 1) * step
    coarse = _score_grid(coarse_field, points, guess, angles, coarse_offsets)
    cx, cy = guess[0] + coarse_offsets * res, guess[1] + coarse_offsets * res
    # the prior is subtracted from the upper bound too; a bound stays a bound
    coarse_objective = coarse - _prior_penalty(prior, angles, cx, cy)
    order = np.argsort(coarse_objective.reshape(-1))[::-1]
    fine_offsets = np.arange(-(step // 2), step // 2 + 1)
    found: list[tuple[float, float, FloatArray]] = []  # objective, score, pose
    for flat in order[: keep * 4]:
        a, iy, ix = np.unravel_index(int(flat), coarse.shape)
        bound = float(coarse_objective[a, iy, ix])
        if len(found) >= keep and bound <= max(f[0] for f in found):
            break  # an upper bound below the best fine objective cannot win
        center = np.array([cx[ix], cy[iy], angles[a]])
        fine_angles = angles[a] + window.angle_step_rad * np.array([-0.5, 0.0, 0.5])
        scores = _score_grid(field, points, center, fine_angles, fine_offsets)
        fx_all, fy_all = center[0] + fine_offsets * res, center[1] + fine_offsets * res
        objective = scores - _prior_penalty(prior, fine_angles, fx_all, fy_all)
        fa, fy, fx = np.unravel_index(int(np.argmax(objective)), objective.shape)
        pose = np.array([fx_all[fx], fy_all[fy], fine_angles[fa]])
        found.append((float(objective[fa, fy, fx]), float(scores[fa, fy, fx]), pose))
    if not found:
        return np.asarray(guess, dtype=np.float64).copy(), 0.0, 0.0
    found.sort(key=lambda f: f[0], reverse=True)
    best_objective, best_score, best_pose = found[0]
    runner_up = 0.0
    for objective_value, _, pose in found[1:]:
        if np.hypot(*(pose[:2] - best_pose[:2])) > DISTINCT_M:
            # reported on the score's scale: how close a different answer came
            runner_up = best_score - (best_objective - objective_value)
            break
    return best_pose, best_score, runner_up


def refine(
    field: LikelihoodField,
    points: FloatArray,
    pose: FloatArray,
    iterations: int = 12,
    prior: Prior | None = None,
) -> tuple[FloatArray, float, FloatArray]:
    """Gauss-Newton on sum (1 - M(T p))^2; returns pose, score and the fit's information.

    The information is the inverse of the Gauss-Newton covariance: large along directions the
    scan pins down, small along a corridor or for the rotation inside a small symmetric room
    (an elevator car), which is what a pose-graph edge should know.
    """
    current = np.asarray(pose, dtype=np.float64).copy()
    lam = 1e-3

    n = len(points)
    if prior is not None:
        # the same pull as in the lattice search, as residual rows of the least squares
        prior_scale = math.sqrt(n * prior.weight) * np.array(
            [1 / prior.sigma_xy, 1 / prior.sigma_xy, 1 / prior.sigma_theta]
        )

    def evaluate(p: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        world = se2.transform_points(p, points)
        value, gx, gy = field.interpolate(world)
        c, s = math.cos(p[2]), math.sin(p[2])
        dxdt = -s * points[:, 0] - c * points[:, 1]
        dydt = c * points[:, 0] - s * points[:, 1]
        jac = np.stack([gx, gy, gx * dxdt + gy * dydt], axis=1)
        residual = 1.0 - value
        if prior is not None:
            dev = np.array([p[0] - prior.pose[0], p[1] - prior.pose[1], 0.0])
            dev[2] = float(se2.wrap(p[2] - prior.pose[2]))
            residual = np.concatenate([residual, -prior_scale * dev])
            jac = np.vstack([jac, -np.diag(prior_scale)])
        return residual, jac, value

    residual, jac, value = evaluate(current)
    cost = float(residual @ residual)
    for _ in range(iterations):
        hessian = jac.T @ jac
        grad = jac.T @ residual
        try:
            delta = np.linalg.solve(hessian + lam * np.diag(np.diag(hessian) + 1e-9), grad)
        except np.linalg.LinAlgError:
            break
        candidate = current + delta
        r2, j2, v2 = evaluate(candidate)
        c2 = float(r2 @ r2)
        if c2 < cost:
            current, residual, jac, value, cost = candidate, r2, j2, v2, c2
            lam = max(lam / 10, 1e-7)
            if np.abs(delta[:2]).max() < 1e-4 and abs(delta[2]) < 1e-5:
                break
        else:
            lam *= 10
            if lam > 1e3:
                break
    # Gauss-Newton covariance sigma_r^2 (J^T J)^-1 of the scan alone (the prior is the
    # odometry edge's business), returned as its inverse: the residual variance makes a
    # poor fit (clutter, partial overlap) count for less
    scan_r, scan_j = residual[:n], jac[:n]
    dof = max(n - 3, 1)
    sigma2 = max(float(scan_r @ scan_r) / dof, 1e-6)
    information = (scan_j.T @ scan_j) / sigma2
    current[2] = float(se2.wrap(current[2]))
    return current, float(value.mean()) if len(value) else 0.0, information


def match(
    field: LikelihoodField,
    points: FloatArray,
    guess: FloatArray,
    window: SearchWindow,
    *,
    coarse_field: LikelihoodField | None = None,
    prior: Prior | None = None,
) -> MatchResult:
    """Search the window, then refine; the refined pose is kept unless refinement went astray.

    Astray: it slid more than two cells from the lattice optimum, or lost score. With a prior
    the refinement trades a little score for agreement with odometry, so it may lose up to
    ``PRIOR_SCORE_SLACK`` (a 1 % lower mean likelihood) before it counts as a loss.
    """
    lattice_pose, _, runner_up = correlative_search(
        field, points, guess, window, coarse_field=coarse_field, prior=prior
    )
    # compare like with like: the interpolated score at the lattice pose, not the cell lookup
    _, lattice_score, lattice_info = refine(field, points, lattice_pose, iterations=0)
    pose, score, info = refine(field, points, lattice_pose, prior=prior)
    moved = np.hypot(*(pose[:2] - lattice_pose[:2]))
    slack = 0.0 if prior is None else PRIOR_SCORE_SLACK
    if score < lattice_score - slack or moved > 2 * field.resolution:
        return MatchResult(lattice_pose, lattice_score, lattice_info, runner_up)
    return MatchResult(pose, score, info, runner_up)
