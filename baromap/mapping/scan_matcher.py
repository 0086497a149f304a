"""Correlative scan matching (Olson 2009) with a Gauss-Newton finish.

A scan is matched against a likelihood field: each cell holds how plausible it is that a laser
endpoint lands there, exp(-d^2 / 2 sigma^2) with d the distance to the nearest endpoint of the
reference points. The search evaluates every pose of a window (rotations x translations) at
once with numpy gathers, which is robust to the bad starting guesses odometry gives after a
turn; Gauss-Newton on the bilinearly interpolated field then takes the pose below the grid's
quantisation. For wide windows the same search runs first on a max-pooled copy of the field,
a grid a few times coarser whose values bound the fine score from above (Olson's
multi-resolution trick), and only the best coarse cells are searched finely.

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


def kernel_radius(resolution: float, sigma: float) -> int:
    """Cells a point's Gaussian reaches (three sigmas): beyond, its value is below 1 %."""
    return max(1, math.ceil(3.0 * sigma / resolution))


def stamp(
    data: Float32Array,
    origin_xy: tuple[float, float],
    resolution: float,
    sigma: float,
    points: FloatArray,
) -> None:
    """Raise every cell near a point to the point's Gaussian at the cell centre, in place.

    Exact distances from each cell centre to each point, so the field keeps the points'
    sub-cell positions (quantising them to cells would cost up to half a cell of accuracy).
    Points whose kernel would touch the grid's border are dropped: the border stays zero, so
    a lookup clipped to the border reads "nothing here".
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 0:
        return
    height, width = data.shape
    radius = kernel_radius(resolution, sigma)
    u = (pts[:, 0] - origin_xy[0]) / resolution
    v = (pts[:, 1] - origin_xy[1]) / resolution
    cols = np.rint(u).astype(np.int64)
    rows = np.rint(v).astype(np.int64)
    keep = (cols > radius) & (cols < width - 1 - radius) & (rows > radius)
    keep &= rows < height - 1 - radius
    cols, rows, u, v = cols[keep], rows[keep], u[keep], v[keep]
    offsets = np.arange(-radius, radius + 1)
    # the Gaussian is separable: one exponential per row and per column offset, not per cell
    scale = resolution**2 / (2 * sigma**2)
    along_x = np.exp(-(((cols - u)[:, None] + offsets[None, :]) ** 2) * scale)  # (N, 2r+1)
    along_y = np.exp(-(((rows - v)[:, None] + offsets[None, :]) ** 2) * scale)
    values = (along_y[:, :, None] * along_x[:, None, :]).astype(np.float32)  # (N, dy, dx)
    flat = (rows * width + cols)[:, None, None] + (offsets[:, None] * width + offsets[None, :])
    np.maximum.at(data.reshape(-1), flat.ravel(), values.ravel())


@dataclass(frozen=True, slots=True)
class LikelihoodField:
    """Endpoint likelihood on a grid; cell (row i, col j) is centred at origin + res * (j, i).

    The outermost rows and columns are zero (see :func:`stamp`).
    """

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
        """Field of a point set; ``bounds`` (xmin, ymin, xmax, ymax) limits the grid to where
        a scan can land, and points outside it are dropped."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if bounds is None:
            if len(pts) == 0:
                bounds = (0.0, 0.0, 1.0, 1.0)
            else:
                lo = pts.min(axis=0)
                hi = pts.max(axis=0)
                bounds = (lo[0], lo[1], hi[0], hi[1])
        pad = (kernel_radius(resolution, sigma) + 2) * resolution
        x0, y0 = bounds[0] - pad, bounds[1] - pad
        width = math.ceil((bounds[2] - bounds[0] + 2 * pad) / resolution) + 1
        height = math.ceil((bounds[3] - bounds[1] + 2 * pad) / resolution) + 1
        data = np.zeros((height, width), dtype=np.float32)
        stamp(data, (x0, y0), resolution, sigma, pts)
        return cls(data=data, origin_xy=(x0, y0), resolution=resolution)

    def pooled(self, step: int) -> LikelihoodField:
        """An upper bound of the field over any shift of up to ``step // 2`` cells, on a grid
        ``step`` times coarser: the largest value of each ``step`` x ``step`` block, then of
        each block's neighbours (a point's shifted cells straddle at most two blocks).

        Its cells are centred on the blocks' centres, so a lookup at the coarse resolution
        lands in the block (or a neighbour) that holds the point's fine cell.
        """
        h, w = self.data.shape
        bh, bw = -(-h // step), -(-w // step)
        padded = np.zeros((bh * step, bw * step), dtype=np.float32)
        padded[:h, :w] = self.data
        blocks = padded.reshape(bh, step, bw, step).max(axis=(1, 3))
        bound = ndimage.maximum_filter(blocks, size=3, mode="constant", cval=0.0)
        # a zero border again, so clipped lookups beyond the grid still read nothing
        data = np.zeros((bh + 2, bw + 2), dtype=np.float32)
        data[1:-1, 1:-1] = bound
        half = (step - 1) / 2 * self.resolution
        coarse = step * self.resolution
        return LikelihoodField(
            data=data,
            origin_xy=(self.origin_xy[0] + half - coarse, self.origin_xy[1] + half - coarse),
            resolution=coarse,
        )

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
    # a shifted point beyond the field reads the zero border
    shifted_c = np.clip(cols[:, :, None] + offsets[None, None, :], 0, w - 1)  # (A, N, T)
    shifted_r = np.clip(rows[:, :, None] + offsets[None, None, :], 0, h - 1) * w
    flat = shifted_r[:, :, :, None] + shifted_c[:, :, None, :]  # (A, N, T dy, T dx)
    values = field.data.reshape(-1)[flat]
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


#: Most points the lattice search scores (an evenly spaced subset of a denser scan).
LATTICE_POINTS = 120
#: Gauss-Newton stops when a step moves the pose less than this (far below the field's cell).
CONVERGED_M = 5e-4
CONVERGED_RAD = 5e-5
#: How much score a prior-weighted refinement may give up for agreement with odometry.
PRIOR_SCORE_SLACK = 0.01
#: Two lattice poses farther apart than this are different answers, not one blurred peak.
DISTINCT_M = 0.3
#: ... or turned against each other by more than this.
DISTINCT_RAD = math.radians(5.0)


@dataclass(frozen=True, slots=True)
class SearchResult:
    pose: FloatArray
    score: float
    runner_up: float  # score of the best clearly different pose less its prior handicap


def _distinct(a: FloatArray, b: FloatArray) -> bool:
    return bool(
        math.hypot(a[0] - b[0], a[1] - b[1]) > DISTINCT_M
        or abs(float(se2.wrap(a[2] - b[2]))) > DISTINCT_RAD
    )


def correlative_search(
    field: LikelihoodField,
    points: FloatArray,
    guess: FloatArray,
    window: SearchWindow,
    *,
    coarse_field: LikelihoodField | None = None,
    prior: Prior | None = None,
    keep: int = 6,
) -> SearchResult:
    """Best pose on the window's lattice, its score, and how close a distinct pose came.

    With a ``coarse_field`` (``field.pooled(window.coarse_step_cells)``) the window is first
    scored on the coarse grid, an upper bound, and only the best coarse cells are searched
    finely.

    The runner-up is reported on the score's scale with the prior's handicap applied: how
    well a clearly different answer (another door along a corridor, the room turned) did by
    the same measure that chose the best.
    """
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
        far = (np.hypot(xs[None, None, :] - xs[ix], ys[None, :, None] - ys[iy]) > DISTINCT_M) | (
            np.abs(se2.wrap(angles - angles[a]))[:, None, None] > DISTINCT_RAD
        )
        best_objective = float(objective[a, iy, ix])
        runner_up = 0.0
        if far.any():
            other = float(np.max(np.where(far, objective, -np.inf)))
            runner_up = float(scores[a, iy, ix]) - (best_objective - other)
        return SearchResult(pose, float(scores[a, iy, ix]), max(runner_up, 0.0))
    coarse_half = math.ceil(half_cells / step)
    coarse_offsets = np.arange(-coarse_half, coarse_half + 1)
    coarse = _score_grid(coarse_field, points, guess, angles, coarse_offsets)
    cx = guess[0] + coarse_offsets * step * res
    cy = guess[1] + coarse_offsets * step * res
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
        return SearchResult(np.asarray(guess, dtype=np.float64).copy(), 0.0, 0.0)
    found.sort(key=lambda f: f[0], reverse=True)
    best_objective, best_score, best_pose = found[0]
    runner_up = 0.0
    for objective_value, _, pose in found[1:]:
        if _distinct(pose, best_pose):
            runner_up = best_score - (best_objective - objective_value)
            break
    return SearchResult(best_pose, best_score, max(runner_up, 0.0))


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
            if np.abs(delta[:2]).max() < CONVERGED_M and abs(delta[2]) < CONVERGED_RAD:
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
    # the lattice only has to find the optimum's basin: a few hundred points do that as well as
    # all of them, and refinement then uses every point
    sparse = points[:: max(1, math.ceil(len(points) / LATTICE_POINTS))]
    found = correlative_search(field, sparse, guess, window, coarse_field=coarse_field, prior=prior)
    lattice_pose, runner_up = found.pose, found.runner_up
    # compare like with like: the interpolated score at the lattice pose, not the cell lookup
    _, lattice_score, lattice_info = refine(field, points, lattice_pose, iterations=0)
    pose, score, info = refine(field, points, lattice_pose, prior=prior)
    moved = np.hypot(*(pose[:2] - lattice_pose[:2]))
    slack = 0.0 if prior is None else PRIOR_SCORE_SLACK
    if score < lattice_score - slack or moved > 2 * field.resolution:
        pose, score, info = lattice_pose, lattice_score, lattice_info
    return MatchResult(pose, score, info, runner_up)
