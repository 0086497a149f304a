"""Occupancy grids: log odds accumulated by casting every beam through the grid.

Casting one beam at a time (Bresenham in Python) is far too slow for a 46-minute run, so the
free part of every beam is sampled once per cell length along the ray, all beams of a batch
of scans at once, and the samples are counted per cell with ``np.bincount``; the endpoint cells
are counted as hits the same way. The counts turn into clamped log odds at the end. A sample
stops half a cell short of the endpoint so a beam never clears the wall it hit.

No-return beams (NaN) clear nothing: a max-range reading of an LMS200 also happens on glass and
black surfaces, and treating it as "free to 80 m" would carve holes through walls.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray
from baromap.mapping import se2
from baromap.mapping.scans import ScanBlock

#: Log odds of one hit and one pass-through (inverse sensor model: p = 0.7 and p = 0.4).
L_HIT = math.log(0.7 / 0.3)
L_MISS = math.log(0.4 / 0.6)
L_CLAMP = 6.0
#: Probability thresholds written into the map_server YAML and used to classify cells.
OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196


@dataclass(frozen=True, slots=True)
class OccupancyGrid:
    """Log odds per cell; row 0 is the lowest y, cell (0, 0)'s lower-left corner at origin."""

    log_odds: npt.NDArray[np.float32]
    origin_xy: tuple[float, float]
    resolution: float

    @property
    def shape(self) -> tuple[int, int]:
        h, w = self.log_odds.shape
        return int(h), int(w)

    def probability(self) -> npt.NDArray[np.float32]:
        p = 1.0 / (1.0 + np.exp(-self.log_odds))
        return p.astype(np.float32)

    def occupied(self) -> npt.NDArray[np.bool_]:
        return self.log_odds > math.log(OCCUPIED_THRESH / (1 - OCCUPIED_THRESH))

    def free(self) -> npt.NDArray[np.bool_]:
        return self.log_odds < math.log(FREE_THRESH / (1 - FREE_THRESH))

    def cell_centers(self) -> tuple[FloatArray, FloatArray]:
        """World x of each column and y of each row."""
        h, w = self.shape
        xs = self.origin_xy[0] + (np.arange(w, dtype=np.float64) + 0.5) * self.resolution
        ys = self.origin_xy[1] + (np.arange(h, dtype=np.float64) + 0.5) * self.resolution
        return xs.astype(np.float64), ys.astype(np.float64)


def grid_bounds(
    scans: ScanBlock, indices: npt.NDArray[np.int64], poses: FloatArray, max_range_m: float
) -> tuple[float, float, float, float]:
    """Bounding box of the endpoints of the given scans (robot positions included)."""
    if len(indices) == 0:
        return (0.0, 0.0, 1.0, 1.0)
    r = scans.ranges_m[indices].astype(np.float64)
    ok = np.isfinite(r) & (r > 0.05) & (r <= max_range_m)
    # endpoints in the robot frame (the laser's offset applied), then in the world
    laser = se2.transform_points(
        scans.laser_offset,
        np.stack([(r * np.cos(scans.angles_rad))[ok], (r * np.sin(scans.angles_rad))[ok]], 1),
    )
    poses = np.asarray(poses, dtype=np.float64)
    owner = np.nonzero(ok)[0]
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    x = poses[owner, 0] + c[owner] * laser[:, 0] - s[owner] * laser[:, 1]
    y = poses[owner, 1] + s[owner] * laser[:, 0] + c[owner] * laser[:, 1]
    lo = (
        min(x.min(initial=np.inf), poses[:, 0].min()),
        min(y.min(initial=np.inf), poses[:, 1].min()),
    )
    hi = (
        max(x.max(initial=-np.inf), poses[:, 0].max()),
        max(y.max(initial=-np.inf), poses[:, 1].max()),
    )
    if not np.all(np.isfinite(lo + hi)):
        return (0.0, 0.0, 1.0, 1.0)
    return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


def build_grid(
    scans: ScanBlock,
    indices: npt.NDArray[np.int64],
    poses: FloatArray,
    *,
    resolution: float = 0.05,
    max_range_m: float = 20.0,
    margin_m: float = 0.5,
    batch: int = 64,
) -> OccupancyGrid:
    """Grid from the scans ``indices`` taken at robot poses ``poses`` (one row per index)."""
    indices = np.asarray(indices, dtype=np.int64)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    bx0, by0, bx1, by1 = grid_bounds(scans, indices, poses, max_range_m)
    x0 = math.floor((bx0 - margin_m) / resolution) * resolution
    y0 = math.floor((by0 - margin_m) / resolution) * resolution
    w = math.ceil((bx1 + margin_m - x0) / resolution)
    h = math.ceil((by1 + margin_m - y0) / resolution)
    cells = h * w
    raster = _Raster(x0, y0, resolution, w, h)
    hits = np.zeros(cells + 1, dtype=np.int64)  # the last bin takes what falls outside
    misses = np.zeros(cells + 1, dtype=np.int64)
    for start in range(0, len(indices), batch):
        idx = indices[start : start + batch]
        laser = se2.compose(poses[start : start + batch], scans.laser_offset[None, :])
        ranges = scans.ranges_m[idx].astype(np.float64)  # (b, B)
        ok = np.isfinite(ranges) & (ranges > 0.05)
        hit = ok & (ranges <= max_range_m)
        length = np.where(ok, np.minimum(ranges, max_range_m), 0.0)
        ang = laser[:, 2:3] + scans.angles_rad[None, :]
        cos, sin = np.cos(ang), np.sin(ang)
        ox, oy = laser[:, 0:1], laser[:, 1:2]
        # endpoints
        ex = (ox + length * cos)[hit]
        ey = (oy + length * sin)[hit]
        hits += np.bincount(raster.cell_index(ex, ey), minlength=cells + 1)
        # free samples along each beam, stopping half a cell before the endpoint: beam b's
        # k-th sample is at distance k * resolution from the laser
        counts = np.maximum(np.floor((length - 0.5 * resolution) / resolution).astype(np.int64), 0)
        counts = np.where(ok, counts, 0).ravel()
        total = int(counts.sum())
        if total == 0:
            continue
        first = np.cumsum(counts) - counts
        d = (np.arange(total) - np.repeat(first, counts)) * resolution
        beams = ranges.shape[1]
        fx = _along(np.broadcast_to(ox, ranges.shape).ravel(), cos.ravel(), counts, d)
        fy = _along(np.broadcast_to(oy, (len(idx), beams)).ravel(), sin.ravel(), counts, d)
        misses += np.bincount(raster.cell_index(fx, fy), minlength=cells + 1)
    hits, misses = hits[:cells], misses[:cells]
    log_odds = np.clip(hits * L_HIT + misses * L_MISS, -L_CLAMP, L_CLAMP)
    return OccupancyGrid(
        log_odds=log_odds.reshape(h, w).astype(np.float32),
        origin_xy=(x0, y0),
        resolution=resolution,
    )


def _along(
    origin: FloatArray, direction: FloatArray, counts: npt.NDArray[np.int64], d: FloatArray
) -> FloatArray:
    """One coordinate of every free sample: each beam's origin plus ``d`` times its direction
    cosine, beam b's repeated ``counts[b]`` times (in place, as few temporaries as can be:
    a batch holds a million samples)."""
    out = np.repeat(direction, counts)
    out *= d
    out += np.repeat(origin, counts)
    return out


@dataclass(frozen=True, slots=True)
class _Raster:
    """Where a grid lies: lower-left corner, cell size and cells across (w) and up (h)."""

    x0: float
    y0: float
    resolution: float
    w: int
    h: int

    def cell_index(self, x: FloatArray, y: FloatArray) -> npt.NDArray[np.int64]:
        """Flat cell index of each point, ``h * w`` (one bin past the grid) for points
        outside. Overwrites ``x`` and ``y``."""
        x -= self.x0
        x /= self.resolution
        np.floor(x, out=x)
        y -= self.y0
        y /= self.resolution
        np.floor(y, out=y)
        inside = (x >= 0) & (x < self.w) & (y >= 0) & (y < self.h)
        y *= self.w
        y += x
        flat = y.astype(np.int64)
        flat[~inside] = self.h * self.w
        return flat
