"""A laser log of one big loop: a corridor ring of a large building, driven once round and on.

The public logs the project has (Intel, Freiburg 079, Acapulco) come back to where they were
every few tens of metres, so the loop closure's one hard case never happens on them: the first
revisit after a long drive (MIT Killian Court, ACES, CSAIL: loops of 100-400 m), when the
front end has drifted metres. This makes that input, with a truth.

The floor is a rectangular corridor ring of 60-120 m a side, one storey: corridors of
1.8-2.6 m whose widths differ per side, offices on both sides (3-7 m wide, 4-6.5 m deep,
doors open or shut, desks and cabinets inside), pilasters and cabinets along the corridor
walls, dead-end side corridors; the corners stay closed (no shortcut through them). The robot
follows the ring's centre line with a wandering lateral offset, rounding the corners, a scan
every ``spacing_m`` (give or take a fifth), once round and ``overrun_m`` past where it
started, so the end of the run revisits the start after the whole ring.

Scans are a 181-beam, 1-degree laser (CARMEN's FLASER geometry), ray cast exactly
(:func:`baromap.sim.laser.cast`) with centimetre noise and a few dropouts; a beam with no wall
within ``max_range_m`` (20 m, as the public logs' LMS) is a no-return. The structure is drawn
on the building simulator's 5 cm raster and its walls are the exact raster boundary.

Deterministic from the seed: the same seed gives the same world, path and ranges.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray
from baromap.errors import ConfigError
from baromap.recording.carmen import NO_RETURN_M, CarmenLog, CarmenScan, flaser_geometry
from baromap.sim.building import RASTER_M, raster_boundary
from baromap.sim.laser import cast

#: Beams of the laser: CARMEN's FLASER with 181 beams is 180 degrees at 1 degree.
BEAMS = 181
#: What a no-return is written as (the Intel log's marker; anything >= NO_RETURN_M reads so).
NO_RETURN_WRITTEN_M = 81.83
#: Laser range noise (an LMS200 in cm units) and the chance a beam drops out.
RANGE_SIGMA_M = 0.01
DROPOUT = 0.01
#: Free space around the ring for the offices and side corridors, metres.
MARGIN_M = 14.0
#: Interior wall thickness.
WALL_M = 0.2
DOOR_M = 0.9
#: The corners' own lengths are kept free of offices (the perpendicular side's offices reach
#: there), so each side's offices start and end this far from its corners.
CORNER_KEEP_M = 8.0
#: The first scan's time, seconds (any fixed stamp: times only order the scans).
START_S = 1_000_000_000.0
SPEED_MPS = 0.5


@dataclass(frozen=True, slots=True)
class BigLoopConfig:
    """The ring's size, the scan spacing and how far past the start the drive goes."""

    side_m: tuple[float, float] = (60.0, 120.0)
    spacing_m: float = 0.5
    overrun_m: float = 40.0
    max_range_m: float = 20.0

    def __post_init__(self) -> None:
        lo, hi = self.side_m
        if not 2 * CORNER_KEEP_M + 4.0 <= lo <= hi:
            raise ConfigError(
                f"ring sides {self.side_m} m: need {2 * CORNER_KEEP_M + 4} <= lo <= hi"
            )
        if self.spacing_m <= 0 or self.overrun_m < 0 or self.max_range_m <= 0:
            raise ConfigError("spacing and range must be positive, the overrun not negative")


@dataclass(frozen=True, slots=True, eq=False)
class BigLoop:
    """The world and the drive: walls (S, 4), true poses (N, 3), times (N,) in ns, ranges
    (N, BEAMS) with no-returns at :data:`NO_RETURN_WRITTEN_M`, and the ring's perimeter."""

    walls: FloatArray
    poses: FloatArray
    times_ns: npt.NDArray[np.int64]
    ranges: FloatArray
    perimeter_m: float

    def carmen(self) -> CarmenLog:
        """As a CARMEN log read from disk would be: the true poses as the corrected ones."""
        angle_min, increment = flaser_geometry(BEAMS)
        out = CarmenLog()
        for t, pose, ranges in zip(self.times_ns, self.poses, self.ranges, strict=True):
            p = (float(pose[0]), float(pose[1]), float(pose[2]))
            out.scans.append(
                CarmenScan(int(t), angle_min, increment, NO_RETURN_M, ranges.copy(), p, p)
            )
        return out

    def flaser_lines(self) -> list[str]:
        """The log as CARMEN FLASER lines (ranges to the centimetre, as the public logs)."""
        lines = []
        for t, pose, ranges in zip(self.times_ns, self.poses, self.ranges, strict=True):
            r = " ".join(f"{v:.2f}" for v in ranges)
            p = f"{pose[0]:.4f} {pose[1]:.4f} {pose[2]:.6f}"
            stamp = f"{t // 1_000_000_000}.{t % 1_000_000_000:09d}"
            lines.append(f"FLASER {BEAMS} {r} {p} {p} {stamp} sim {stamp}")
        return lines


Box = tuple[float, float, float, float]


class _Raster:
    """Free space on the building simulator's raster, origin at (0, 0)."""

    def __init__(self, width_m: float, height_m: float) -> None:
        self.free = np.zeros((round(height_m / RASTER_M), round(width_m / RASTER_M)), dtype=bool)

    def carve(self, box: Box, value: bool = True) -> None:
        """Set the cells of ``box`` (x0, y0, x1, y1) free (or solid, ``value`` False)."""
        x0, y0, x1, y1 = box
        c0, c1 = sorted((round(x0 / RASTER_M), round(x1 / RASTER_M)))
        r0, r1 = sorted((round(y0 / RASTER_M), round(y1 / RASTER_M)))
        self.free[max(r0, 0) : r1, max(c0, 0) : c1] = value


def _ring_world(
    rng: np.random.Generator, width: float, height: float, half: FloatArray
) -> FloatArray:
    """Walls of the ring whose centre line is the rectangle (MARGIN, MARGIN) + (width,
    height); ``half`` is each side's corridor half width (south, east, north, west)."""
    m = MARGIN_M
    raster = _Raster(width + 2 * m, height + 2 * m)
    corners = np.array([[m, m], [m + width, m], [m + width, m + height], [m, m + height]])
    clutter: list[Box] = []
    for side in range(4):
        a, b = corners[side], corners[(side + 1) % 4]
        along = (b - a) / np.linalg.norm(b - a)
        left = np.array([-along[1], along[0]])  # into the ring (counter-clockwise drive)
        length = float(np.linalg.norm(b - a))
        hw = float(half[side])
        # the corridor, reaching across the perpendicular corridors at both ends
        reach = length + half[side - 1] + half[(side + 1) % 4]
        start = a - along * half[side - 1] - left * hw
        raster.carve(_aabb(start, along, left, reach, 2 * hw))
        for outward in (-1.0, 1.0):
            normal = left * -outward  # from the corridor towards this row of offices
            # the inner rows may only be so deep: the ring's inside is shared by four rows
            room_depth = (1.5, min(6.5, (min(width, height) / 2 - max(half) - 1.0)))
            pos = CORNER_KEEP_M
            while pos < length - CORNER_KEEP_M - 3.0:
                w = float(rng.uniform(3.0, 7.0))
                w = min(w, length - CORNER_KEEP_M - pos)
                start = a + along * pos
                wall = start + normal * hw  # corridor wall line at this row
                if rng.random() < 0.08 and (outward > 0 or room_depth[1] > 8.0):
                    # a dead-end side corridor, 1.8-2.4 m wide, 5-11 m long
                    cw = float(rng.uniform(1.8, 2.4))
                    deep = float(rng.uniform(5.0, min(11.0, MARGIN_M - 2.0)))
                    raster.carve(_aabb(wall - normal * 0.5 + along * 0.5, along, normal, cw, deep))
                    pos += cw + 1.0
                    continue
                depth = float(rng.uniform(4.0, 6.5))
                depth = max(room_depth[0], min(depth, room_depth[1]))
                inner = wall + normal * WALL_M + along * (WALL_M / 2)
                raster.carve(_aabb(inner, along, normal, w - WALL_M, depth))
                if rng.random() < 0.6:  # door open
                    d = float(rng.uniform(0.3, max(0.3, w - WALL_M - DOOR_M - 0.3)))
                    raster.carve(
                        _aabb(wall - normal * 0.05 + along * d, along, normal, DOOR_M, 0.35)
                    )
                # desks against the back wall, and a cabinet or a table somewhere inside
                for _ in range(int(rng.integers(1, 4))):
                    dl = float(rng.uniform(0.8, min(2.0, w - 1.0)))
                    dp = float(rng.uniform(0.5, 0.8))
                    x = float(rng.uniform(0.2, max(0.2, w - WALL_M - dl - 0.2)))
                    corner = inner + along * x + normal * (depth - dp)
                    clutter.append(_aabb(corner, along, normal, dl, dp))
                if depth > 3.5 and rng.random() < 0.5:
                    tl, tw = float(rng.uniform(0.6, 1.4)), float(rng.uniform(0.5, 1.0))
                    x = float(rng.uniform(0.5, max(0.5, w - WALL_M - tl - 0.5)))
                    corner = inner + along * x + normal * float(rng.uniform(1.5, depth - tw - 0.9))
                    clutter.append(_aabb(corner, along, normal, tl, tw))
                pos += w
        # pilasters and cabinets along both corridor walls, leaving a lane for the robot
        pos = float(rng.uniform(1.0, 4.0))
        while pos < length - 1.0:
            for sign in (-1.0, 1.0):
                kind = rng.random()
                if kind < 0.5:
                    depth, extent = 0.15, 0.45  # pilaster
                elif kind < 0.7:
                    depth, extent = float(rng.uniform(0.2, 0.35)), float(rng.uniform(0.6, 1.6))
                else:
                    continue
                wall = a + along * pos + left * (sign * hw)
                clutter.append(_aabb(wall, along, -left * sign, extent, depth))
            pos += float(rng.uniform(3.0, 7.0))
    for box in clutter:
        raster.carve(box, value=False)
    walls: FloatArray = raster_boundary(raster.free)
    return walls


def _aabb(
    corner: FloatArray, along: FloatArray, normal: FloatArray, length: float, depth: float
) -> Box:
    """The axis-aligned box from ``corner`` spanning ``length`` along and ``depth`` inwards."""
    far = corner + along * length + normal * depth
    return (
        float(min(corner[0], far[0])),
        float(min(corner[1], far[1])),
        float(max(corner[0], far[0])),
        float(max(corner[1], far[1])),
    )


def _ring_path(
    rng: np.random.Generator, width: float, height: float, length_m: float
) -> tuple[FloatArray, float]:
    """Dense (every 5 cm) points of the drive: from the middle of the south side round the
    ring counter-clockwise for ``length_m``, corners rounded, a lateral offset wandering within
    a quarter metre. Returns the points and the ring's perimeter."""
    m, r = MARGIN_M, 1.0
    # the rounded rectangle, by arc length, starting mid-south
    straights = [width - 2 * r, height - 2 * r, width - 2 * r, height - 2 * r]
    arc = math.pi / 2 * r
    perimeter = sum(straights) + 4 * arc
    step = 0.05
    s = np.arange(0.0, length_m + step, step)
    u = np.mod(s + straights[0] / 2 + 0.0, perimeter)  # from the south side's start
    pts = np.zeros((len(s), 2))
    heading = np.zeros(len(s))
    starts = [np.array([m + r, m]), np.array([m + width, m + r])]
    starts += [np.array([m + width - r, m + height]), np.array([m, m + height - r])]
    base = 0.0
    for side in range(4):
        theta0 = side * math.pi / 2
        d = np.array([math.cos(theta0), math.sin(theta0)])
        n = np.array([-d[1], d[0]])
        in_straight = (u >= base) & (u < base + straights[side])
        t = u[in_straight] - base
        pts[in_straight] = starts[side] + t[:, None] * d
        heading[in_straight] = theta0
        base += straights[side]
        in_arc = (u >= base) & (u < base + arc)
        phi = (u[in_arc] - base) / r
        centre = starts[side] + straights[side] * d + n * r
        pts[in_arc] = centre + r * (np.sin(phi)[:, None] * d - np.cos(phi)[:, None] * n)
        heading[in_arc] = theta0 + phi
        base += arc
    # a smooth lateral wander: sinusoids of random wavelengths 8-40 m
    offset = np.zeros(len(s))
    for _ in range(3):
        wave = float(rng.uniform(8.0, 40.0))
        offset += 0.08 * np.sin(math.tau * s / wave + float(rng.uniform(0, math.tau)))
    normal = np.column_stack([-np.sin(heading), np.cos(heading)])
    return pts + offset[:, None] * normal, perimeter


def big_loop(seed: int, config: BigLoopConfig | None = None) -> BigLoop:
    """The world, drive and scans of ``seed`` (see the module's docstring)."""
    if seed < 0:
        raise ConfigError(f"the seed must not be negative, got {seed}")
    config = config or BigLoopConfig()
    rng = np.random.default_rng([20_14, seed])
    width, height = sorted(float(v) for v in rng.uniform(*config.side_m, size=2))[::-1]
    half = rng.uniform(0.9, 1.3, size=4)
    walls = _ring_world(rng, width, height, half)
    dense, perimeter = _ring_path(
        rng, width, height, perimeter_guess(width, height) + config.overrun_m
    )
    # a scan every spacing, give or take a fifth
    gaps = config.spacing_m * rng.uniform(
        0.8, 1.2, size=int(len(dense) * 0.05 / config.spacing_m) + 2
    )
    at = np.cumsum(np.concatenate([[0.0], gaps]))
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(dense, axis=0).T))])
    at = at[at <= travelled[-1] - 0.1]
    idx = np.searchsorted(travelled, at)
    xy = dense[idx]
    ahead = dense[np.minimum(idx + 2, len(dense) - 1)] - dense[np.maximum(idx - 2, 0)]
    theta = np.arctan2(ahead[:, 1], ahead[:, 0])
    poses = np.column_stack([xy, theta])
    angle_min, increment = flaser_geometry(BEAMS)
    angles: FloatArray = angle_min + increment * np.arange(BEAMS, dtype=np.float64)
    ranges = np.empty((len(poses), BEAMS))
    for lo in range(0, len(poses), 64):
        chunk = poses[lo : lo + 64]
        true, cosines = cast(walls, chunk[:, :2], chunk[:, 2], angles, config.max_range_m)
        noisy = true + rng.normal(0.0, RANGE_SIGMA_M, true.shape)
        grazing = np.clip((0.17 - cosines) / 0.17, 0.0, 1.0)
        dropped = rng.random(true.shape) < DROPOUT + 0.5 * grazing
        ranges[lo : lo + 64] = np.where(
            np.isfinite(true) & ~dropped, np.maximum(noisy, 0.01), NO_RETURN_WRITTEN_M
        )
    times = (START_S * 1e9 + at[: len(poses)] / SPEED_MPS * 1e9).astype(np.int64)
    return BigLoop(walls, poses, times, ranges, perimeter)


def perimeter_guess(width: float, height: float) -> float:
    """The rounded ring's perimeter (corners of radius 1 m)."""
    return 2 * (width + height) - 8.0 + 2 * math.pi
