"""The live map of the current floor: scans matched and drawn into that floor's grid as they come.

Live, causal and cheap, unlike ``build-maps``: each keyframe (a scan taken after the robot
moved ``keyframe_m`` or turned ``keyframe_deg``, SLAM's own spacing) is matched against the
likelihood field of what this floor's earlier keyframes saw, in a window as wide as odometry
can be wrong since the last one (the front end's correlative matcher, its prior and windows),
then cast into the floor's occupancy grid (the post-run grid's inverse sensor model, one scan
at a time). There is no loop closure: drift that builds up along a long loop stays in the live
map; the post-run maps remove it.

Floors follow the detector: the floor is :class:`~baromap.messages.FloorState`'s
``floor_id`` (the last decided visit, corrections included). While the state says the robot
is riding or stopped at a level not yet decided (``changing``, ``stopped``), nothing is drawn:
the car's walls would be drawn into the floor being left, and the floor it arrives at is not
known yet. When the detector decides a floor, the map switches to that floor's grid: a new one
for a floor seen for the first time, the one it left there for a floor visited before (the
robot's pose carries over through the ride, the car standing where it stood, so all floors
share one ``map`` frame as the post-run maps do).

Sans-I/O: messages in, :meth:`LiveFloorMap.snapshot` out; the caller decides the threads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray
from baromap.errors import ConfigError
from baromap.mapping import se2
from baromap.mapping.occupancy import L_CLAMP, OccupancyGrid, build_grid
from baromap.mapping.scan_matcher import (
    LikelihoodField,
    Prior,
    kernel_radius,
    match,
    stamp,
)
from baromap.mapping.scans import ScanBlock, voxel_filter
from baromap.mapping.slam.measurement import lattice_angle_step, search_window
from baromap.mapping.slam.settings import (
    MAX_FRONT_WINDOW_M,
    MAX_FRONT_WINDOW_RAD,
    MIN_POINTS,
    MIN_WINDOW_M,
    MIN_WINDOW_RAD,
    ODOMETRY_SIGMA_M,
    ODOMETRY_SIGMA_RAD,
    PRIOR_WEIGHT,
    WINDOW_SIGMAS,
    SlamConfig,
)
from baromap.messages import FloorPhase, FloorState, LaserScan, Odometry

#: The grid grows by at least this much on a side the robot drives out of (a handful of
#: reallocations per floor rather than one per keyframe).
GROWTH_M = 8.0
#: The post-run SLAM's settings, whose keyframe spacing, odometry error and match threshold the
#: live map takes.
_SLAM = SlamConfig()
#: Phases in which the robot is on the floor the state names (drawing is safe).
_ON_FLOOR = (FloorPhase.SETTLED,)


@dataclass(frozen=True, slots=True)
class LiveMapSettings:
    """How the live map is built; the defaults are the post-run SLAM's, coarser cells aside.

    ``resolution_m`` is the cell of both the grid and the matcher's field (10 cm by default:
    a quarter of the cells of the post-run 5 cm, for a map a person looks at while driving).
    """

    resolution_m: float = 0.1
    max_range_m: float = 20.0
    keyframe_m: float = _SLAM.keyframe_m
    keyframe_deg: float = _SLAM.keyframe_deg
    min_score: float = _SLAM.front_min_score
    odometry_sigma_m_per_m: float = _SLAM.odometry_sigma_m_per_m
    odometry_sigma_deg_per_m: float = _SLAM.odometry_sigma_deg_per_m
    odometry_sigma_per_rad: float = _SLAM.odometry_sigma_per_rad
    #: most poses of the current floor's path kept (older ones are thinned out, every other)
    path_max: int = 2000

    def __post_init__(self) -> None:
        if not 0.02 <= self.resolution_m <= 0.5:
            raise ConfigError(f"live map resolution must be 0.02-0.5 m, not {self.resolution_m} m")
        if not self.max_range_m > 0 or not self.keyframe_m > 0 or not 0 < self.keyframe_deg < 180:
            raise ConfigError("live map ranges and keyframe spacing must be positive")


@dataclass(frozen=True, slots=True)
class LiveMapInfo:
    """What the live grid shows: whose floor, how it was built (``/live/map/info``)."""

    t_ns: int
    floor_id: int | None
    floor_name: str | None
    height_m: float
    #: the floor's grid was resumed (a floor visited before), not started afresh
    resumed: bool
    keyframes: int
    matched: int
    #: keyframes placed by odometry alone (a poor match, or too few points)
    unmatched: int
    #: keyframes while riding or stopped at an undecided level: not drawn
    not_drawn: int
    width: int
    height: int
    resolution_m: float


@dataclass(frozen=True, slots=True)
class LiveMapSnapshot:
    """The current floor's grid, the robot's path on it and ``map -> odom``, at ``t_ns``."""

    info: LiveMapInfo
    grid: OccupancyGrid
    path: FloatArray  # (N, 3) map poses of this floor's keyframes, oldest first
    map_to_odom: FloatArray  # (3,) the correction: map pose = map_to_odom (+) odometry pose


@dataclass(slots=True)
class _FloorGrid:
    """One floor's evidence in the ``map`` frame: log odds and the matcher's field, one lattice.

    Cell (row i, col j) covers [origin + res * (j, i), origin + res * (j + 1, i + 1)); the field
    holds its value at the cell's centre (``LikelihoodField``'s convention).
    """

    resolution: float
    sigma: float
    log_odds: npt.NDArray[np.float32] = field(default_factory=lambda: np.zeros((0, 0), np.float32))
    likelihood: npt.NDArray[np.float32] = field(
        default_factory=lambda: np.zeros((0, 0), np.float32)
    )
    origin: tuple[float, float] = (0.0, 0.0)
    path: list[FloatArray] = field(default_factory=list)
    keyframes: int = 0
    matched: int = 0
    unmatched: int = 0

    @property
    def empty(self) -> bool:
        return self.keyframes == 0

    def likelihood_field(self) -> LikelihoodField:
        half = 0.5 * self.resolution
        return LikelihoodField(
            self.likelihood, (self.origin[0] + half, self.origin[1] + half), self.resolution
        )

    def grid(self) -> OccupancyGrid:
        return OccupancyGrid(self.log_odds.copy(), self.origin, self.resolution)

    def fit(self, lo: FloatArray, hi: FloatArray) -> None:
        """Grow both arrays, on the same lattice, so [lo, hi] plus a kernel fits inside."""
        res = self.resolution
        pad = (kernel_radius(res, self.sigma) + 2) * res
        h, w = self.log_odds.shape
        x0, y0 = self.origin
        want = (lo[0] - pad, lo[1] - pad, hi[0] + pad, hi[1] + pad)
        if h and w:
            x1, y1 = x0 + w * res, y0 + h * res
            if want[0] >= x0 and want[1] >= y0 and want[2] <= x1 and want[3] <= y1:
                return
            nx0 = x0 - GROWTH_M * math.ceil(max(0.0, x0 - want[0]) / GROWTH_M)
            ny0 = y0 - GROWTH_M * math.ceil(max(0.0, y0 - want[1]) / GROWTH_M)
            nx1 = x1 + GROWTH_M * math.ceil(max(0.0, want[2] - x1) / GROWTH_M)
            ny1 = y1 + GROWTH_M * math.ceil(max(0.0, want[3] - y1) / GROWTH_M)
        else:
            # the lattice is whole cells from the map's origin, as build_grid's grids are
            nx0 = math.floor((want[0] - GROWTH_M / 2) / res) * res
            ny0 = math.floor((want[1] - GROWTH_M / 2) / res) * res
            nx1, ny1 = want[2] + GROWTH_M / 2, want[3] + GROWTH_M / 2
            x0, y0 = nx0, ny0
        col0 = round((x0 - nx0) / res)
        row0 = round((y0 - ny0) / res)
        width = math.ceil((nx1 - nx0) / res) + 1
        height = math.ceil((ny1 - ny0) / res) + 1
        for name in ("log_odds", "likelihood"):
            old = getattr(self, name)
            new = np.zeros((height, width), np.float32)
            if h and w:
                new[row0 : row0 + h, col0 : col0 + w] = old
            setattr(self, name, new)
        self.origin = (x0 - col0 * res, y0 - row0 * res)

    def draw(
        self, scan: ScanBlock, pose: FloatArray, points: FloatArray, max_range_m: float
    ) -> None:
        """Cast the scan taken at ``pose`` into the log odds and stamp its points in the field."""
        one = build_grid(
            scan,
            np.zeros(1, np.int64),
            pose[None, :],
            resolution=self.resolution,
            max_range_m=max_range_m,
            margin_m=self.resolution,
        )
        h, w = one.shape
        x1 = one.origin_xy[0] + w * self.resolution
        y1 = one.origin_xy[1] + h * self.resolution
        world = se2.transform_points(pose, points)
        lo = np.minimum(np.array(one.origin_xy), world.min(axis=0, initial=np.inf))
        hi = np.maximum(np.array([x1, y1]), world.max(axis=0, initial=-np.inf))
        self.fit(lo, hi)
        col = round((one.origin_xy[0] - self.origin[0]) / self.resolution)
        row = round((one.origin_xy[1] - self.origin[1]) / self.resolution)
        target = self.log_odds[row : row + h, col : col + w]
        target += one.log_odds
        np.clip(target, -L_CLAMP, L_CLAMP, out=target)
        centres = self.likelihood_field().origin_xy
        stamp(self.likelihood, centres, self.resolution, self.sigma, world)

    def add_pose(self, pose: FloatArray, most: int) -> None:
        self.path.append(pose.copy())
        if len(self.path) > most:  # thin out the old half, keep the recent path dense
            half = len(self.path) // 2
            self.path[:half] = self.path[:half:2]


class LiveFloorMap:
    """Odometry, scans and floor states in; the current floor's map out.

    ``odometry`` and ``floor_state`` are cheap and may be called for every message;
    ``scan`` does the work only for a keyframe, and says whether it did (a caller that falls
    behind offers only its newest scan and counts the others as dropped).
    """

    def __init__(
        self, settings: LiveMapSettings | None = None, laser_offset: npt.ArrayLike | None = None
    ):
        self.settings = settings or LiveMapSettings()
        self._offset = np.zeros(3) if laser_offset is None else np.asarray(laser_offset, float)
        self._floors: dict[int | None, _FloorGrid] = {}
        self._floor_id: int | None = None
        self._floor_name: str | None = None
        self._height_m = 0.0
        self._drawing = False
        self._resumed = False
        self._odom: FloatArray | None = None
        self._odom_t_ns = 0
        #: map pose = correction (+) odometry pose
        self._correction = np.zeros(3)
        self._last_key_odom: FloatArray | None = None
        self._last_t_ns = 0
        self.not_drawn = 0
        self._current = self._grid(None)

    def _grid(self, floor_id: int | None) -> _FloorGrid:
        grid = self._floors.get(floor_id)
        if grid is None:
            res = self.settings.resolution_m
            grid = _FloorGrid(resolution=res, sigma=res)
            self._floors[floor_id] = grid
        return grid

    @property
    def floor_id(self) -> int | None:
        return self._floor_id

    @property
    def t_ns(self) -> int:
        """The newest message's time (0 before the first: nothing to show yet)."""
        return self._last_t_ns

    def odometry(self, odom: Odometry) -> None:
        self._odom = np.array([odom.x_m, odom.y_m, odom.theta_rad])
        self._odom_t_ns = odom.t_ns
        self._last_t_ns = max(self._last_t_ns, odom.t_ns)

    def floor_state(self, state: FloorState) -> None:
        """Follow the detector: draw only while on a floor; switch grids when it decides one."""
        self._drawing = state.phase in _ON_FLOOR and state.floor_id is not None
        if state.floor_id is None:
            return  # no settled pressure yet: the start floor's grid is the unnamed one
        self._floor_name = state.name
        self._height_m = state.height_m if math.isfinite(state.height_m) else 0.0
        if state.floor_id == self._floor_id:
            return
        if self._floor_id is None and None in self._floors:
            # the first floor the detector names is the one driven on until then
            self._floors[state.floor_id] = self._floors.pop(None)
            self._floor_id = state.floor_id
            self._current = self._floors[state.floor_id]
            return
        self._resumed = state.floor_id in self._floors and not self._floors[state.floor_id].empty
        self._floor_id = state.floor_id
        self._current = self._grid(state.floor_id)

    def scan(self, scan: LaserScan) -> bool:
        """Match and draw the scan if it is a keyframe; True if it was one."""
        odom = self._odom
        if odom is None:
            return False  # no odometry yet: nowhere to put it
        self._last_t_ns = max(self._last_t_ns, scan.t_ns)
        s = self.settings
        last = self._last_key_odom
        if last is not None:
            step = se2.between(last, odom)
            moved, turned = math.hypot(step[0], step[1]), abs(float(se2.wrap(step[2])))
            if moved < s.keyframe_m and turned < math.radians(s.keyframe_deg):
                return False
        else:
            moved = turned = 0.0
        self._last_key_odom = odom.copy()
        grid = self._current
        if not self._drawing and not (self._floor_id is None and grid.empty):
            self.not_drawn += 1
            return True
        block = ScanBlock.from_messages([scan], self._offset)
        points = voxel_filter(block.surface(0, s.max_range_m, s.resolution_m), s.resolution_m)
        guess = se2.compose(self._correction, odom)
        pose = guess
        if grid.empty:
            pass  # the first keyframe of a floor is where odometry says
        elif len(points) >= MIN_POINTS:
            sigma_xy = max(ODOMETRY_SIGMA_M, s.odometry_sigma_m_per_m * moved)
            sigma_theta = max(
                ODOMETRY_SIGMA_RAD,
                math.radians(s.odometry_sigma_deg_per_m) * moved
                + s.odometry_sigma_per_rad * turned,
            )
            linear = min(MAX_FRONT_WINDOW_M, max(MIN_WINDOW_M, WINDOW_SIGMAS * sigma_xy))
            angular = min(MAX_FRONT_WINDOW_RAD, max(MIN_WINDOW_RAD, WINDOW_SIGMAS * sigma_theta))
            typical = float(np.median(np.hypot(points[:, 0], points[:, 1])))
            window = search_window(
                linear, angular, lattice_angle_step(typical, s.resolution_m), s.resolution_m
            )
            fld = grid.likelihood_field()
            coarse = fld.pooled(window.coarse_step_cells) if window.coarse_step_cells > 1 else None
            result = match(
                fld,
                points,
                guess,
                window,
                coarse_field=coarse,
                prior=Prior(guess, sigma_xy, sigma_theta, PRIOR_WEIGHT),
            )
            if result.score >= s.min_score:
                pose = result.pose
                grid.matched += 1
            else:
                grid.unmatched += 1
        else:
            grid.unmatched += 1
        self._correction = se2.compose(pose, se2.inverse(odom))
        grid.draw(block, pose, points, s.max_range_m)
        grid.keyframes += 1
        grid.add_pose(pose, s.path_max)
        return True

    def snapshot(self) -> LiveMapSnapshot:
        grid = self._current
        occupancy = grid.grid()
        h, w = occupancy.shape
        info = LiveMapInfo(
            t_ns=self._last_t_ns,
            floor_id=self._floor_id,
            floor_name=self._floor_name,
            height_m=self._height_m,
            resumed=self._resumed,
            keyframes=grid.keyframes,
            matched=grid.matched,
            unmatched=grid.unmatched,
            not_drawn=self.not_drawn,
            width=w,
            height=h,
            resolution_m=grid.resolution,
        )
        path = np.array(grid.path, dtype=np.float64).reshape(-1, 3)
        return LiveMapSnapshot(info, occupancy, path, self._correction.copy())

    def nbytes(self) -> int:
        """Memory the floors' arrays hold (the live map's share of the process)."""
        return sum(g.log_odds.nbytes + g.likelihood.nbytes for g in self._floors.values())
