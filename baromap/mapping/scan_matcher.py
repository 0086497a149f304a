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

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from baromap.arrays import Float32Array, FloatArray
from baromap.mapping import se2


def kernel_radius(resolution: float, sigma: float) -> int:
    """Cells a point's Gaussian reaches (three sigmas): beyond, its value is below 1 %."""
    return max(1, math.ceil(3.0 * sigma / resolution))


#: Points stamped at a time (a few MB in flight).
STAMP_CHUNK = 8192


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
    # a kernel's cells cost ~1 KB a point in flight: a whole run's points at once (the last
    # solve's field of every scan, a large hall driven four times) hold 0.6 GB; a maximum is
    # the same taken in parts
    for start in range(0, len(pts), STAMP_CHUNK):
        _stamp_part(data, origin_xy, resolution, sigma, pts[start : start + STAMP_CHUNK])


def _stamp_part(
    data: Float32Array,
    origin_xy: tuple[float, float],
    resolution: float,
    sigma: float,
    pts: FloatArray,
) -> None:
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


def _block_max(data: Float32Array, step: int) -> Float32Array:
    """Largest value of each ``step`` x ``step`` block of ``data`` (its sides are multiples
    of ``step``).

    One strided ``np.maximum`` per row and column of a block: a ``max`` over the axes of a
    reshaped view walks memory out of order, 13 ms on a 1200 x 1400 field against 0.7 ms
    this way.
    """
    h, w = data.shape
    cols = data.reshape(h, w // step, step)
    across: Float32Array = cols[:, :, 0].copy()
    for i in range(1, step):
        np.maximum(across, cols[:, :, i], out=across)
    rows = across.reshape(h // step, step, w // step)
    out: Float32Array = rows[:, 0].copy()
    for i in range(1, step):
        np.maximum(out, rows[:, i], out=out)
    return out


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
        blocks = _block_max(padded, step)
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
    runner_up_pose: FloatArray | None = None  # that pose (on the search lattice), None if none


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


#: Most (angle, point, dy, dx) cells the lattice is scored in at once. A front-end window
#: of 38 degrees at a quarter degree, 0.9 m either way and 96 points holds 40 million, and
#: scored whole its index and value arrays hold 2 GB (a sparse log after a turn); blocks of
#: angles score the same values in a few tens of megabytes.
LATTICE_BLOCK_CELLS = 1 << 22


def _score_grid(
    field: LikelihoodField,
    points: FloatArray,
    center: FloatArray,
    angles: FloatArray,
    offsets: npt.NDArray[np.int64],
) -> Float32Array:
    """Mean field value for every (angle, dy, dx) of the window: shape (A, T, T).

    ``center`` is one (x, y) for all angles, or one per angle (A, 2).
    """
    per_angle = max(1, len(points) * len(offsets) ** 2)
    block = max(1, LATTICE_BLOCK_CELLS // per_angle)
    h, w = field.data.shape
    flat_field = field.data.reshape(-1)
    parts: list[Float32Array] = []
    for first in range(0, max(1, len(angles)), block):
        part = angles[first : first + block]
        c, s = np.cos(part)[:, None], np.sin(part)[:, None]
        if center.ndim == 1:
            cx, cy = center[0], center[1]
        else:
            cx, cy = center[first : first + block, :1], center[first : first + block, 1:2]
        x = cx + c * points[None, :, 0] - s * points[None, :, 1]
        y = cy + s * points[None, :, 0] + c * points[None, :, 1]
        cols = np.rint((x - field.origin_xy[0]) / field.resolution).astype(np.int64)
        rows = np.rint((y - field.origin_xy[1]) / field.resolution).astype(np.int64)
        # a shifted point beyond the field reads the zero border
        shifted_c = _clamp(cols[:, :, None] + offsets[None, None, :], w - 1)  # (A, N, T)
        shifted_r = _clamp(rows[:, :, None] + offsets[None, None, :], h - 1) * w
        flat = shifted_r[:, :, :, None] + shifted_c[:, :, None, :]  # (A, N, T dy, T dx)
        parts.append(_mean_over(flat_field[flat], axis=1))
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def _clamp(cells: npt.NDArray[np.int64], last: int) -> npt.NDArray[np.int64]:
    """Cell indices held to [0, last], in place: ``np.clip``'s own checks of its bounds cost
    more than the clamp on the few thousand cells of a search node."""
    np.maximum(cells, 0, out=cells)
    return np.minimum(cells, last, out=cells)


def _mean_over(values: Float32Array, axis: int) -> Float32Array:
    """``values.mean(axis, dtype=float32)`` to the bit, without ``mean``'s per-call
    bookkeeping (a search node's mean is over a few thousand values)."""
    total: Float32Array = np.add.reduce(values, axis=axis, dtype=np.float32)
    return np.true_divide(total, np.intp(values.shape[axis]), out=total, casting="unsafe")


class _NodeScorer:
    """Scores the cells of one branch-and-bound node at one of the window's headings.

    A wide search splits hundreds of nodes, most at a few headings; the scan rotated to a
    heading (and the prior's pull at it) is worked out once per heading rather than once per
    node. Every value is computed by the same operations as :func:`_score_grid` and
    :func:`_prior_penalty`, so a search gives the same answer to the bit.
    """

    def __init__(
        self, field: LikelihoodField, points: FloatArray, angles: FloatArray, prior: Prior | None
    ) -> None:
        self._px, self._py = points[:, 0], points[:, 1]
        self._angles = angles
        self._prior = prior
        self._origin_x, self._origin_y = field.origin_xy
        self._resolution = field.resolution
        self._shape = field.data.shape
        self._rotated: dict[int, tuple[FloatArray, FloatArray, FloatArray, FloatArray]] = {}
        self._heading_penalty: dict[int, FloatArray] = {}

    def _rotation(self, a: int) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        found = self._rotated.get(a)
        if found is None:
            part = self._angles[a : a + 1]
            c, s = np.cos(part), np.sin(part)
            found = (c * self._px, s * self._py, s * self._px, c * self._py)
            self._rotated[a] = found
        return found

    def scores(
        self, field: LikelihoodField, a: int, x: float, y: float, offsets: npt.NDArray[np.int64]
    ) -> Float32Array:
        """Mean field value at every (dy, dx) of ``offsets`` around (x, y): shape (T, T)."""
        cpx, spy, spx, cpy = self._rotation(a)
        h, w = self._shape
        cols = np.rint(((x + cpx) - spy - self._origin_x) / self._resolution).astype(np.int64)
        rows = np.rint(((y + spx) + cpy - self._origin_y) / self._resolution).astype(np.int64)
        shifted_c = _clamp(cols[:, None] + offsets, w - 1)  # (N, T)
        shifted_r = _clamp(rows[:, None] + offsets, h - 1) * w
        flat = shifted_r[:, :, None] + shifted_c[:, None, :]  # (N, T dy, T dx)
        return _mean_over(field.data.reshape(-1)[flat], axis=0)

    def penalty(self, a: int, xs: FloatArray, ys: FloatArray) -> FloatArray | float:
        """:func:`_prior_penalty` at heading ``a`` over the cells (ys x xs): shape (T, T)."""
        prior = self._prior
        if prior is None:
            return 0.0
        heading = self._heading_penalty.get(a)
        if heading is None:
            da = se2.wrap(self._angles[a : a + 1] - prior.pose[2]) / prior.sigma_theta
            heading = da**2
            self._heading_penalty[a] = heading
        ex = (xs - prior.pose[0]) / prior.sigma_xy
        ey = (ys - prior.pose[1]) / prior.sigma_xy
        out: FloatArray = 0.5 * prior.weight * ((heading + ex[None, :] ** 2) + ey[:, None] ** 2)
        return out


def _prior_penalty(
    prior: Prior | None, angles: FloatArray, xs: FloatArray, ys: FloatArray
) -> FloatArray | float:
    """Score penalty over an (angle, y, x) lattice, broadcastable against its scores: ``xs``
    and ``ys`` are the lattice's coordinates, one row (T,) for every angle or one row per
    angle (A, T)."""
    if prior is None:
        return 0.0
    da = se2.wrap(angles - prior.pose[2])[:, None, None] / prior.sigma_theta
    ex = (np.atleast_2d(xs)[:, None, :] - prior.pose[0]) / prior.sigma_xy
    ey = (np.atleast_2d(ys)[:, :, None] - prior.pose[1]) / prior.sigma_xy
    out: FloatArray = 0.5 * prior.weight * (da**2 + ex**2 + ey**2)
    return out


#: Most points the lattice search scores (an evenly spaced subset of a denser scan).
LATTICE_POINTS = 120
#: Gauss-Newton stops when a step moves the pose less than this (far below the field's cell).
CONVERGED_M = 5e-4
CONVERGED_RAD = 5e-5
#: ... or when a step lowers the cost by less than this share of it.
CONVERGED_COST = 1e-4
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
    runner_up_pose: FloatArray | None = None


def _window_angles(guess: FloatArray, window: SearchWindow) -> FloatArray:
    """The headings a search tries: the guess's, and steps of the window's angle step either
    side of it out to its angular half-width."""
    half = max(0, round(window.angular_rad / window.angle_step_rad))
    angles: FloatArray = guess[2] + window.angle_step_rad * np.arange(-half, half + 1)
    return angles


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
    finely (:func:`_coarse_to_fine`); without one, every pose of the lattice is scored
    (:func:`_every_pose`).

    The runner-up is reported on the score's scale with the prior's handicap applied: how
    well a clearly different answer (another door along a corridor, the room turned) did by
    the same measure that chose the best.
    """
    if max(1, window.coarse_step_cells) == 1 or coarse_field is None:
        return _every_pose(field, points, guess, window, prior)
    found = _coarse_to_fine(field, coarse_field, points, guess, window, prior=prior, keep=keep)
    if not found:
        return SearchResult(np.asarray(guess, dtype=np.float64).copy(), 0.0, 0.0)
    return _best_and_runner_up(found)


def _every_pose(
    field: LikelihoodField,
    points: FloatArray,
    guess: FloatArray,
    window: SearchWindow,
    prior: Prior | None,
) -> SearchResult:
    """Every pose of the lattice scored at once; the runner-up is the best pose distinct
    from the best (:data:`DISTINCT_M`, :data:`DISTINCT_RAD`)."""
    res = field.resolution
    angles = _window_angles(guess, window)
    half_cells = max(0, math.ceil(window.linear_m / res))
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
    runner_pose = None
    if far.any():
        masked = np.where(far, objective, -np.inf)
        ra, ry, rx = np.unravel_index(int(np.argmax(masked)), masked.shape)
        runner_up = float(scores[a, iy, ix]) - (best_objective - float(masked[ra, ry, rx]))
        runner_pose = np.array([xs[rx], ys[ry], angles[ra]])
    return SearchResult(pose, float(scores[a, iy, ix]), max(runner_up, 0.0), runner_pose)


def _coarse_to_fine(
    field: LikelihoodField,
    coarse_field: LikelihoodField,
    points: FloatArray,
    guess: FloatArray,
    window: SearchWindow,
    *,
    prior: Prior | None,
    keep: int,
) -> list[tuple[float, float, FloatArray]]:
    """The window scored on the coarse field, then the best coarse cells, ``keep`` at a time,
    searched on the fine lattice around them until no coarse bound left can beat the best
    fine objective: (objective, score, pose) of each searched cell's best."""
    res = field.resolution
    angles = _window_angles(guess, window)
    step = max(1, window.coarse_step_cells)
    half_cells = max(0, math.ceil(window.linear_m / res))
    coarse_half = math.ceil(half_cells / step)
    coarse_offsets = np.arange(-coarse_half, coarse_half + 1)
    coarse = _score_grid(coarse_field, points, guess, angles, coarse_offsets)
    cx = guess[0] + coarse_offsets * step * res
    cy = guess[1] + coarse_offsets * step * res
    # the prior is subtracted from the upper bound too; a bound stays a bound
    coarse_objective = coarse - _prior_penalty(prior, angles, cx, cy)
    order = np.argsort(coarse_objective.reshape(-1))[::-1]
    flat_bound = coarse_objective.reshape(-1)
    fine_offsets = np.arange(-(step // 2), step // 2 + 1)
    half_step = window.angle_step_rad * np.array([-0.5, 0.0, 0.5])
    found: list[tuple[float, float, FloatArray]] = []  # objective, score, pose
    done = 0
    while done < min(len(order), 4 * keep):
        # the best coarse cells in one batch: each gets the fine lattice around it
        batch = order[done : done + keep]
        done += len(batch)
        ba, by, bx = np.unravel_index(batch, coarse.shape)
        fine_angles = (angles[ba][:, None] + half_step[None, :]).ravel()  # (B * 3,)
        centers = np.repeat(np.stack([cx[bx], cy[by]], axis=1), 3, axis=0)
        scores = _score_grid(field, points, centers, fine_angles, fine_offsets)
        dx = centers[:, 0][:, None] + fine_offsets[None, :] * res  # (B * 3, T)
        dy = centers[:, 1][:, None] + fine_offsets[None, :] * res
        objective = scores - _prior_penalty(prior, fine_angles, dx, dy)
        for b in range(len(batch)):
            block = objective[3 * b : 3 * b + 3]
            fa, fy, fx = np.unravel_index(int(np.argmax(block)), block.shape)
            row = 3 * b + fa
            pose = np.array([dx[row, fx], dy[row, fy], fine_angles[row]])
            found.append((float(block[fa, fy, fx]), float(scores[row, fy, fx]), pose))
        best = max(f[0] for f in found)
        if done >= len(order) or flat_bound[order[done]] <= best:
            break  # every remaining upper bound is below the best fine objective
    return found


def _best_and_runner_up(found: list[tuple[float, float, FloatArray]]) -> SearchResult:
    """The best of the (objective, score, pose) found, and the best distinct from it as the
    runner-up, on the score's scale with the prior's handicap applied."""
    found.sort(key=lambda f: f[0], reverse=True)
    best_objective, best_score, best_pose = found[0]
    runner_up = 0.0
    runner_pose = None
    for objective_value, _, pose in found[1:]:
        if _distinct(pose, best_pose):
            runner_up = best_score - (best_objective - objective_value)
            runner_pose = pose
            break
    return SearchResult(best_pose, best_score, max(runner_up, 0.0), runner_pose)


#: Node sizes of the branch-and-bound search, in cells, coarsest first: a node of 16 cells
#: (0.8 m at 5 cm) branches into nodes of 4, which branch into single cells.
BNB_STEPS = (16, 4, 1)
#: The search keeps looking for a runner-up until no node left can reach this share of the
#: best: below it no caller's ambiguity test (0.95, 0.97) can be failed.
RUNNER_UP_FLOOR = 0.9
#: Most nodes one search splits.
BNB_BUDGET = 300


def _bound_field(field: LikelihoodField, step: int) -> LikelihoodField:
    """The field's largest value within +-step/2 cells of each cell: what any point of a scan
    can score anywhere in a node of ``step`` x ``step`` cells centred on its cell."""
    if step <= 1:
        return field
    data = ndimage.maximum_filter(field.data, size=step + 1, mode="constant", cval=0.0)
    return LikelihoodField(data=data, origin_xy=field.origin_xy, resolution=field.resolution)


def branch_and_bound_search(
    field: LikelihoodField,
    points: FloatArray,
    guess: FloatArray,
    window: SearchWindow,
    *,
    prior: Prior | None = None,
    budget: int | None = None,
) -> SearchResult:
    """Best pose of a wide window by depth-first branch and bound (Hess et al. 2016).

    Every rotation of the window is scored on a lattice of 16-cell nodes against the field's
    maximum over each node (an upper bound of every pose inside it); nodes are taken best
    bound first and split into 4-cell nodes, then cells, and a node whose bound cannot beat
    what was found is not split. For a loop closure after a long stretch without one, where
    the drift is metres: a lattice of that size is millions of poses, most never scored.

    ``budget`` bounds the nodes split (CPU; default ``BNB_BUDGET``); when it runs out, the
    best cell found so far is returned. The runner-up is the best cell distinct from the best
    (:func:`_distinct`), kept while no node left can reach ``RUNNER_UP_FLOOR`` of the best.
    """
    res = field.resolution
    angles = _window_angles(guess, window)
    levels = [_bound_field(field, step) for step in BNB_STEPS]
    half_cells = max(0, math.ceil(window.linear_m / res))
    top = BNB_STEPS[0]
    top_half = math.ceil(half_cells / top)
    offsets = np.arange(-top_half, top_half + 1) * top
    xs = guess[0] + offsets * res
    ys = guess[1] + offsets * res
    bounds = _score_grid(levels[0], points, guess, angles, offsets) - _prior_penalty(
        prior, angles, xs, ys
    )
    flat_bounds = bounds.ravel()
    order = np.argsort(flat_bounds)[::-1]
    search = _DepthFirst(
        levels, _NodeScorer(field, points, angles, prior), angles, res,
        BNB_BUDGET if budget is None else budget,
    )  # fmt: skip
    # the top nodes best bound first, each searched depth first before the next
    for top_node in order:
        if search.exhausted():
            break
        if search.beaten(flat_bounds[top_node]):
            break  # every remaining top node is bounded lower still
        a, iy, ix = np.unravel_index(top_node, bounds.shape)
        search.descend(float(flat_bounds[top_node]), int(a), float(xs[ix]), float(ys[iy]))
    return search.result(guess)


class _DepthFirst:
    """What one branch-and-bound search has found so far (the best cell, the best cell
    distinct from it) and the nodes it may still split, shared by the descents from each top
    node."""

    def __init__(
        self,
        levels: list[LikelihoodField],
        nodes: _NodeScorer,
        angles: FloatArray,
        resolution: float,
        budget: int,
    ) -> None:
        self._levels = levels
        self._nodes = nodes
        self._angles = angles
        self._budget = budget
        self.split = 0
        self.best: tuple[float, float, FloatArray] | None = None  # objective, score, pose
        self.runner_up = -np.inf  # objective of the best cell distinct from the best
        self.runner_pose: FloatArray | None = None
        # cell offsets of a node's children, and their distances, per level split
        self._children = [
            np.arange(-(parent // 2), parent // 2 + 1, child)
            for parent, child in itertools.pairwise(BNB_STEPS)
        ]
        self._children_m: list[FloatArray] = [
            (level_offsets * resolution).astype(np.float64) for level_offsets in self._children
        ]

    def exhausted(self) -> bool:
        return self.split >= self._budget

    def beaten(self, bound: float) -> bool:
        """Whether a node bounded by ``bound`` can hold neither a better best nor a runner-up
        that matters (:data:`RUNNER_UP_FLOOR`)."""
        best = self.best
        return best is not None and bound <= max(self.runner_up, RUNNER_UP_FLOOR * best[0])

    def descend(self, bound: float, a: int, x: float, y: float) -> None:
        """Split the top node at heading ``a`` centred on (x, y), depth first, best child
        first, while the budget lasts."""
        stack = [(bound, 0, a, x, y)]
        while stack and not self.exhausted():
            bound, level, a, x, y = stack.pop()
            if self.beaten(bound):
                continue
            self.split += 1
            child_offsets = self._children[level]
            cx: FloatArray = x + self._children_m[level]
            cy: FloatArray = y + self._children_m[level]
            scores = self._nodes.scores(self._levels[level + 1], a, x, y, child_offsets)
            objective = scores - self._nodes.penalty(a, cx, cy)
            ranked = np.argsort(objective.ravel())  # worst first
            if level + 1 < len(BNB_STEPS) - 1:
                for flat in ranked:  # the best child ends on top of the stack
                    jy, jx = divmod(int(flat), len(child_offsets))
                    value = float(objective[jy, jx])
                    stack.append((value, level + 1, a, float(cx[jx]), float(cy[jy])))
                continue
            self._take_cells(a, cx, cy, objective=objective, scores=scores, best_first=ranked[::-1])

    def _take_cells(
        self,
        a: int,
        cx: FloatArray,
        cy: FloatArray,
        *,
        objective: npt.NDArray[np.floating[Any]],
        scores: Float32Array,
        best_first: npt.NDArray[np.intp],
    ) -> None:
        """A node's single cells, whose values are exact: each may become the best or the
        runner-up."""
        width = len(cx)
        for flat in best_first:
            jy, jx = divmod(int(flat), width)
            value = float(objective[jy, jx])
            pose = np.array([cx[jx], cy[jy], self._angles[a]])
            best = self.best
            if best is None or value > best[0]:
                if best is not None and _distinct(pose, best[2]) and best[0] > self.runner_up:
                    self.runner_up, self.runner_pose = best[0], best[2]
                self.best = (value, float(scores[jy, jx]), pose)
            elif value <= self.runner_up:
                break  # the rest of this node's cells are lower still
            elif _distinct(pose, best[2]):
                self.runner_up, self.runner_pose = value, pose

    def result(self, guess: FloatArray) -> SearchResult:
        best = self.best
        if best is None:
            return SearchResult(np.asarray(guess, dtype=np.float64).copy(), 0.0, 0.0)
        runner_up = self.runner_up
        runner = best[1] - (best[0] - runner_up) if np.isfinite(runner_up) else 0.0
        return SearchResult(best[2], best[1], max(runner, 0.0), self.runner_pose)


@dataclass(slots=True)
class _Fit:
    """One evaluation of a pose: total cost and normal equations (scan plus prior), and the
    scan's own part for the information it reports."""

    cost: float
    hessian: FloatArray
    gradient: FloatArray
    score: float
    scan_hessian: FloatArray
    scan_cost: float


class _ScanCost:
    """The cost :func:`refine` lowers at a pose: the scan's misfit in the field and, with a
    prior, the same pull towards it as in the lattice search."""

    def __init__(self, field: LikelihoodField, points: FloatArray, prior: Prior | None) -> None:
        self._field = field
        self._n = len(points)
        self._px, self._py = points[:, 0], points[:, 1]
        self._prior = prior
        self._stiff = np.zeros(3)
        if prior is not None:
            self._stiff = (self._n * prior.weight) / np.array(
                [prior.sigma_xy**2, prior.sigma_xy**2, prior.sigma_theta**2]
            )

    def evaluate(self, p: FloatArray) -> _Fit:
        n, px, py = self._n, self._px, self._py
        c, s = math.cos(p[2]), math.sin(p[2])
        world = np.empty((n, 2))
        world[:, 0] = p[0] + c * px - s * py
        world[:, 1] = p[1] + s * px + c * py
        value, gx, gy = self._field.interpolate(world)
        jac = np.empty((3, n))
        jac[0], jac[1] = gx, gy
        jac[2] = gx * (-s * px - c * py) + gy * (c * px - s * py)
        residual = 1.0 - value
        scan_h = jac @ jac.T
        scan_cost = float(residual @ residual)
        h, g, cost = scan_h.copy(), jac @ residual, scan_cost
        if self._prior is not None:
            dev = p - self._prior.pose
            dev[2] = math.remainder(dev[2], math.tau)
            h[[0, 1, 2], [0, 1, 2]] += self._stiff
            g = g - self._stiff * dev
            cost += float(self._stiff @ dev**2)
        return _Fit(cost, h, g, float(value.mean()) if n else 0.0, scan_h, scan_cost)

    def information(self, fit: _Fit) -> FloatArray:
        """Gauss-Newton covariance sigma_r^2 (J^T J)^-1 of the scan alone (the prior is the
        odometry edge's business), as its inverse: the residual variance makes a poor fit
        (clutter, partial overlap) count for less."""
        sigma2 = max(fit.scan_cost / max(self._n - 3, 1), 1e-6)
        out: FloatArray = fit.scan_hessian / sigma2
        return out


def refine(
    field: LikelihoodField,
    points: FloatArray,
    pose: FloatArray,
    *,
    iterations: int = 10,
    prior: Prior | None = None,
    start: list[Any] | None = None,
) -> tuple[FloatArray, float, FloatArray]:
    """Levenberg-Marquardt on sum (1 - M(T p))^2; returns pose, score and the fit's
    information.

    The information is the inverse of the Gauss-Newton covariance: large along directions the
    scan pins down, small along a corridor or for the rotation inside a small symmetric room
    (an elevator car), which is what a pose-graph edge should know. ``start``, when given,
    receives the score and information at the starting pose (what the search found).
    """
    current = np.asarray(pose, dtype=np.float64).copy()
    cost = _ScanCost(field, points, prior)
    fit = cost.evaluate(current)
    if start is not None:
        start.extend([fit.score, cost.information(fit)])
    lam = 1e-3
    for _ in range(iterations):
        damped = fit.hessian + lam * np.diag(np.diag(fit.hessian) + 1e-9)
        try:
            delta = np.linalg.solve(damped, fit.gradient)
        except np.linalg.LinAlgError:
            break
        candidate = current + delta
        trial = cost.evaluate(candidate)
        if trial.cost < fit.cost:
            converged = (fit.cost - trial.cost) < CONVERGED_COST * fit.cost
            current, fit = candidate, trial
            lam = max(lam / 10, 1e-7)
            if converged or (
                (abs(delta[0]) < CONVERGED_M and abs(delta[1]) < CONVERGED_M)
                and abs(delta[2]) < CONVERGED_RAD
            ):
                break
        else:
            lam *= 10
            if lam > 1e3:
                break
    current[2] = math.remainder(current[2], math.tau)
    return current, fit.score, cost.information(fit)


def score_at(field: LikelihoodField, points: FloatArray, pose: FloatArray) -> float:
    """Mean field value of the points placed at ``pose``: the score :func:`refine` reports."""
    value, _, _ = field.interpolate(se2.transform_points(pose, points))
    return float(value.mean()) if len(value) else 0.0


def lowest_between(
    field: LikelihoodField, points: FloatArray, a: FloatArray, b: FloatArray, samples: int = 3
) -> float:
    """The lowest score at ``samples`` poses evenly spaced strictly between poses a and b.

    Two answers of a search that score alike are either two peaks (the next door along a
    corridor, a room turned by its symmetry), with a valley between them, or two ends of one
    ridge (a sparse scan in a hall fits equally well anywhere over a few decimetres), along
    which the score stays up: this tells which.
    """
    turn = float(se2.wrap(b[2] - a[2]))
    lowest = math.inf
    for t in np.arange(1, samples + 1) / (samples + 1):
        pose = np.array([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * turn])
        lowest = min(lowest, score_at(field, points, pose))
    return lowest


def match(
    field: LikelihoodField,
    points: FloatArray,
    guess: FloatArray,
    window: SearchWindow,
    *,
    coarse_field: LikelihoodField | None = None,
    prior: Prior | None = None,
    wide: bool = False,
    budget: int | None = None,
) -> MatchResult:
    """Search the window, then refine; the refined pose is kept unless refinement went astray.

    ``wide`` searches by branch and bound (:func:`branch_and_bound_search`), for windows of
    metres; ``coarse_field`` is then not used.

    Astray: it slid more than two cells from the lattice optimum, or lost score. With a prior
    the refinement trades a little score for agreement with odometry, so it may lose up to
    ``PRIOR_SCORE_SLACK`` (a 1 % lower mean likelihood) before it counts as a loss.
    """
    # the lattice only has to find the optimum's basin: a few hundred points do that as well as
    # all of them, and refinement then uses every point
    sparse = points[:: max(1, math.ceil(len(points) / LATTICE_POINTS))]
    if wide:
        found = branch_and_bound_search(field, sparse, guess, window, prior=prior, budget=budget)
    else:
        found = correlative_search(
            field, sparse, guess, window, coarse_field=coarse_field, prior=prior
        )
    lattice_pose, runner_up = found.pose, found.runner_up
    # compare like with like: the interpolated score at the lattice pose, not the cell lookup
    at_lattice: list[Any] = []
    pose, score, info = refine(field, points, lattice_pose, prior=prior, start=at_lattice)
    lattice_score, lattice_info = at_lattice
    moved = np.hypot(*(pose[:2] - lattice_pose[:2]))
    slack = 0.0 if prior is None else PRIOR_SCORE_SLACK
    if score < lattice_score - slack or moved > 2 * field.resolution:
        pose, score, info = lattice_pose, lattice_score, lattice_info
    return MatchResult(pose, score, info, runner_up, found.runner_up_pose)
