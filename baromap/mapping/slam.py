"""Floor-aware graph SLAM over a whole run.

Keyframes: every ``keyframe_m`` metres or ``keyframe_deg`` of odometric motion, plus the first
and last scan of every floor visit (the robot in the elevator car, before and after a ride).

Front end: each keyframe is matched against the submap it is driving through (the last 20 to
40 keyframes of the visit fused into one likelihood field, :mod:`baromap.mapping.submaps`),
with odometry as a soft prior so a featureless corridor cannot make it slide. The search
window follows the motion since the last keyframe: what odometry can have got wrong over it,
so a sparse log's metre-long steps and 80-degree turns get a wide coarse-to-fine search and a
dense log's centimetre steps a narrow one. A match that a clearly different pose explains
almost as well (a door further along, the room turned) is ambiguous and refused: odometry
alone carries that step. After a turn of more than 90 degrees between keyframes (a sparse log
turning round), a poor match is tried again against the keyframes of the last 20 m: looking
back, the scan sees what the submap of the last metres, seen looking forward, hardly holds.
Both odometry and the match enter the pose graph, the match with the information of its own
fit (weak along a corridor, strong across it).

Odometry's systematic errors (distance read long by the tyres, turns by a skid-steer's slip,
heading creep per metre) are learnt from the front end's matches wherever they pin a step
down at both ends (:mod:`baromap.mapping.odometry_calibration`), and taken out of every later
odometric step and, at the end, of every odometry edge: along a featureless corridor, where
odometry alone decides, a 2 % scale error would otherwise stretch the map. What corrected
odometry still gets wrong per step is measured on the same matched steps, and the last solve
weighs every odometry edge by it rather than by the front end's deliberately wide sigmas; then
every kind of edge (odometry, matches, closures, the car) is scaled to how far it actually
scatters against that solve, and the graph solved again.

Loop closures: each keyframe looks for finished submaps of the *same floor* (the barometer's
verdict) that it sees from near where they were built, and matches against each with a
window as wide as the front end can have drifted since it was last tied to the map (the path
since the submap, or since the last closure, whichever is shorter); a submap of a sparse log,
a scan every few metres, holds too few scans to score a revisit, and the keyframes around the
revisited one stand in for it. Ambiguous matches and corrections larger than that drift are
refused, and accepted closures carry a Cauchy kernel, so the few wrong ones that pass cannot
bend the map. Against such a target of few scans a revisit scores low (what the revisiting
scan sees, they mostly never saw) and may come back after long stretches without a closure,
metres off: there a closure under the threshold, or from a window as wide as the drift
(searched by branch and bound), is taken only once another keyframe's closure implies the
same correction. Different floors never close against each other: stacked floors can look
identical, and only the barometer tells them apart.

Floors: the elevator car, the one place seen on every floor, joins them. The car travels with
the robot and stands in the same shaft on every floor, so every pair of car keyframes (the
closed car, before and after each ride, from any floor) is matched; together these keep all
floors in one frame. The graph is solved when a closure disagrees with it (a correction that
moves the map), not after every keyframe.

Scans that are not keyframes get the corrected pose of the keyframes around them: odometry
between the two, with the correction the graph made to that stretch spread along it.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, fields

import numpy as np
import numpy.typing as npt
import structlog

from baromap.errors import ConfigError
from baromap.mapping import se2
from baromap.mapping.errors import MappingError
from baromap.mapping.keyframes import motion_spaced
from baromap.mapping.occupancy import OccupancyGrid, build_grid
from baromap.mapping.odometry_calibration import (
    NOISE_OUTLIER_SIGMAS,
    OdometryCalibration,
    OdometryNoise,
    fit_noise,
)
from baromap.mapping.pose_graph import Edge, PoseGraph
from baromap.mapping.refine import Pull, concatenate, refine_batch
from baromap.mapping.scan_matcher import (
    DISTINCT_RAD,
    LikelihoodField,
    MatchResult,
    Prior,
    SearchWindow,
    lowest_between,
    match,
    score_at,
)
from baromap.mapping.scans import ScanBlock, voxel_filter
from baromap.mapping.submaps import Submap, SubmapCache

log = structlog.get_logger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
Int8Array = npt.NDArray[np.int8]

#: Floor label of scans taken while the barometer says the robot is between floors.
BETWEEN_FLOORS = -1


@dataclass(frozen=True, slots=True)
class SlamConfig:
    """What the SLAM assumes about the robot, its sensors and its own drift.

    Every setting is a property of the world (how far apart keyframes are, how good the
    odometry is, how far the front end drifts per metre) that can be set by reasoning about a
    robot, not a knob to tune against one log. The matcher's inner constants are module
    constants below, with the reasons for their values.
    """

    #: a keyframe every this much travel or turn: well inside what one scan overlaps (the
    #: scans between keyframes are placed on the finished map at the end)
    keyframe_m: float = 0.5
    keyframe_deg: float = 25.0
    #: beams beyond this are ignored. Far returns are sparse (0.5 m apart at 30 m with 1
    #: degree beams) and often graze a wall, but across a hall they are what pins the heading:
    #: from 20 to 30 m Acapulco's ATE fell 0.127 -> 0.114 m (seeds 0-4; 0.114 at 40 m too),
    #: Freiburg 079's 0.066 -> 0.062 m, Intel's 0.053 -> 0.051 m, while the relations, local,
    #: moved by under 3 % (Intel 0.0219 -> 0.0224 m mean). A laser in its 8 m mode (the
    #: simulated robot's) never reaches it
    max_range_m: float = 30.0
    #: cell of the likelihood fields and of the scan's voxel filter; also the field's sigma
    resolution_m: float = 0.05
    #: a submap takes keyframes over this much travel, as the newer of the two being built,
    #: and as much again as the older one the front end matches against (see submaps.py):
    #: short enough that the front end's drift inside it is below a cell
    submap_m: float = 5.0
    #: odometry's error per step: sigma of position per metre driven, of heading per metre
    #: driven and per radian turned. Wheel odometry misjudges distance by a few percent and
    #: drifts in heading by a degree or two per metre; a skid-steer base misjudges turns in
    #: place by several percent, systematically. These are worse than a P3-AT (1-2 %, under
    #: a degree per metre, 1-4 % of a turn) to cover the public logs' error model too (5 %,
    #: 2 deg/m). The front end searches three sigmas around odometry.
    odometry_sigma_m_per_m: float = 0.07
    odometry_sigma_deg_per_m: float = 3.0
    odometry_sigma_per_rad: float = 0.05
    #: how far the front end (odometry corrected by submap matching) can drift per metre
    #: driven: it bounds the loop-closure search and the largest correction believed
    drift_m_per_m: float = 0.1
    drift_deg_per_m: float = 0.5
    #: a finished submap is a loop-closure candidate when the keyframe is within this of a
    #: place it was built from (plus the drift bound)
    loop_radius_m: float = 3.0
    #: least mean likelihood of a match's points to accept it (front end, loop closure).
    #: The front end's is a floor for "the scan barely overlaps its submap" (under one point
    #: in seven explained), not a test of right and wrong: a scan two or three metres on
    #: sees much its submap never saw, so a correct match there scores 0.2-0.3, and on the
    #: Intel log with every third scan wrong matches (0.3 m or 3 deg from GMapping's) were
    #: as frequent among scores over 0.55 as among 0.2-0.3. Refusing those drove the front
    #: end on odometry and the map fell apart (metres); the ambiguity test and odometry's
    #: window are what keep wrong matches out. A loop closure, judged against a map it may
    #: only partly share, keeps a high bar: lowering it (0.35) bent Freiburg 079.
    front_min_score: float = 0.15
    loop_min_score: float = 0.55

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ConfigError(f"SlamConfig.{f.name} must be a number, got {value!r}")
            if not math.isfinite(value) or value <= 0:
                raise ConfigError(f"SlamConfig.{f.name} must be positive, got {value!r}")
        for name in ("front_min_score", "loop_min_score"):
            if getattr(self, name) >= 1.0:
                raise ConfigError(f"SlamConfig.{name} is a mean likelihood, below 1")
        if self.keyframe_deg >= 180.0:
            raise ConfigError("SlamConfig.keyframe_deg must be below 180")
        if self.resolution_m > 0.5:
            raise ConfigError(f"SlamConfig.resolution_m {self.resolution_m} m is over 0.5 m")

    @property
    def keyframe_rad(self) -> float:
        return math.radians(self.keyframe_deg)


# Inner constants of the matcher and the graph, and why they have these values.

#: The search covers odometry's error to this many sigmas.
WINDOW_SIGMAS = 3.0
#: ... but never less than a couple of cells and a degree: the lattice must hold the optimum's
#: neighbours for the refinement to start from, and never more than what a step can hold.
MIN_WINDOW_M = 0.1
MIN_WINDOW_RAD = math.radians(2.0)
MAX_FRONT_WINDOW_M = 1.5
MAX_FRONT_WINDOW_RAD = math.radians(45.0)
#: The lattice's angular step moves a typical point by about one cell, within these limits.
MIN_ANGLE_STEP_RAD = math.radians(0.25)
MAX_ANGLE_STEP_RAD = math.radians(1.0)
#: A window wider than this many cells is searched coarse-to-fine (4-cell coarse lattice).
COARSE_ABOVE_CELLS = 4
COARSE_STEP_CELLS = 4
#: A front-end match scoring under this after a turn of more than FRONT_RETRY_TURN_RAD (the
#: robot looking back over where it came from) is tried again against the keyframes of the
#: last FRONT_RETRY_M of travel (:meth:`_Slam._retry_after_turn`). Dense logs, a keyframe
#: every 25 degrees, never turn that far between keyframes.
FRONT_RETRY_BELOW = 0.3
FRONT_RETRY_M = 20.0
FRONT_RETRY_TURN_RAD = math.radians(90.0)
#: Odometry's floor: even a standing robot's pose is known to about this.
ODOMETRY_SIGMA_M = 0.02
ODOMETRY_SIGMA_RAD = math.radians(0.5)
#: A match's Gauss-Newton covariance is inflated by this factor (scan points are not
#: independent: neighbouring beams see the same wall) and floored by these sigmas before it
#: becomes an edge.
MATCH_COV_SCALE = 4.0
MATCH_SIGMA_M = 0.01
MATCH_SIGMA_RAD = math.radians(0.2)
LOOP_SIGMA_M = 0.02
LOOP_SIGMA_RAD = math.radians(0.5)
#: Information given to an edge's directions before its covariance is taken where one of them
#: has less, a standard deviation of 1 km (see :func:`edge_covariance`); the floors above cap
#: a measured direction's at 2.5e3-8e4, so the inverse stays well conditioned.
UNMEASURED_INFORMATION = 1e-6
#: Weight of odometry's pull in matching (see scan_matcher.Prior).
PRIOR_WEIGHT = 0.01
#: A loop closure's pull towards the current estimate: among equally good corridor alignments
#: the one nearest the estimate wins.
LOOP_PRIOR_SIGMA_M = 0.5
LOOP_PRIOR_SIGMA_RAD = math.radians(5.0)
#: A match is ambiguous when a clearly different pose scores within this ratio of the best.
FRONT_MAX_AMBIGUITY = 0.97
#: ... unless every pose between the two scores at least this share of the lower of them: one
#: ridge, not two peaks (see :meth:`_Slam._ridge`).
FRONT_RIDGE_SHARE = 0.9
LOOP_MAX_AMBIGUITY = 0.95
#: The loop window's floor (the front end is never better tied than this) and ceiling.
LOOP_BASE_M = 0.1
LOOP_BASE_RAD = math.radians(1.0)
LOOP_MAX_M = 2.0
LOOP_MAX_RAD = math.radians(20.0)
#: When the drift since the last closure is beyond LOOP_MAX_M the window grows up to this,
#: searched by branch and bound (scan_matcher.branch_and_bound_search).
LOOP_WIDE_M = 12.0
#: Keyframes closer than this along the run are the front end's business, not a loop.
LOOP_MIN_SEPARATION = 30
#: A submap is tried again as a loop target after this much travel, and a keyframe tries at
#: most this many targets: consecutive keyframes see the same thing, and a closure every
#: half metre ties a pass to the map as well as one per keyframe does.
LOOP_RETRY_M = 1.0
LOOP_TARGETS = 2
#: A loop target holds at least this many keyframes (see :meth:`_Slam._loop_target`).
LOOP_MIN_KEYFRAMES = 5
#: A closure against a target of few scans (see :meth:`_Slam._loop_target`) scoring under the
#: loop threshold but at least this is taken once another keyframe's closure, from at most
#: this many keyframes before it, implies the same correction (:meth:`_Slam._propose`).
LOOP_GROUP_MIN_SCORE = 0.2
LOOP_GROUP_KEYFRAMES = 10
#: Cauchy scale of loop closures, in sigmas.
LOOP_ROBUST_C = 3.0
#: Solve the graph when a new closure disagrees with it (squared Mahalanobis error over three
#: sigmas in each of its three dimensions: the correction would move the map), or when this
#: many closures wait. The estimate is warm, so a couple of iterations settle it.
SOLVE_ABOVE_CHI2 = 27.0
SOLVE_AFTER_LOOPS = 20
SOLVE_ITERATIONS = 2
FINAL_ITERATIONS = 30
#: Scans whose 90th-percentile range is shorter than this (the robot inside the elevator car)
#: are too small and symmetric for a wide search: the box matches itself turned or shifted.
#: They are matched with each other, car to car, in a fine field.
CAR_EXTENT_M = 2.5
CAR_MIN_POINTS = 30
CAR_MIN_SCORE = 0.6
#: Keyframes this near the car (on any floor) see the elevator core, and of what they see,
#: what lies this near the car is matched across floors (:meth:`_Slam._core_edges`).
CORE_RADIUS_M = 4.0
CORE_REACH_M = 6.0
#: How far the car at a ride can be from where the rides' chain of car matches puts it.
CAR_WINDOW_M = 0.3
CAR_WINDOW_RAD = math.radians(5.0)
#: A ride none of whose car keyframes is found within CAR_WINDOW is looked for this far out
#: (:meth:`_Slam._car_beyond`): a minute's drive without the laser at half a metre a second
#: leaves odometry metres and tens of degrees off (6 m and 19 degrees in the simulated run),
#: and a turn of 45 degrees stays clear of the box's own symmetries (a half turn, a quarter
#: turn of a square car).
CAR_FAR_WINDOW_M = 10.0
CAR_FAR_WINDOW_RAD = math.radians(45.0)
#: ... in the car's field at the map's resolution, by branch and bound with this many node
#: splits, its lattice turned a degree at a time (the car's walls are within 2.5 m, where a
#: degree moves a point half a cell; the refinement takes it from there), for at most this
#: many keyframes of each such ride. The pooled field of a 2 m box bounds thousands of nodes
#: near 1.0: with the loops' 300 splits, or a quarter-degree lattice, the budget ran out and
#: the search returned aliases; so it settles in 0.5-1.4 s a keyframe.
CAR_FAR_BUDGET = 30_000
CAR_FAR_ANGLE_STEP_RAD = math.radians(1.0)
CAR_FAR_PER_RIDE = 3
#: Far matches count as one correction of the chain when they agree this well.
CAR_FAR_AGREE_M = 0.15
CAR_FAR_AGREE_RAD = math.radians(2.0)
#: A step across scans the odometry said nothing about may be as long as the robot can drive
#: and turn in its time (a P3-AT: 0.7 m/s; a turn on the spot well under 90 deg/s): its
#: odometry edge has three sigmas of that.
BLIND_SPEED_M_S = 1.0
BLIND_TURN_RAD_S = math.radians(90.0)
#: After such a step across which the odometry shows no motion at all (a power-cycled base
#: counts from zero in a frame of its own, joined at its last pose), the chain has lost its
#: place: the robot turned 120 degrees on the spot in 5 s, or drove 18 m and turned 161
#: degrees in a minute, and the chain after the gap stood where "no motion" put it. So what
#: it saw in its last RELOCATE_RECENT_M is looked for in the map of its floor from before the
#: gap (the keyframes within RELOCATE_VIEW_M of the step's reach), placed in the frame of the
#: first keyframe after the gap: within the step's reach, at most RELOCATE_MAX_M (a wider
#: window is all aliases), at any heading it allows, by branch and bound with
#: RELOCATE_BUDGET splits for the whole turn; every RELOCATE_EVERY_M of the drive, at most
#: RELOCATE_TRIES times, until the visit ends.
RELOCATE_MAX_M = 10.0
RELOCATE_VIEW_M = 10.0
RELOCATE_RECENT_M = 5.0
RELOCATE_BUDGET = 60_000
RELOCATE_EVERY_M = 2.0
RELOCATE_TRIES = 40
#: The map's free space, at this cell, costs a point RELOCATE_FREE_PENALTY (what a point on
#: a wall earns) where the field is under RELOCATE_NEAR_WALL: a scan of a few pillars fits
#: several places of a hall, and one that puts walls where the robot saw through is none.
RELOCATE_FREE_CELL_M = 0.1
RELOCATE_FREE_PENALTY = 1.0
RELOCATE_NEAR_WALL = 0.1
#: A look counts with this many points, this score and a runner-up under LOOP_MAX_AMBIGUITY
#: of it; two looks that agree (CAR_FAR_AGREE) on one rigid correction move the chain.
RELOCATE_MIN_POINTS = 100
RELOCATE_MIN_SCORE = 0.4
#: A submap also ends after this many keyframes (a robot turning on the spot).
SUBMAP_MAX_KEYFRAMES = 30
#: Memory the fields of finished submaps may hold; beyond it the least recently used are
#: released and stamped again when a loop closure needs them.
SUBMAP_MEMORY_BYTES = 256 * 2**20
#: Scans between keyframes are matched against the finished map with this many beams.
REGISTER_BEAMS = 60
#: Fewest points a scan must keep to be matched at all.
MIN_POINTS = 10
#: Between keyframes a radian of turn counts as this much travel when the correction the
#: graph made is spread along the stretch (a turn in place is where odometry errs most).
TURN_AS_M = 0.5
REFINE_PASSES = 3
#: Fewest steps matched at both ends to fit odometry's noise from (three parameters each for
#: position and heading, and a trimmed tail).
MIN_NOISE_STEPS = 30
#: In the refinement (each keyframe against its floor's finished map) odometry's sigmas are that fit
#: times this; in the graph solve before it, against the front end's matches and the loop closures,
#: they are the fit itself (then every kind scaled to its scatter). The fit mixes the matches'
#: errors into odometry's (it cannot tell them apart), and the map fits carry covariances several
#: times their real error (MATCH_COV_SCALE and the floors above); at the fit itself in the
#: refinement too, odometry outweighs good fits: the Intel relations lose a quarter (0.023 -> 0.030
#: m, seed 0). Found by trying the fit itself, 2 and 3 in both solves and then in one of them (3 in
#: the refinement only: Intel seeds 0-4 at 0.021-0.024 m, the simulated building 0.035-0.056 m RMS
#: over seeds 0-4). Weighing the map fits, the core and odometry in the refinement by their own
#: scatter (as :meth:`_Slam._weigh_by_scatter` does before it) with this factor at 1 does not
#: replace it: the building gains (seed 2 0.030 m RMS) but the Intel relations lose (seeds 0-4 at
#: 0.033-0.034 m): there odometry shows under half the variance it claims and the fits a quarter,
#: yet the relations want odometry weaker still (perhaps because its errors are not independent step
#: to step, or because the fits' residuals shrink where they decide their keyframes: neither
#: measured).
REFINE_ODOMETRY_INFLATION = 3.0
#: Matching against a finished map (the refinement, the elevator core, the scans between
#: keyframes) uses a field this fraction of the front end's cell and sigma. The front end's
#: field is as wide as its search needs: a correlative search over a window of decimetres
#: wants a basin a few cells wide, and a 5 cm sigma is five times a laser's range noise. Once
#: the graph has put every keyframe within a cell of where it belongs, only Gauss-Newton from
#: there is left, and a field that wide blurs the walls it aligns to. At half (2.5 cm, still
#: above a SICK's 1-2 cm noise and the map's own spread) the ground-truth relations improved
#: on both logs that have them, beyond the spread of five draws of a seed (Intel seeds 0-4
#: mean 0.0224 -> 0.0202 m, worst over the draws 0.0242 -> 0.0215 m; Freiburg 079 mean
#: 0.0490 -> 0.0469 m), the simulated building's RMS fell on five of six recordings (mean
#: 0.040 -> 0.035 m), the ATE against GMapping's poses held (Acapulco mean 0.115 -> 0.113 m),
#: at the same time and memory (docs/mapping.md, "One run is one draw").
FINISHED_MAP_FIELD_SCALE = 0.5
#: In the graph solve before the refinement every kind of edge with at least this many edges
#: is weighed by its own scatter against the solved graph (:meth:`_Slam._weigh_by_scatter`).
SCATTER_KINDS = ("odometry", "match", "ride", "loop", "car")
MIN_SCATTER_EDGES = 30


@dataclass(slots=True)
class SlamResult:
    keyframes: IntArray  # scan index of each keyframe
    keyframe_poses: FloatArray  # (K, 3)
    scan_poses: FloatArray  # (S, 3), every scan
    graph: PoseGraph
    loop_edges: list[tuple[int, int]] = field(default_factory=list)  # keyframe ids
    #: closures between the closed elevator car at different rides (any floors)
    car_edges: list[tuple[int, int]] = field(default_factory=list)
    stats: dict[str, float] = field(default_factory=dict)
    #: odometry's systematic errors as learnt (:mod:`baromap.mapping.odometry_calibration`):
    #: distance factor, turn factor - 1, heading creep [rad/m]; (1, 0, 0) when unknown
    odometry_correction: tuple[float, float, float] = (1.0, 0.0, 0.0)


def select_keyframes(
    odom: FloatArray, visit: IntArray, floor: IntArray, config: SlamConfig
) -> IntArray:
    """Scans where the robot has moved enough since the last keyframe of the same visit, and
    the first and last scan of every visit (the car before and after a ride)."""
    group = np.where(floor == BETWEEN_FLOORS, -1, visit)
    return motion_spaced(odom, group, config.keyframe_m, config.keyframe_rad, last_of_group=True)


class _Keyframes:
    """Per-keyframe point clouds, filtered once, and what is known about each."""

    def __init__(
        self, scans: ScanBlock, odom: FloatArray, indices: IntArray, config: SlamConfig
    ) -> None:
        self.points = [
            voxel_filter(scans.endpoints(int(s), config.max_range_m), config.resolution_m)
            for s in indices
        ]
        #: what fields are stamped with: the surfaces the scan saw, sampled finely
        self.surfaces = [
            scans.surface(int(s), config.max_range_m, config.resolution_m / 2) for s in indices
        ]
        steps = np.hypot(*np.diff(odom[indices, :2], axis=0).T) if len(indices) > 1 else []
        self.distance = np.concatenate([[0.0], np.cumsum(steps)])
        ranges = [np.hypot(p[:, 0], p[:, 1]) for p in self.points]
        self.extent = np.array([float(np.percentile(r, 90)) if len(r) else 0.0 for r in ranges])
        self.typical_range = np.array([float(np.median(r)) if len(r) else 1.0 for r in ranges])

    def path_m(self, a: int, b: int) -> float:
        """Odometric path length between keyframes a and b."""
        return float(abs(self.distance[b] - self.distance[a]))

    def in_car(self, k: int) -> bool:
        """A small enclosed scan: the robot inside the closed elevator car."""
        return bool(len(self.points[k]) >= CAR_MIN_POINTS and self.extent[k] < CAR_EXTENT_M)


@dataclass(frozen=True, slots=True)
class _MapFits:
    """Keyframes' poses as fitted to their floor's map, with each fit's information."""

    nodes: IntArray
    poses: FloatArray
    information: FloatArray


def _graph(poses: FloatArray, edges: list[Edge]) -> PoseGraph:
    graph = PoseGraph()
    for pose in poses:
        graph.add_node(pose)
    for edge in edges:
        graph.add_edge(edge)
    return graph


@dataclass(frozen=True, slots=True)
class _Car:
    """The closed car's model: its walls seen from the first ride, in the anchor's frame."""

    anchor: int
    fine: LikelihoodField  # at half the map's cells: the car's walls are a metre away
    far: LikelihoodField  # at the map's cells, for the search beyond the chain's window
    coarse: LikelihoodField = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "coarse", self.fine.pooled(COARSE_STEP_CELLS))


@dataclass(slots=True)
class _Lost:
    """The chain after a step across the odometry's silence, while it looks for its place:
    the map from before, in the frame of the last keyframe before the step."""

    before: int
    start: int  # the first keyframe after the silence
    window: SearchWindow
    fld: LikelihoodField
    #: the rigid corrections of the chain the unambiguous looks so far asked for
    found: list[FloatArray] = field(default_factory=list)
    tried: int = 0
    tried_at: float = -math.inf  # the chain's path at the last look


def _free_space_costs(
    fld: LikelihoodField, frame: FloatArray, grid: OccupancyGrid
) -> LikelihoodField:
    """``fld`` (in the frame of the pose ``frame``) with RELOCATE_FREE_PENALTY wherever
    ``grid`` (the same map's occupancy, in the world) is free and the field near nothing."""
    h, w = fld.data.shape
    res = fld.resolution
    cx, cy = np.meshgrid(
        fld.origin_xy[0] + np.arange(w) * res, fld.origin_xy[1] + np.arange(h) * res
    )
    world = se2.transform_points(frame, np.stack([cx.ravel(), cy.ravel()], axis=1))
    col = np.floor((world[:, 0] - grid.origin_xy[0]) / grid.resolution).astype(np.int64)
    row = np.floor((world[:, 1] - grid.origin_xy[1]) / grid.resolution).astype(np.int64)
    gh, gw = grid.shape
    inside = (col >= 0) & (col < gw) & (row >= 0) & (row < gh)
    free = np.zeros(h * w, dtype=bool)
    free[inside] = grid.free()[row[inside], col[inside]]
    free = free.reshape(h, w) & (fld.data < RELOCATE_NEAR_WALL)
    data = np.where(free, np.float32(-RELOCATE_FREE_PENALTY), fld.data).astype(np.float32)
    return LikelihoodField(data=data, origin_xy=fld.origin_xy, resolution=res)


def _same_shift(a: FloatArray, b: FloatArray) -> bool:
    """Two rigid corrections of the chain that agree (CAR_FAR_AGREE)."""
    d = se2.between(a, b)
    return bool(
        math.hypot(d[0], d[1]) <= CAR_FAR_AGREE_M and abs(se2.wrap(d[2])) <= CAR_FAR_AGREE_RAD
    )


def _info(sigma_xy: float, sigma_theta: float) -> FloatArray:
    return np.diag([1 / sigma_xy**2, 1 / sigma_xy**2, 1 / sigma_theta**2])


def _finished_map_field(world: FloatArray, resolution: float) -> LikelihoodField:
    """The field a keyframe or scan is refined against once the graph holds the map (see
    FINISHED_MAP_FIELD_SCALE), of the map's points thinned to one per half front-end cell:
    passes through one place repeat their points."""
    fine = resolution * FINISHED_MAP_FIELD_SCALE
    return LikelihoodField.from_points(voxel_filter(world, resolution / 2), fine, fine)


def match_information(information: FloatArray, sigma_xy: float, sigma_theta: float) -> FloatArray:
    """Edge information from a match: inflated GN covariance plus a floor, inverted (in the
    frame the match was made in; :func:`_rotate_info` takes it into the edge's frame).

    ``(H^-1 s + F)^-1`` is computed as ``(I + H F / s)^-1 H / s``, which needs no inverse of
    ``H``: a scan with a handful of points along one wall (a laser that sees little in a hall)
    has an information matrix of rank one, whose inverse is ``inf`` or garbage and made the old
    double inversion raise. A direction the scan did not measure gets no information here.
    """
    h = np.asarray(information, dtype=np.float64) / MATCH_COV_SCALE
    floor = np.diag([sigma_xy**2, sigma_xy**2, sigma_theta**2])
    out = np.asarray(np.linalg.solve(np.eye(3) + h @ floor, h), dtype=np.float64)
    symmetric: FloatArray = (out + out.T) / 2
    return symmetric


def spread_information(information: FloatArray, spread: FloatArray) -> FloatArray:
    """Information of a measurement whose covariance is widened by ``spread spread^T``: it
    says nothing more precise than the spread along that direction, and as much as before
    across it. Sherman-Morrison, ``H - H d (H d)^T / (1 + d^T H d)``, so a singular ``H`` (a
    direction the scan did not measure) needs no inverse."""
    h = np.asarray(information, dtype=np.float64)
    hd = h @ spread
    out: FloatArray = h - np.outer(hd, hd) / (1.0 + float(spread @ hd))
    symmetric: FloatArray = (out + out.T) / 2
    return symmetric


def edge_covariance(information: FloatArray) -> FloatArray:
    """An edge's covariance from its information, finite where the edge measured nothing.

    :func:`match_information` leaves a direction a scan did not measure without information;
    such a direction (information under ``UNMEASURED_INFORMATION``) is given that much, a
    standard deviation of 1 km, instead of an inverse that raises. An edge that measured every
    direction is inverted as it is.
    """
    info = np.asarray(information, dtype=np.float64)
    if float(np.linalg.eigvalsh(info)[0]) < UNMEASURED_INFORMATION:
        info = info + UNMEASURED_INFORMATION * np.eye(3)
    cov: FloatArray = np.asarray(np.linalg.inv(info), dtype=np.float64)
    return cov


def place_on_ridge(
    guess: FloatArray, guess_info: FloatArray, best: FloatArray, spread: FloatArray
) -> FloatArray:
    """The pose on the ridge from ``best`` to ``best + spread`` that odometry's ``guess``
    (weighed by its information) likes best. The ridge was seen between its two ends only:
    a pose beyond them is where the scan fits worse, so the choice stops at the ends."""
    miss = guess - best
    miss[2] = float(se2.wrap(miss[2]))
    along = float(spread @ guess_info @ spread)
    t = float(np.clip(spread @ guess_info @ miss / along, 0.0, 1.0)) if along > 0 else 0.0
    out: FloatArray = best + t * spread
    out[2] = float(se2.wrap(out[2]))
    return out


def _rotate_info(info: FloatArray, theta: float) -> FloatArray:
    """Information in the frame of the matched pose (heading ``theta`` in the frame the match
    was made in), where the pose graph expresses an edge's translational error."""
    c, s = math.cos(theta), math.sin(theta)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out: FloatArray = rot.T @ info @ rot
    return out


def _angle_step(typical_range_m: float, resolution: float) -> float:
    """Lattice rotation step that moves a typical point of the scan by about one cell."""
    return min(MAX_ANGLE_STEP_RAD, max(MIN_ANGLE_STEP_RAD, resolution / typical_range_m))


def _window(linear: float, angular: float, angle_step: float, resolution: float) -> SearchWindow:
    coarse = COARSE_STEP_CELLS if linear > COARSE_ABOVE_CELLS * resolution else 1
    return SearchWindow(linear, angular, angle_step, coarse_step_cells=coarse)


class _SubmapIndex:
    """Finished submaps as arrays, so a keyframe finds its loop candidates without a Python
    loop over hundreds of them: anchor, bounding circle of keyframe positions (anchor frame),
    floor, last keyframe, and the path length at the last loop attempt against each."""

    def __init__(self) -> None:
        self.anchor: IntArray = np.zeros(0, dtype=np.int64)
        self.center: FloatArray = np.zeros((0, 2))
        self.radius: FloatArray = np.zeros(0)
        self.floor: IntArray = np.zeros(0, dtype=np.int64)
        self.last_keyframe: IntArray = np.zeros(0, dtype=np.int64)
        self.tried_at: FloatArray = np.zeros(0)

    def add(self, sub: Submap) -> None:
        origins = sub.origins()
        center = origins.mean(axis=0)
        radius = float(np.hypot(*(origins - center).T).max())
        self.anchor = np.append(self.anchor, sub.anchor)
        self.center = np.vstack([self.center, center])
        self.radius = np.append(self.radius, radius)
        self.floor = np.append(self.floor, sub.floor)
        self.last_keyframe = np.append(self.last_keyframe, sub.keyframes[-1])
        self.tried_at = np.append(self.tried_at, -np.inf)


class _Slam:
    """The state of one SLAM run, fed one keyframe at a time."""

    def __init__(
        self,
        scans: ScanBlock,
        odom: FloatArray,
        kf_scan: IntArray,
        *,
        kf_floor: IntArray,
        kf_visit: IntArray,
        config: SlamConfig,
        travel: FloatArray | None = None,
        blind: BoolArray | None = None,
    ) -> None:
        self.config = config
        self.odom = odom
        self.travel = travel
        #: the step to each keyframe crosses scans the odometry said nothing about
        self.blind_step = np.zeros(len(kf_scan), dtype=bool)
        #: ... and across them the odometry shows no motion at all: a base that counted from
        #: zero again, joined at its last pose (baromapd), or one that stood; where it moved,
        #: its counters went on and measured the drive
        self.unmeasured_step = np.zeros(len(kf_scan), dtype=bool)
        if blind is not None and blind.any() and len(kf_scan) > 1:
            covered = np.concatenate([[0], np.cumsum(blind)])
            ends = np.asarray(kf_scan)
            self.blind_step[1:] = covered[ends[1:] + 1] - covered[ends[:-1]] > 0
            for k in np.flatnonzero(self.blind_step):
                inside = np.arange(ends[k - 1] + 1, ends[k])
                inside = inside[blind[inside]]
                self.unmeasured_step[k] = (
                    len(inside) >= 2 and float(np.ptp(odom[inside], axis=0).max()) < 1e-6
                )
        self.t_ns = scans.t_ns
        self.scans = scans
        self.blind = np.zeros(len(odom), dtype=bool) if blind is None else blind
        self.kf_scan = kf_scan
        self.kf_floor = kf_floor
        self.kf_visit = kf_visit
        self.clouds = _Keyframes(scans, odom, kf_scan, config)
        self.graph = PoseGraph()
        self.active: list[Submap] = []
        self.finished: list[Submap] = []
        self.cache = SubmapCache(SUBMAP_MEMORY_BYTES)
        self.finished_index = _SubmapIndex()
        self.loops: list[tuple[int, int]] = []
        self.stats: Counter[str] = Counter()
        self.visit_start = 0
        self.last_closure = 0  # keyframe of the last accepted closure (or visit start)
        #: keyframe of the last front-end step the scan could not vouch for (a weak, refused
        #: or missing match: odometry or a doubtful match placed it), -1 for none
        self.last_doubtful = -1
        self.unsolved: list[int] = []  # loop edges added since the last solve
        #: closures under the threshold waiting for another to agree (see _propose)
        self.pending: list[tuple[Edge, float]] = []
        #: those of them beyond the drift model, searched for again (see _follow_beyond)
        self.beyond: list[Edge] = []
        #: closures against a target the run frames on one side only, kept until the visit
        #: ends in case no closure framed on both sides comes (see _settle_deferred)
        self.deferred: list[tuple[Edge, float]] = []
        self.car_edges: list[tuple[int, int]] = []
        #: keyframes reached by a step the fitted odometry noise does not describe: beyond the
        #: front end's window (the laser silent), or across a gap in the odometry
        self.silent_steps: set[int] = set()
        #: the chain after a step across the odometry's silence, until it finds its place
        self.lost: _Lost | None = None
        #: odometry's systematic errors, learnt from front-end matches (see the module)
        self.calibration = OdometryCalibration()
        #: covariance of each front-matched keyframe's pose (its own frame), for calibration
        self.front_cov: dict[int, FloatArray] = {}
        #: steps matched at both ends, (odometric, matched): what odometry's noise is learnt from
        self.matched_steps: list[tuple[FloatArray, FloatArray]] = []
        #: corrected odometry's noise as the run showed it (set by finish, when it can say)
        self.noise: OdometryNoise | None = None

    # ------------------------------------------------------------------ the run

    def add(self, k: int) -> None:
        graph = self.graph
        if k == 0:
            graph.add_node(self.odom[self.kf_scan[0]])
            self._insert(k)
            return
        new_visit = bool(self.kf_visit[k] != self.kf_visit[k - 1])
        if new_visit:
            self._end_visit()
            if self.lost is not None:
                log.info("the chain did not find its place after the odometry's silence")
                self.stats["relocate_failed"] += 1
                self.lost = None  # the car ties the floors after the ride
        read = self._odometry_step(k - 1, k)
        step = self.calibration.correct(read)
        guess = se2.compose(graph.poses[k - 1], step)
        graph.add_node(guess)
        sigma_xy, sigma_theta = self._odometry_sigmas(step)
        drive = self._drive(k, read)
        if drive is not None:
            drive_xy, drive_theta = self._odometry_sigmas(drive)
            if (
                WINDOW_SIGMAS * drive_xy > MAX_FRONT_WINDOW_M
                or WINDOW_SIGMAS * drive_theta > MAX_FRONT_WINDOW_RAD
            ):
                # a drive beyond the window: its doubt is the whole drive's, not its end's
                sigma_xy, sigma_theta = max(sigma_xy, drive_xy), max(sigma_theta, drive_theta)
        blind = bool(self.blind_step[k])
        if blind:
            # odometry drew a straight line here: the step is as long as the robot can drive
            # and turn in the time
            seconds = float(self.t_ns[self.kf_scan[k]] - self.t_ns[self.kf_scan[k - 1]]) / 1e9
            sigma_xy = max(sigma_xy, BLIND_SPEED_M_S * seconds / WINDOW_SIGMAS)
            sigma_theta = max(sigma_theta, BLIND_TURN_RAD_S * seconds / WINDOW_SIGMAS)
            self.stats["odometry_gaps"] += 1
        if not new_visit and (
            blind
            or WINDOW_SIGMAS * sigma_xy > MAX_FRONT_WINDOW_M
            or (drive is not None and WINDOW_SIGMAS * sigma_theta > MAX_FRONT_WINDOW_RAD)
        ):
            # a step longer than the front end's widest window can search odometry's doubt
            # over (the laser silent while the robot drove on: unplugged, power-cycled): the
            # scan is not matched against the submaps from before it, where a capped window
            # holds only aliases; it begins new ones, and loop closure, whose search widens
            # with the drift, ties them back
            self.stats["front_after_gap"] += 1
            self.silent_steps.add(k)
            self._finish_active()
        # odometry always enters the graph: along a featureless corridor it is the only
        # measurement of the motion, and the match edge's information says so
        graph.add_edge(Edge(k - 1, k, step, _info(sigma_xy, sigma_theta), "odometry"))
        if new_visit:
            self.visit_start = k
            self.last_closure = k
            self._ride(k, guess, sigma_xy, sigma_theta)
        else:
            self._front_end(k, guess, sigma_xy, sigma_theta, read)
        self._insert(k)
        if self.unmeasured_step[k] and not new_visit:
            self.lost = self._lost_at(k, sigma_xy, sigma_theta)
        if self.lost is not None:
            self._relocate(k)
        if not self.clouds.in_car(k) and k - self.visit_start >= 1:
            self._close_loops(k)
        self._solve_if_needed()

    def finish(self) -> SlamResult:
        self._end_visit()
        self._car_to_car()
        noise = self.noise = self._odometry_noise()
        self._odometry_as_learnt(noise, 1.0)
        if noise is not None:
            self._doubt_matches_beyond(noise)
        self.graph.optimize(iterations=FINAL_ITERATIONS)
        if self._weigh_by_scatter():
            self.graph.optimize(iterations=FINAL_ITERATIONS)
        if REFINE_PASSES:
            self._odometry_as_learnt(noise, REFINE_ODOMETRY_INFLATION)
        for _ in range(REFINE_PASSES):
            self._refine()
        self.stats["keyframes"] = len(self.kf_scan)
        self.stats["odometry_samples"] = self.calibration.samples
        scale = self.calibration.scale()
        turn, creep = self.calibration.turn_terms()
        log.info(
            "odometry calibration",
            samples=self.calibration.samples,
            rejected=self.calibration.rejected,
            scale=round(scale, 5),
            turn=round(turn, 5),
            creep_deg_per_m=round(math.degrees(creep), 4),
        )
        self.stats["loops"] = len(self.loops)
        self.stats["submaps"] = len(self.finished)
        self.stats["submap_releases"] = self.cache.releases
        poses = self.graph.poses.copy()
        return SlamResult(
            self.kf_scan,
            poses,
            np.zeros((0, 3)),
            self.graph,
            self.loops,
            self.car_edges,
            {k: float(v) for k, v in self.stats.items()},
            (scale, turn, creep),
        )

    def _odometry_as_learnt(self, noise: OdometryNoise | None, inflation: float) -> None:
        """Every odometry edge with what the whole run taught about odometry: its systematic
        errors taken out, and the information of the noise that corrected odometry showed
        against the steps the front end matched at both ends.

        The front end's odometry sigmas are wide on purpose: its search window must hold an
        uncalibrated robot's error (and the public logs' 2 deg/m). Once the systematic part is
        known, what is left of a P3-AT's half-metre step is millimetres and a tenth of a
        degree; weighed as centimetres and degrees, odometry lets the weakest matches decide
        (a doorway into a room, an open hall, a turn in the car), and they bend rooms and
        turn floors by fractions of a degree. The fitted noise includes the matches' own
        errors, so it is an upper bound of odometry's, never a guess below what the run shows
        (in the refinement it is inflated, see REFINE_ODOMETRY_INFLATION).

        A step over a silence of the laser or across a gap in the odometry (``silent_steps``)
        keeps the front end's sigmas:
        the noise was fitted to keyframe steps of half a metre, and a minute's drive is far
        outside them (the simulated one was 6 m and 19 degrees off, a hundred sigmas of the
        fit). Weighed by the fit, that one edge held every floor after it against the car.
        """
        edges = self.graph.edges
        for e in edges:
            if e.kind != "odometry":
                continue
            read = self._odometry_step(e.i, e.j)
            e.z = self.calibration.correct(read)
            if noise is not None and e.j not in self.silent_steps:
                sigma_xy, sigma_theta = noise.sigmas(math.hypot(read[0], read[1]), read[2])
                e.information = _info(inflation * sigma_xy, inflation * sigma_theta)
        self.graph = _graph(self.graph.poses, edges)

    def _doubt_matches_beyond(self, noise: OdometryNoise) -> None:
        """Front-end matches that put a step further from corrected odometry than the noise
        the run showed allows get a robust kernel in the last solve, as loop closures have.

        A front-end match edge is plain least squares: the front end trusts its own matches,
        and along a sparse log's corridors and after its turns of 100-170 degrees that trust
        is where the map went wrong. A probe of the worst sparse runs (every front-end step
        against GMapping's relative pose of the two scans) found the keyframes taken 0.5-1 m
        along a corridor (the next door along) or turned by 10-20 degrees where corrected
        odometry was 0.03-0.15 m and 1-5 degrees off; the next keyframe's match, against the
        submap, put the robot back, so two match edges held the wrong pose in place against
        two odometry edges, and no closure could move it. Replacing those matches by
        GMapping's steps took `intel/4` seed 2 from 0.258 to 0.061 m and `fr079/30` seed 3
        from 0.443 to 0.094 m: they are what is left.

        A match is doubted when it and corrected odometry disagree by more than both can be
        wrong together: the miss weighed by the match's own covariance plus odometry's noise
        as fitted to the matched steps (:func:`fit_noise`), beyond NOISE_OUTLIER_SIGMAS (where
        that fit itself counts a step as a wrong match). Odometry's noise alone is not the
        test: on the simulated building it is 7 mm a half-metre step, and 45 matches along
        corridors, 3-5 cm along the corridor where the match itself is weak, were doubted
        and the building bent (seed 0: 0.033 -> 0.042 m RMS, max 0.102 -> 0.157 m). A
        doubted edge keeps its weight while the graph agrees with it and yields to odometry
        and the closures where they disagree; where match and odometry agree, the chain stays
        as stiff as before.

        What it does not mend: the keyframes after a wrong match are matched against a submap
        that holds it and move with it as one piece, and the graph starts where the front end
        left them, at the doubted edges' own solution; where odometry's noise is several
        degrees (a turn) a Cauchy edge's pull, fading only as one over its residual, keeps
        them there (`fr079/30` seed 1: keyframes 56-61 stay turned by 15 degrees). Leaving
        the doubted edges out of the solve mends that, but on the simulated building it
        turned a floor by a tenth of a degree (docs/mapping.md).
        """
        edges = self.graph.edges
        doubted = 0
        for e in edges:
            if e.kind != "match":
                continue
            read = self._odometry_step(e.i, e.j)
            # the corrected odometric step as seen from where the match put k (the frame in
            # which the edge's information weighs a translation)
            miss = se2.between(e.z, self.calibration.correct(read))
            miss[2] = se2.wrap(miss[2])
            sigma_xy, sigma_theta = noise.sigmas(math.hypot(read[0], read[1]), read[2])
            both = edge_covariance(e.information) + np.diag(
                [sigma_xy**2, sigma_xy**2, sigma_theta**2]
            )
            if float(miss @ np.linalg.solve(both, miss)) > NOISE_OUTLIER_SIGMAS**2:
                e.robust_c = LOOP_ROBUST_C
                doubted += 1
        self.stats["matches_doubted"] = doubted
        self.graph = _graph(self.graph.poses, edges)

    def _weigh_by_scatter(self) -> bool:
        """Each kind of edge weighed by how it actually scatters against the solved graph.

        The information of a match is its fit's Gauss-Newton curvature inflated and floored
        (MATCH_COV_SCALE, MATCH_SIGMA_M, LOOP_SIGMA_M...): a guess at how far the shared
        errors of neighbouring beams spread it, made once for the front end's matches, loop
        closures and the car alike. Against the solved graph they show a sixth to a thirtieth
        of the variance they claim (median), and not one factor for all: on the simulated
        run (seeds 0-4) front-end matches 0.062-0.067, loop closures 0.107-0.161, car matches
        0.031-0.059 and odometry at its fitted noise 0.051-0.069; on the Intel log matches and
        closures 0.11-0.12 and odometry 0.33-0.36. Every kind with enough edges to say is
        scaled to its median scatter and the graph solved again, so the kinds weigh against
        each other as the run shows, the way odometry's noise is fitted to the matched steps
        (:func:`fit_noise`). The robust kernels' scale is in sigmas, so a closure that
        disagrees is now judged against the closures' real spread. The median of each kind's
        residuals, not a full variance-component estimate: edges that decide their own nodes
        show less than their error, and a kind is only scaled once. Returns whether any was.
        """
        factors = {}
        for kind in SCATTER_KINDS:
            count, scatter = self.graph.scatter(kind)
            if count >= MIN_SCATTER_EDGES and scatter > 0:
                self.graph.scale_information(kind, 1.0 / scatter)
                factors[kind] = round(scatter, 3)
        log.info("edges weighed by their scatter", **factors)
        return bool(factors)

    def _odometry_noise(self) -> OdometryNoise | None:
        """Corrected odometry's noise, fitted to the matched steps' residuals (None when too
        few steps were matched at both ends to say)."""
        if len(self.matched_steps) < MIN_NOISE_STEPS:
            return None
        read = np.array([r for r, _ in self.matched_steps])
        matched = np.array([m for _, m in self.matched_steps])
        corrected = np.array([self.calibration.correct(r) for r in read])
        residuals = matched - corrected
        residuals[:, 2] = se2.wrap(residuals[:, 2])
        noise = fit_noise(residuals, np.hypot(read[:, 0], read[:, 1]), read[:, 2])
        xy, theta = noise.sigmas(self.config.keyframe_m, 0.0)
        _, turn = noise.sigmas(0.0, self.config.keyframe_rad)
        log.info(
            "odometry noise",
            steps=len(read),
            sigma_m_per_keyframe_step=round(xy, 4),
            sigma_deg_per_keyframe_step=round(math.degrees(theta), 3),
            sigma_deg_per_keyframe_turn=round(math.degrees(turn), 3),
        )
        return noise

    def _refine(self) -> None:
        """Each floor's keyframes against the map of the others (see refine.py), in a graph of
        odometry, the elevator edges and the core; match and loop edges have had their say."""
        config = self.config
        poses = self.graph.poses.copy()
        nodes: list[IntArray] = []
        measured: list[FloatArray] = []
        infos: list[FloatArray] = []
        for floor in np.unique(self.kf_floor):
            ids = np.flatnonzero(self.kf_floor == floor)
            for parity in (0, 1):
                mine, other = ids[ids % 2 == parity], ids[ids % 2 != parity]
                if len(mine) == 0 or len(other) == 0:
                    continue
                world = np.concatenate(
                    [se2.transform_points(poses[k], self.clouds.surfaces[k]) for k in other]
                )
                fld = _finished_map_field(world, config.resolution_m)
                points, owner = concatenate([self.clouds.points[k] for k in mine])
                out = refine_batch(fld, points, owner, poses[mine])
                info = np.array(
                    [match_information(h, MATCH_SIGMA_M, MATCH_SIGMA_RAD) for h in out.information]
                )
                nodes.append(mine[out.usable])
                measured.append(out.poses[out.usable])
                infos.append(info[out.usable])
        # odometry as the whole run taught it (see _odometry_as_learnt)
        kept = [e for e in self.graph.edges if e.kind in ("odometry", "ride", "car")]
        kept += self._core_edges(poses)
        fits = _MapFits(
            np.concatenate(nodes) if nodes else np.zeros(0, dtype=np.int64),
            np.concatenate(measured) if nodes else np.zeros((0, 3)),
            np.concatenate(infos) if nodes else np.zeros((0, 3, 3)),
        )
        if len(np.unique(self.kf_floor)) > 1:
            self.graph = self._solve_with_floor_frames(poses, kept, fits)
        else:  # one floor: nothing to turn it against, the fits hold it where it is
            graph = _graph(poses, kept)
            graph.set_priors(fits.nodes, fits.poses, fits.information)
            # the fits are poses in the map's frame, so they fix the frame themselves: pinning
            # the first keyframe where the graph solve left it as well (the solver's usual
            # anchor) would keep the run's start off its own map, the place a run comes back
            # to at its end (Acapulco seed 0: scan 0 needed a 75 mm move to lie on its
            # revisits, 26 mm once free, GMapping's poses 28 mm)
            graph.optimize(iterations=FINAL_ITERATIONS, anchor=None if len(fits.nodes) else 0)
            self.graph = graph
        self.stats["refined"] = len(fits.nodes)

    def _solve_with_floor_frames(
        self, poses: FloatArray, edges: list[Edge], fits: _MapFits
    ) -> PoseGraph:
        """The last solve, with each floor's map fits relative to a frame of that floor.

        A fit says where a keyframe stands on its floor's map, and that map is in the frame
        the floor had when it was drawn. As priors in that frame they would hold each floor
        where it stands; relative to a node of the floor's own (one per floor, free) they
        keep the floor's shape, and where the floor stands against the others is decided by
        the edges that join floors (the rides, the car, the core).
        """
        count = len(poses)
        graph = _graph(poses, edges)
        frames = {int(f): graph.add_node(np.zeros(3)) for f in np.unique(self.kf_floor)}
        owner = np.array([frames[int(f)] for f in self.kf_floor[fits.nodes]], dtype=np.int64)
        for k, frame, z, info in zip(fits.nodes, owner, fits.poses, fits.information, strict=True):
            graph.add_edge(Edge(int(frame), int(k), z.copy(), _rotate_info(info, z[2]), "map"))
        graph.optimize(iterations=FINAL_ITERATIONS)
        solved = graph.poses
        # the graph handed on: keyframes only, the fits as priors where their floors went
        final = _graph(solved[:count], edges)
        if len(fits.nodes):
            moved = solved[owner]
            infos = np.array(
                [_rotate_info(i, -t) for i, t in zip(fits.information, moved[:, 2], strict=True)]
            )
            final.set_priors(fits.nodes, se2.compose(moved, fits.poses), infos)
        return final

    def _core_edges(self, poses: FloatArray) -> list[Edge]:
        """The elevator core on every visit against the core on every other visit.

        The shaft is vertical, so the car and the walls around its doors stand at the same
        place on every floor: keyframes near the car, on any visit, see one structure. Each
        visit's keyframes near the car are stamped into a field in the frame of the first of
        them; every other visit's keyframes near the car are matched against it (Gauss-Newton
        from where the car edges put them) and enter as robust edges. A floor whose lobby
        differs finds little to match (the score stays low) and adds nothing.
        """
        cars = [k for ride in self._car_ends() for k in ride]
        if not cars:
            return []
        center = poses[cars, :2].mean(axis=0)
        res = self.config.resolution_m
        near = np.hypot(poses[:, 0] - center[0], poses[:, 1] - center[1]) < CORE_RADIUS_M
        visits = {
            int(v): np.flatnonzero(near & (self.kf_visit == v)) for v in np.unique(self.kf_visit)
        }
        visits = {v: ids for v, ids in visits.items() if len(ids) >= 3}
        edges: list[Edge] = []
        if len(visits) < 2:
            # one visit near the car (a map the others were lost from): nothing to tie
            self.stats["core_edges"] = 0
            return edges
        for v, ids in visits.items():
            anchor = int(ids[0])
            clouds = []
            for k in ids:
                pts = se2.transform_points(poses[k], self.clouds.surfaces[k])
                keep = np.hypot(pts[:, 0] - center[0], pts[:, 1] - center[1]) < CORE_REACH_M
                clouds.append(se2.transform_points(se2.inverse(poses[anchor]), pts[keep]))
            fld = _finished_map_field(np.concatenate(clouds), res)
            others = np.concatenate([o for w, o in visits.items() if w != v])
            clouds = []
            for k in others:
                pts = self.clouds.points[k]
                world = se2.transform_points(poses[k], pts)
                clouds.append(
                    pts[np.hypot(world[:, 0] - center[0], world[:, 1] - center[1]) < CORE_REACH_M]
                )
            points, owner = concatenate(clouds)
            start = se2.between(poses[anchor][None, :], poses[others])
            out = refine_batch(fld, points, owner, start)
            for n in np.flatnonzero(out.usable):
                info = match_information(out.information[n], LOOP_SIGMA_M, LOOP_SIGMA_RAD)
                edges.append(
                    Edge(
                        anchor,
                        int(others[n]),
                        out.poses[n].copy(),
                        _rotate_info(info, out.poses[n, 2]),
                        "core",
                        robust_c=LOOP_ROBUST_C,
                    )
                )
        self.stats["core_edges"] = len(edges)
        return edges

    def _sides_of_silences(self) -> Int8Array:
        """For the scans between the keyframes of a silent step: -1 before the silence, +1
        after it, split at the longest wait between two scans the odometry spoke for (the
        gap, with the scans it said nothing about inside; the robot may have stood a while
        before it, so the middle of the step is not the gap); 0 for every other scan."""
        side = np.zeros(len(self.odom), dtype=np.int8)
        t = self.t_ns
        for k in sorted(self.silent_steps):
            a, b = int(self.kf_scan[k - 1]), int(self.kf_scan[k])
            s = np.arange(a + 1, b)
            heard = np.concatenate([[a], s[~self.blind[s]], [b]])
            resumed = heard[int(np.argmax(np.diff(t[heard]))) + 1]
            side[s] = np.where(s >= resumed, 1, -1)
        return side

    def register_scans(self, scans: ScanBlock, floor: IntArray) -> FloatArray:
        """Every scan's pose: keyframes as the graph has them; the scans between them
        interpolated (:func:`scan_poses`) and then matched against the finished map of their
        floor, pulled towards the interpolation as odometry would (a corridor cannot make a
        scan slide). A scan that finds too little of the map keeps its interpolated pose.

        The pull's sigmas are corrected odometry's noise as the run showed it
        (:meth:`_odometry_noise`) over the travel and turn to the nearer keyframe, where the
        interpolation is pinned: what the interpolation can be wrong by. The front end's
        search sigmas (2 cm + 7 %/m, wide on purpose to hold an uncalibrated robot) are used
        only when the run matched too few steps to fit the noise."""
        config = self.config
        kf_poses = self.graph.poses
        poses = scan_poses(self.odom, self.kf_scan, kf_poses, silence=self._sides_of_silences())
        is_kf = np.zeros(len(poses), dtype=bool)
        is_kf[self.kf_scan] = True
        # odometric distance of every scan to the nearer keyframe (how much odometry it holds)
        travelled = np.concatenate(
            [[0.0], np.cumsum(np.hypot(*np.diff(self.odom[:, :2], axis=0).T))]
        )
        kf_travel = travelled[self.kf_scan]
        pos = np.clip(np.searchsorted(kf_travel, travelled), 1, max(len(kf_travel) - 1, 1))
        after = np.minimum(pos, len(kf_travel) - 1)

        def to_nearer_keyframe(along: FloatArray) -> FloatArray:
            at_kf = along[self.kf_scan]
            return np.minimum(np.abs(along - at_kf[pos - 1]), np.abs(at_kf[after] - along))

        to_kf = to_nearer_keyframe(travelled)
        turned = np.concatenate([[0.0], np.cumsum(np.abs(se2.wrap(np.diff(self.odom[:, 2]))))])
        turn_to_kf = to_nearer_keyframe(turned)
        for f in np.unique(self.kf_floor):
            todo = np.flatnonzero((floor == f) & ~is_kf)
            if len(todo) == 0:
                continue
            ids = np.flatnonzero(self.kf_floor == f)
            world = np.concatenate(
                [se2.transform_points(kf_poses[k], self.clouds.surfaces[k]) for k in ids]
            )
            fld = _finished_map_field(world, config.resolution_m)
            points, owner = scans.sampled_endpoints(todo, config.max_range_m, REGISTER_BEAMS)
            d = to_kf[todo]
            if self.noise is not None:
                pull = Pull(*self.noise.sigmas_many(d, turn_to_kf[todo]))
            else:
                pull = Pull(
                    ODOMETRY_SIGMA_M + config.odometry_sigma_m_per_m * d,
                    ODOMETRY_SIGMA_RAD + math.radians(config.odometry_sigma_deg_per_m) * d,
                )
            out = refine_batch(fld, points, owner, poses[todo], pull)
            poses[todo[out.usable]] = out.poses[out.usable]
            self.stats["registered"] += int(out.usable.sum())
        return poses

    def _drive(self, k: int, step: FloatArray) -> FloatArray | None:
        """The odometric ``step`` to keyframe k as the odometry drove it: its path and every
        turn on the way, as a step (path, 0, turn); None when the odometry came only with
        the scans."""
        if self.travel is None:
            return None
        path, turn = self.travel[self.kf_scan[k]] - self.travel[self.kf_scan[k - 1]]
        return np.array([max(path, math.hypot(step[0], step[1])), 0.0, max(turn, abs(step[2]))])

    def _odometry_sigmas(self, step: FloatArray) -> tuple[float, float]:
        config = self.config
        dist = math.hypot(step[0], step[1])
        sigma_xy = ODOMETRY_SIGMA_M + config.odometry_sigma_m_per_m * dist
        sigma_theta = (
            ODOMETRY_SIGMA_RAD
            + math.radians(config.odometry_sigma_deg_per_m) * dist
            + config.odometry_sigma_per_rad * abs(step[2])
        )
        return sigma_xy, sigma_theta

    # ------------------------------------------------------------------ submaps

    def _insert(self, k: int) -> None:
        config = self.config
        newest = self.active[-1] if self.active else None
        if (
            newest is None
            or self.clouds.path_m(newest.anchor, k) >= config.submap_m
            or len(newest.keyframes) >= SUBMAP_MAX_KEYFRAMES
        ):
            self.active.append(
                Submap(
                    k,
                    int(self.kf_floor[k]),
                    config.resolution_m,
                    config.resolution_m,
                    self.clouds.surfaces,
                )
            )
            if len(self.active) > 2:
                self._finish_submap(self.active.pop(0))
        poses = self.graph.poses
        for sub in self.active:
            sub.insert(k, se2.between(poses[sub.anchor], poses[k]))

    def _finish_submap(self, sub: Submap) -> None:
        sub.finish()
        if len(sub.keyframes) >= 2:
            self.finished.append(sub)
            self.finished_index.add(sub)
            self.cache.use(sub)

    def _end_visit(self) -> None:
        self._settle_deferred()
        self._finish_active()

    def _finish_active(self) -> None:
        """The submaps being built are finished: the next keyframe begins new ones."""
        while self.active:
            self._finish_submap(self.active.pop(0))

    # ------------------------------------------------------------------ front end

    def _odometry_step(self, a: int, b: int) -> FloatArray:
        """Odometry's motion from keyframe a to keyframe b, as the wheels read it."""
        return se2.between(self.odom[self.kf_scan[a]], self.odom[self.kf_scan[b]])

    def _learn_odometry(self, k: int, read: FloatArray, edge: Edge) -> None:
        """Keyframe k was matched: with k - 1 matched too, the step between them is measured at
        both ends, a sample of what odometry got wrong (:mod:`odometry_calibration`)."""
        # k's pose, in k's own frame
        cov = edge_covariance(edge.information)
        self.front_cov[k] = cov
        before = self.front_cov.get(k - 1)
        if before is not None:
            # k's covariance in the frame of k - 1 (k stands turned by z's heading in it)
            in_before = _rotate_info(cov, -float(edge.z[2]))
            self.calibration.observe(read, edge.z, before + in_before)
            self.matched_steps.append((read.copy(), edge.z.copy()))

    def _front_end(
        self, k: int, guess: FloatArray, sigma_xy: float, sigma_theta: float, read: FloatArray
    ) -> None:
        points = self.clouds.points[k]
        if len(points) < MIN_POINTS or not self.active:
            self.stats["front_skipped"] += 1
            self.last_doubtful = k
            return
        config = self.config
        sub = self.active[0]
        anchor = self.graph.poses[sub.anchor]
        local_guess = se2.between(anchor, guess)
        linear = min(MAX_FRONT_WINDOW_M, max(MIN_WINDOW_M, WINDOW_SIGMAS * sigma_xy))
        angular = min(MAX_FRONT_WINDOW_RAD, max(MIN_WINDOW_RAD, WINDOW_SIGMAS * sigma_theta))
        window = _window(
            linear,
            angular,
            _angle_step(self.clouds.typical_range[k], config.resolution_m),
            config.resolution_m,
        )
        prior = Prior(local_guess, sigma_xy, sigma_theta, PRIOR_WEIGHT)
        if self.clouds.extent[k] < CAR_EXTENT_M:
            # a small enclosure (the elevator car): its walls are a metre away, where a 5 cm
            # cell blurs a degree of rotation, so it is matched in a field twice as fine made
            # of what the submap's keyframes saw of it
            fld = self._fine_field(sub, local_guess)
            window = SearchWindow(window.linear_m, window.angular_rad, MIN_ANGLE_STEP_RAD)
            result = match(fld, points, local_guess, window, prior=prior)
        else:
            fld = sub.field
            coarse = sub.coarse(window.coarse_step_cells) if window.coarse_step_cells > 1 else None
            result = match(fld, points, local_guess, window, coarse_field=coarse, prior=prior)
            if result.score < FRONT_RETRY_BELOW and abs(read[2]) > FRONT_RETRY_TURN_RAD:
                result = self._retry_after_turn(k, sub.anchor, result, window=window, prior=prior)
        ambiguous = result.runner_up >= FRONT_MAX_AMBIGUITY * result.score
        spread = self._ridge(fld, points, result) if ambiguous else None
        if spread is not None:
            ambiguous = False
            self.stats["front_ridges"] += 1
        if result.score < FRONT_RETRY_BELOW or ambiguous:
            self.last_doubtful = k
        if result.score < config.front_min_score:
            self.stats["front_failures"] += 1
            return
        if ambiguous:
            self.stats["front_ambiguous"] += 1
            return
        edge = self._match_edge(sub.anchor, k, result, kind="match", spread=spread)
        placed = result.pose
        if spread is not None:
            placed = place_on_ridge(local_guess, _info(sigma_xy, sigma_theta), result.pose, spread)
        self.graph.poses[k] = se2.compose(anchor, placed)
        # the measurement is expressed from the previous keyframe, whose pose the submap
        # holds as the graph last had it: a solve that bends the run between the anchor and
        # the previous keyframe then moves this edge with it
        edge.i = k - 1
        edge.z = se2.between(se2.between(anchor, self.graph.poses[k - 1]), result.pose)
        self.graph.add_edge(edge)
        self.stats["front_matches"] += 1
        self._learn_odometry(k, read, edge)

    def _retry_after_turn(
        self,
        k: int,
        anchor: int,
        result: MatchResult,
        *,
        window: SearchWindow,
        prior: Prior,
    ) -> MatchResult:
        """A poor match after a turn of more than FRONT_RETRY_TURN_RAD, tried again against
        the keyframes of the last FRONT_RETRY_M of travel (:meth:`_recent_field`); the better
        scoring of the two is kept unless it is ambiguous.

        On a sparse log a turn of 100-170 degrees between two scans is where the front end
        broke: odometry is several degrees off over such a turn (8-9 on `fr079/30`), and the
        scan, looking back, overlaps the submap of the last metres (seen looking forward)
        too little to match. The retry lowered the heading error of the steps where it was
        taken from 5.6 to 2.5 degrees (mean, `fr079/30` seeds 0-2) and 4.8 to 3.9 (`intel/4`).
        """
        wider = self._recent_field(k, anchor)
        if wider is None:
            return result
        step = window.coarse_step_cells
        coarse = wider.pooled(step) if step > 1 else None
        again = match(
            wider, self.clouds.points[k], prior.pose, window, coarse_field=coarse, prior=prior
        )
        self.stats["front_retries"] += 1
        if again.score > result.score and again.runner_up < FRONT_MAX_AMBIGUITY * again.score:
            self.stats["front_retried"] += 1
            return again
        return result

    def _recent_field(self, k: int, anchor: int) -> LikelihoodField | None:
        """The keyframes of this visit over the last FRONT_RETRY_M of travel before k, in the
        anchor's frame: after a turn the robot looks back over where it came from, which the
        active submap (the last few metres, seen looking forward) hardly holds."""
        poses = self.graph.poses
        start = k - 1
        while start > self.visit_start and self.clouds.path_m(start - 1, k) <= FRONT_RETRY_M:
            start -= 1
        ids = range(start, k)
        if len(ids) < 2:
            return None
        base = se2.inverse(poses[anchor])
        world = np.concatenate(
            [
                se2.transform_points(se2.compose(base, poses[j]), self.clouds.surfaces[j])
                for j in ids
            ]
        )
        res = self.config.resolution_m
        return LikelihoodField.from_points(voxel_filter(world, res / 2), res, res)

    def _fine_field(self, sub: Submap, local_guess: FloatArray) -> LikelihoodField:
        """Half-cell field of the submap's points within reach of a small enclosure."""
        reach = CAR_EXTENT_M + MAX_FRONT_WINDOW_M
        clouds = []
        for k, pose in zip(sub.keyframes, sub.local_poses, strict=True):
            pts = se2.transform_points(pose, self.clouds.surfaces[k])
            near = np.hypot(pts[:, 0] - local_guess[0], pts[:, 1] - local_guess[1]) < reach
            clouds.append(pts[near])
        res = self.config.resolution_m / 2
        return LikelihoodField.from_points(np.concatenate(clouds), res, res)

    def _ridge(
        self, fld: LikelihoodField, points: FloatArray, result: MatchResult
    ) -> FloatArray | None:
        """An ambiguous match's runner-up minus its best, when the two are ends of one ridge.

        A sparse scan in a hall (a metre or two from the last, its beams a degree apart and
        tens of metres long) fits about as well anywhere over a few decimetres: the search's
        best and a runner-up 0.3 m off score alike, and both hold the heading. Refused, the
        keyframe stood where odometry put it, degrees off after a turn, and the next scans
        matched against it (`acapulco/2` seed 0 of the varied odometry: one such keyframe
        3.8 deg off turned the first 200 m of the run, 0.96 m ATE). Two peaks with a valley
        between them (the next door along a corridor) stay ambiguous, and so do two answers
        turned against each other: a scan that cannot tell its heading to 5 degrees has not
        measured it (taken in a first version, such keyframes of `intel/4` were placed 3.3-15.7
        degrees off where odometry was 0.3-2.5 degrees off).
        """
        other = result.runner_up_pose
        if other is None or abs(float(se2.wrap(other[2] - result.pose[2]))) > DISTINCT_RAD:
            return None
        ends = min(result.score, score_at(fld, points, other))
        if lowest_between(fld, points, result.pose, other) < FRONT_RIDGE_SHARE * ends:
            return None
        spread: FloatArray = other - result.pose
        spread[2] = float(se2.wrap(spread[2]))
        return spread

    def _match_edge(
        self,
        anchor: int,
        k: int,
        result: MatchResult,
        *,
        kind: str,
        spread: FloatArray | None = None,
    ) -> Edge:
        """Edge anchor -> k from a match of keyframe k made in the anchor's frame.

        Front-end and car edges are trusted (plain least squares); loop closures get the
        robust kernel and their own floor sigmas, and can be outvoted.
        """
        loop = kind in ("loop", "car")
        info = match_information(
            result.information,
            LOOP_SIGMA_M if loop else MATCH_SIGMA_M,
            LOOP_SIGMA_RAD if loop else MATCH_SIGMA_RAD,
        )
        if spread is not None:
            info = spread_information(info, spread)
        return Edge(
            anchor,
            k,
            result.pose.copy(),
            _rotate_info(info, result.pose[2]),
            kind,
            robust_c=LOOP_ROBUST_C if loop else None,
        )

    # ------------------------------------------------------------------ the car

    def _car_match(self, a: int, b: int, guess_b: FloatArray, window: SearchWindow) -> MatchResult:
        """Match car keyframe b against car keyframe a, in a's frame, on a fine field: the car's
        walls are a metre away, where a degree of rotation moves points less than a 5 cm cell."""
        res = self.config.resolution_m / 2
        fld = LikelihoodField.from_points(self.clouds.surfaces[a], res, res)
        local = se2.between(self.graph.poses[a], guess_b)
        return match(fld, self.clouds.points[b], local, window)

    def _ride(self, k: int, guess: FloatArray, sigma_xy: float, sigma_theta: float) -> None:
        """The ride: both keyframes see the closed car, which travels with the robot, so
        matching them measures how the robot moved in the car while the floors changed."""
        if not (self.clouds.in_car(k - 1) and self.clouds.in_car(k)):
            return
        window = SearchWindow(
            min(MAX_FRONT_WINDOW_M, max(MIN_WINDOW_M, WINDOW_SIGMAS * sigma_xy)),
            min(MAX_FRONT_WINDOW_RAD, max(MIN_WINDOW_RAD, WINDOW_SIGMAS * sigma_theta)),
            MIN_ANGLE_STEP_RAD,
        )
        result = self._car_match(k - 1, k, guess, window)
        if result.score >= CAR_MIN_SCORE and result.runner_up < FRONT_MAX_AMBIGUITY * result.score:
            self.graph.poses[k] = se2.compose(self.graph.poses[k - 1], result.pose)
            self.graph.add_edge(self._match_edge(k - 1, k, result, kind="ride"))
            self.stats["ride_matches"] += 1

    def _car_ends(self) -> list[list[int]]:
        """Keyframes in the closed car at each ride: the end of the visit before and the start
        of the visit after, one list per ride."""
        rides = []
        count = len(self.kf_scan)
        for k in np.flatnonzero(np.diff(self.kf_visit) != 0) + 1:
            group = []
            j = int(k) - 1
            while j >= 0 and self.kf_visit[j] == self.kf_visit[k - 1] and self.clouds.in_car(j):
                group.append(j)
                j -= 1
            j = int(k)
            while j < count and self.kf_visit[j] == self.kf_visit[k] and self.clouds.in_car(j):
                group.append(j)
                j += 1
            if group:
                rides.append(sorted(group))
        return rides

    def _car_to_car(self) -> None:
        """The car at every ride against the car at the first: the same car in the same
        shaft, on whatever floor, so all floors share one frame through it.

        The car's model is made of the car keyframes of the first ride (the robot turning in
        it sees it from several sides), in the frame of the first of them. A ride whose car
        is nowhere near where the chain puts it (the laser silent while the robot drove to
        the lift) is looked for further out (:meth:`_car_beyond`).
        """
        rides = self._car_ends()
        if len(rides) < 2:
            return
        poses = self.graph.poses
        model, anchor = rides[0], rides[0][0]
        res = self.config.resolution_m / 2
        points = np.concatenate(
            [
                se2.transform_points(se2.between(poses[anchor], poses[m]), self.clouds.surfaces[m])
                for m in model
            ]
        )
        car = _Car(
            anchor,
            LikelihoodField.from_points(points, res, res),
            LikelihoodField.from_points(points, 2 * res, 2 * res),
        )
        missed = [ride for ride in rides[1:] if not self._car_closures(car, ride)]
        self.stats["car_rides_missed"] = len(missed)
        if missed and self._car_beyond(car, missed):
            for ride in missed:
                self._car_closures(car, ride)

    def _car_closures(self, car: _Car, ride: list[int]) -> int:
        """Each car keyframe of a ride matched against the car's model, within CAR_WINDOW of
        where the graph puts it; returns how many closures were taken."""
        window = SearchWindow(
            CAR_WINDOW_M, CAR_WINDOW_RAD, MIN_ANGLE_STEP_RAD, coarse_step_cells=COARSE_STEP_CELLS
        )
        taken = 0
        for b in ride:
            result = self._car_search(car, b, window)
            if result is None or result.score < CAR_MIN_SCORE:
                continue
            self.graph.add_edge(self._match_edge(car.anchor, b, result, kind="car"))
            self.car_edges.append((car.anchor, b))
            self.stats["car_closures"] += 1
            taken += 1
        return taken

    def _car_search(
        self, car: _Car, b: int, window: SearchWindow, *, wide: bool = False
    ) -> MatchResult | None:
        """Car keyframe b matched against the car's model; None when ambiguous."""
        local = se2.between(self.graph.poses[car.anchor], self.graph.poses[b])
        if wide:
            result = match(
                car.far, self.clouds.points[b], local, window, wide=True, budget=CAR_FAR_BUDGET
            )
        else:
            result = match(car.fine, self.clouds.points[b], local, window, coarse_field=car.coarse)
        if result.runner_up >= LOOP_MAX_AMBIGUITY * result.score:
            return None
        return result

    def _car_beyond(self, car: _Car, missed: list[list[int]]) -> bool:
        """The rides whose car was not where the chain put it, looked for as far as a drive
        without the laser can have carried the chain (CAR_FAR_WINDOW).

        A silence of a minute on the way to the lift leaves the chain metres and tens of
        degrees off at the ride, and every floor after it with it: matched within
        CAR_WINDOW the car is not found, and a closure metres off, among edges that all
        agree with the chain, is what the robust kernel is for, so it would be given no
        weight. Far out, a box can match a wall or a corner of itself, so a far match is
        taken only where another far match (the same ride's other keyframes, a later ride)
        asks for the same rigid correction of the chain. The agreeing matches then pull the
        graph in one plain least-squares solve: the correction goes where the graph is
        weakest, the silent step's odometry, and the car is matched again within CAR_WINDOW
        from there as at every other ride. Returns whether the graph was moved.
        """
        window = SearchWindow(CAR_FAR_WINDOW_M, CAR_FAR_WINDOW_RAD, CAR_FAR_ANGLE_STEP_RAD)
        poses = self.graph.poses
        found: list[tuple[int, MatchResult, FloatArray]] = []
        for ride in missed:
            mine = 0
            for b in ride:
                if mine == CAR_FAR_PER_RIDE:
                    break
                result = self._car_search(car, b, window, wide=True)
                if result is None or result.score < CAR_MIN_SCORE:
                    continue
                moved = se2.compose(poses[car.anchor], result.pose)
                found.append((b, result, se2.compose(moved, se2.inverse(poses[b]))))
                mine += 1
        pulls = []
        moves = []  # how far each pulling match puts its keyframe from where the chain had it
        for b, result, shift in found:
            if any(other is not shift and _same_shift(shift, other) for _, _, other in found):
                edge = self._match_edge(car.anchor, b, result, kind="car")
                edge.robust_c = None
                pulls.append(edge)
                moves.append(se2.between(poses[b], se2.compose(poses[car.anchor], result.pose)))
        self.stats["car_far_matches"] = len(pulls)
        if not pulls:
            return False
        log.info(
            "the car found beyond the chain's window",
            rides=len(missed),
            matches=len(pulls),
            moved_m=round(max(math.hypot(m[0], m[1]) for m in moves), 2),
            turned_deg=round(max(abs(math.degrees(se2.wrap(m[2]))) for m in moves), 1),
        )
        kept = list(self.graph.edges)
        self.graph = _graph(poses, kept + pulls)
        self.graph.optimize(iterations=FINAL_ITERATIONS)
        self.graph = _graph(self.graph.poses, kept)
        return True

    # ------------------------------------------------------------------ lost and found

    def _lost_at(self, k: int, sigma_xy: float, sigma_theta: float) -> _Lost | None:
        """The search for keyframe k's place after a step across the odometry's silence
        (RELOCATE_*): the map of its floor from before, near enough to be seen from where
        the step may have taken it; None when there is no such map."""
        poses = self.graph.poses
        reach_m = min(RELOCATE_MAX_M, WINDOW_SIGMAS * sigma_xy)
        reach_rad = min(math.pi, WINDOW_SIGMAS * sigma_theta)
        before = k - 1
        seen = np.flatnonzero(
            (self.kf_floor[:k] == self.kf_floor[k])
            & (np.hypot(*(poses[:k, :2] - poses[k, :2]).T) < reach_m + RELOCATE_VIEW_M)
        )
        if len(seen) < 2:
            return None
        world = np.concatenate(
            [se2.transform_points(poses[m], self.clouds.surfaces[m]) for m in seen]
        )
        res = self.config.resolution_m
        local = se2.transform_points(se2.inverse(poses[before]), voxel_filter(world, res / 2))
        window = SearchWindow(reach_m, reach_rad, CAR_FAR_ANGLE_STEP_RAD)
        grid = build_grid(
            self.scans, self.kf_scan[seen], poses[seen], resolution=RELOCATE_FREE_CELL_M
        )
        fld = _free_space_costs(LikelihoodField.from_points(local, res, res), poses[before], grid)
        return _Lost(before, k, window, fld)

    def _relocate(self, k: int) -> None:
        """The chain since the silence looked for in the map from before it (RELOCATE_*):
        once two looks agree on one rigid correction, the chain from the silence on is moved
        there (nothing after the silence is tied to the map from before but the silent
        step's odometry, which allows it) and the match enters as a closure.

        What is placed is what the chain saw in its last few metres, in the frame of its
        first keyframe after the silence: the correction is the same for all of the chain,
        so the window stays the silent step's reach however far the robot drives on. One
        scan in a corridor fits a dozen places of a 10 m window; at 600 s in the simulated
        run the robot drove 20 m through ground the map from before had not seen, every
        look there ambiguous, before it came back into a room it had mapped, which fits one.
        """
        lost = self.lost
        assert lost is not None
        travelled = float(self.clouds.distance[k])
        if k != lost.start and travelled - lost.tried_at < RELOCATE_EVERY_M:
            return
        if lost.tried >= RELOCATE_TRIES:
            return
        lost.tried += 1
        lost.tried_at = travelled
        poses = self.graph.poses
        start = lost.start
        points = voxel_filter(
            np.concatenate(
                [
                    se2.transform_points(se2.between(poses[start], poses[m]), self.clouds.points[m])
                    for m in range(start, k + 1)
                    if self.clouds.path_m(m, k) <= RELOCATE_RECENT_M
                ]
            ),
            self.config.resolution_m,
        )
        if len(points) < RELOCATE_MIN_POINTS:
            return
        guess = se2.between(poses[lost.before], poses[start])
        result = match(lost.fld, points, guess, lost.window, wide=True, budget=RELOCATE_BUDGET)
        self.stats["relocate_attempts"] += 1
        if (
            result.score < RELOCATE_MIN_SCORE
            or result.runner_up >= LOOP_MAX_AMBIGUITY * result.score
        ):
            return
        shift = se2.compose(se2.compose(poses[lost.before], result.pose), se2.inverse(poses[start]))
        agrees = any(_same_shift(shift, other) for other in lost.found)
        lost.found.append(shift)
        if not agrees:
            return
        was = poses[start].copy()
        poses[start:] = se2.compose(shift, poses[start:])
        moved = se2.between(was, poses[start])
        self._accept_loop(self._match_edge(lost.before, start, result, kind="loop"), result.score)
        self.stats["relocated"] += 1
        log.info(
            "the chain found its place after the odometry's silence",
            keyframe=start,
            seen_m=round(travelled - float(self.clouds.distance[start]), 1),
            moved_m=round(math.hypot(moved[0], moved[1]), 2),
            turned_deg=round(math.degrees(se2.wrap(moved[2])), 1),
            looks=lost.tried,
        )
        self.lost = None

    # ------------------------------------------------------------------ loops

    def _close_loops(self, k: int) -> None:
        points = self.clouds.points[k]
        if len(points) < CAR_MIN_POINTS or not self.finished:
            return
        index = self.finished_index
        travelled = float(self.clouds.distance[k])
        since_closure = self.clouds.path_m(self.last_closure, k)
        near = index.last_keyframe <= k - LOOP_MIN_SEPARATION
        near &= travelled - index.tried_at >= LOOP_RETRY_M
        for n, nearest_kf, repeat in self._loop_candidates(
            k, self.graph.poses[k], since_closure, near
        ):
            index.tried_at[n] = travelled
            if not repeat:
                self._try_loop(k, self.finished[n], nearest_kf, since_closure)
        self._follow_beyond(k)

    def _loop_candidates(
        self, k: int, here: FloatArray, since_closure: float, near: npt.NDArray[np.bool_]
    ) -> list[tuple[int, int, bool]]:
        """The finished submaps (of those ``near`` allows) a revisit at ``here`` may match,
        nearest first, at most LOOP_TARGETS: (submap, revisited keyframe, repeat). Two small
        submaps sharing the revisited keyframe stand for the same target (the keyframes
        around it): the second is a repeat, one match of the target is enough."""
        index = self.finished_index
        poses = self.graph.poses
        reach = self.config.loop_radius_m + min(
            LOOP_WIDE_M, self.config.drift_m_per_m * since_closure
        )
        # a cheap first cut on each submap's bounding circle of keyframe positions
        anchors = poses[index.anchor]
        c, s = np.cos(anchors[:, 2]), np.sin(anchors[:, 2])
        cx = anchors[:, 0] + c * index.center[:, 0] - s * index.center[:, 1]
        cy = anchors[:, 1] + s * index.center[:, 0] + c * index.center[:, 1]
        near = near & (np.hypot(cx - here[0], cy - here[1]) < index.radius + reach)
        near &= index.floor == self.kf_floor[k]
        candidates: list[tuple[float, int, int]] = []
        for m in np.flatnonzero(near):
            sub = self.finished[m]
            origins = se2.transform_points(anchors[m], sub.origins())
            dist = np.hypot(origins[:, 0] - here[0], origins[:, 1] - here[1])
            nearest = int(np.argmin(dist))
            drift = min(since_closure, self.clouds.path_m(sub.keyframes[nearest], k))
            # every target is searched as wide as the drift (see _try_loop)
            if dist[nearest] < self.config.loop_radius_m + min(
                LOOP_WIDE_M, self.config.drift_m_per_m * drift
            ):
                candidates.append((float(dist[nearest]), int(m), sub.keyframes[nearest]))
        candidates.sort(key=lambda c: c[0])
        chosen: list[tuple[int, int, bool]] = []
        small: set[int] = set()
        for _, n, nearest_kf in candidates[:LOOP_TARGETS]:
            repeat = False
            if len(self.finished[n].keyframes) < LOOP_MIN_KEYFRAMES:
                repeat = nearest_kf in small
                small.add(nearest_kf)
            chosen.append((n, nearest_kf, repeat))
        return chosen

    def _follow_beyond(self, k: int) -> None:
        """A closure beyond the drift model still waiting for a partner: searched for again
        from keyframe k as if it were right.

        A front-end match gone wrong after a turn (degrees, on a sparse log) leaves the
        estimate further off than the loop window, which is sized by the drift model, can
        reach: a keyframe that finds the correction anyway (beyond, proposed) needs another
        that agrees, and the next keyframes, searching around the same wrong estimate,
        cannot see it (`fr079/30` varied seed 1: keyframe 151 scored 0.79 at a 22 degree
        correction, the next windows reached 16-17 degrees, and the run ended 2 m off).
        Searched around where the proposal puts keyframe k (the window sized by the drift
        since the proposal, never wide), the next scan either fits there as a loop does
        (score past loop_min_score, unambiguous, within that drift) and the two must still
        agree, or does not and the proposal lapses as before: the window says where to
        look, the scans decide. Only until a closure is taken at or after the proposal's
        keyframe: the graph has then placed the run anew (following on after that, a
        proposal whose sibling was taken confirmed itself through weak targets).
        """
        # a closure taken since (here or after the proposal) has placed the run anew: the
        # proposal is then either what the graph holds or contradicted, nothing to follow
        self.beyond = [
            e for e in self.beyond if e.j > self.last_closure and k - e.j <= LOOP_GROUP_KEYFRAMES
        ]
        earlier = [
            (edge, score)
            for edge, score in self.pending
            if edge.j < k and any(edge is e for e in self.beyond)
        ]
        if not earlier:
            return
        proposal = max(earlier, key=lambda p: p[1])[0]
        poses = self.graph.poses
        # keyframe k, moved with the keyframe the proposal places
        placed = se2.compose(poses[proposal.i], proposal.z)
        guess = se2.compose(placed, se2.between(poses[proposal.j], poses[k]))
        since = self.clouds.path_m(proposal.j, k)
        near = self.finished_index.last_keyframe <= k - LOOP_MIN_SEPARATION
        for n, nearest_kf, repeat in self._loop_candidates(k, guess, since, near):
            if repeat:
                continue
            self.stats["loop_follows"] += 1
            self._try_loop(k, self.finished[n], nearest_kf, since, guess=guess)
            if not any(proposal is other for other, _ in self.pending):
                self.stats["loop_followed"] += 1
                return

    def _try_loop(
        self,
        k: int,
        sub: Submap,
        nearest_kf: int,
        since_closure: float,
        *,
        capped: bool = False,
        defer: bool = False,
        guess: FloatArray | None = None,
    ) -> None:
        """Match keyframe k against a finished submap it may revisit, and take, propose or
        refuse the closure. ``guess`` is where to search from when not k's estimate (a
        proposal followed, :meth:`_follow_beyond`): what it finds is then only proposed."""
        config = self.config
        poses = self.graph.poses
        following = guess is not None
        drift = min(since_closure, self.clouds.path_m(nearest_kf, k))
        bound_m = LOOP_BASE_M + config.drift_m_per_m * drift
        bound_rad = LOOP_BASE_RAD + math.radians(config.drift_deg_per_m) * drift
        # past LOOP_MAX_M the window is searched by branch and bound, and what it finds must
        # agree with another keyframe's closure: a window of metres holds aliases. Any
        # target: after a long drive without a closure (a big building's loop of hundreds of
        # metres) the front end is metres off, and a window capped at LOOP_MAX_M would hold
        # only the aliases, the best of which scores like a loop; a dense target is then the
        # run around the revisit, and where the correction turns out within LOOP_MAX_M the
        # capped search decides, alone, as before (docs/mapping.md)
        sparse_target = len(sub.keyframes) < LOOP_MIN_KEYFRAMES
        # a followed proposal is looked for where it puts k, not searched for afresh
        wide = bound_m > LOOP_MAX_M and not capped and not following
        stretch = None
        one_sided = False
        if wide and not sparse_target:
            stretch, one_sided = self._stretch_target(nearest_kf, k, min(LOOP_WIDE_M, bound_m))
        linear = min(LOOP_WIDE_M if wide else LOOP_MAX_M, bound_m)
        angular = min(LOOP_MAX_RAD, bound_rad)
        window = _window(
            max(linear, MIN_WINDOW_M),
            max(angular, MIN_WINDOW_RAD),
            _angle_step(self.clouds.typical_range[k], config.resolution_m),
            config.resolution_m,
        )
        if stretch is not None:
            target, fld, coarse = stretch
        else:
            target, fld, coarse = self._loop_target(sub, nearest_kf, k, window.coarse_step_cells)
        anchor = poses[target]
        local_guess = se2.between(anchor, poses[k] if guess is None else guess)
        # the pull towards the estimate costs as much at the wide window's edge as at the
        # capped one's
        prior_m = LOOP_PRIOR_SIGMA_M * max(1.0, linear / LOOP_MAX_M)
        prior = Prior(local_guess, prior_m, LOOP_PRIOR_SIGMA_RAD, PRIOR_WEIGHT)
        self.stats["loop_attempts"] += 1
        if wide:
            self.stats["loop_wide_attempts"] += 1
        result = match(
            fld,
            self.clouds.points[k],
            local_guess,
            window,
            coarse_field=coarse,
            prior=prior,
            wide=wide,
        )
        moved = math.hypot(result.pose[0] - local_guess[0], result.pose[1] - local_guess[1])
        if stretch is not None and moved <= LOOP_MAX_M:
            # the front end has drifted no further than the capped window reaches: that
            # window, against the submap, decides as it did before the wide search existed;
            # against a target the run frames on one side only, it is kept in case no
            # closure framed on both sides follows (see _settle_deferred)
            self._try_loop(k, sub, nearest_kf, since_closure, capped=True, defer=one_sided)
            return
        if one_sided:
            self.stats["loop_unframed"] += 1
            return
        low = LOOP_GROUP_MIN_SCORE if sparse_target else config.loop_min_score
        if following:
            # the window is centred on the proposal: only a scan that fits there as a
            # loop does (a weak one fits anywhere near) says the proposal is right
            low = config.loop_min_score
        if result.score < low:
            return
        turned = abs(float(se2.wrap(result.pose[2] - local_guess[2])))
        # a correction larger than the front end's drift along the way: an alias (a similar
        # room, the next door along), or, where the chain it corrects holds a step the scan
        # could not vouch for, a front-end match that went wrong (degrees, after a turn of
        # 100-170 degrees on a sparse log), which no drift model foresees and only such a
        # closure can put right. Then, scoring as a loop within the capped loop window (2 m)
        # and the front end's widest turn (45 deg) of the estimate, it is proposed: taken
        # only when another keyframe's closure agrees
        beyond = moved > bound_m + config.resolution_m or turned > bound_rad + window.angle_step_rad
        if beyond and (
            following
            or self.last_doubtful <= max(self.last_closure, nearest_kf)
            or result.score < config.loop_min_score
            or moved > LOOP_MAX_M
            or turned > MAX_FRONT_WINDOW_RAD
        ):
            self.stats["loop_implausible"] += 1
            return
        if result.runner_up >= LOOP_MAX_AMBIGUITY * result.score:
            self.stats["loop_ambiguous"] += 1
            return
        edge = self._match_edge(target, k, result, kind="loop")
        if defer:  # a dense target: its score is past loop_min_score here
            self.deferred.append((edge, result.score))
            self.stats["loop_deferred"] += 1
            return
        if result.score < config.loop_min_score or wide or beyond or following:
            if beyond:
                self.stats["loop_beyond_drift"] += 1
                self.beyond.append(edge)
            self._propose(edge, result.score)
            return
        self._accept_loop(edge, result.score)

    def _accept_loop(self, edge: Edge, score: float) -> None:
        # the largest correction a closure made to the graph as it stood: the front end's
        # drift at the first revisit after a long drive, for the bench to print
        poses = self.graph.poses
        fix = se2.between(se2.between(poses[edge.i], poses[edge.j]), edge.z)
        moved_mm = round(1000 * math.hypot(fix[0], fix[1]))
        self.stats["loop_max_correction_mm"] = max(self.stats["loop_max_correction_mm"], moved_mm)
        index = self.graph.add_edge(edge)
        self.unsolved.append(index)
        self.loops.append((edge.i, edge.j))
        self.last_closure = max(self.last_closure, edge.j)
        log.debug("loop closure", frm=edge.i, to=edge.j, score=round(score, 3))

    def _propose(self, edge: Edge, score: float) -> None:
        """A closure under the loop threshold, against a target of few scans: kept until
        another keyframe's closure agrees with it, then both are taken.

        A sparse log's revisit scores 0.3-0.55 against the handful of scans around the
        revisited place (much of what the revisiting scan sees, they never saw), and there
        so do wrong matches (a turned room, the next door along). One wrong match is as
        likely as a right one at such a score; two matches of different scans that imply
        the same correction are not, unless the world repeats. Agreement is judged on the
        cycle the two closures make with the graph's chains between their keyframes and
        between their targets, within what the front end can drift along those chains.
        """
        k = edge.j
        self.pending = [p for p in self.pending if k - p[0].j <= LOOP_GROUP_KEYFRAMES]
        poses = self.graph.poses
        agreeing = []
        for other, other_score in self.pending:
            if other.j == k and not self._one_scan_two_places(other, other_score, edge, score):
                continue
            if self._agree(other, edge, poses):
                agreeing.append((other, other_score))
        if not agreeing:
            self.pending.append((edge, score))
            self.stats["loop_proposed"] += 1
            return
        for other, other_score in agreeing:
            self.pending.remove((other, other_score))
            self._accept_loop(other, other_score)
        self._accept_loop(edge, score)
        self.stats["loop_groups"] += 1
        if all(other.j == k for other, _ in agreeing):
            self.stats["loop_groups_one_scan"] += 1

    def _one_scan_two_places(self, a: Edge, a_score: float, b: Edge, b_score: float) -> bool:
        """Whether two closures of one keyframe may confirm each other: both beyond the
        drift model (searched within the capped window, scoring as loops: the doubt is
        whether the front end can be that far off, not the match), against different
        targets.

        One scan's matches are not independent draws as two scans' are, so a weak closure
        never confirms another of its scan. But a front end turned by a wrong match is
        found this way on the sparse logs: the keyframe that first sees a revisited
        stretch matches two of its submaps, both right, and the next keyframes search
        around the turned estimate and confirm neither (Intel every fourth scan, strong
        odometry, seed 2: keyframe 188 matched submaps 21 and 24 at 0.67 and 0.61, 0.36 and
        0.04 m from the truth; left waiting, two weak closures 2 m off were taken instead,
        ATE 0.709 m). Of 64 beyond-drift proposals in 30 runs of the sparse logs one was
        wrong by more than half a metre (1.0 m, score 0.55); of the 11 pairs one scan made in
        55 runs, none (docs/mapping.md)."""
        beyond = {id(e) for e in self.beyond}
        return (
            a.i != b.i
            and id(a) in beyond
            and id(b) in beyond
            and min(a_score, b_score) >= self.config.loop_min_score
        )

    def _settle_deferred(self) -> None:
        """At the end of a visit, the closures against one-sided targets made since the
        last accepted closure: taken when at least two agree, else dropped.

        A revisit of the run's first metres after a long drive (a run that ends just past
        where it began) can only be matched against a map the run frames on one side: the
        scan, truly a little behind where the run began, sees walls beside it the map never
        saw, and slid a metre or two along the corridor onto the map it scores better than
        where it is (the big loop with varied odometry, seed 0, such closures taken at once:
        one 1.4 m along, then capped closures that followed it, ATE 0.39 -> 0.62 m). Where
        the run goes on, a closure framed on both sides comes and decides instead, as if
        these were never made; where it ends, these are all there is, and they are right
        far more often than not (the big loop driven 6 m past its start: ATE 1.5-5.7 m
        without them, 0.40-0.60 m with them)."""
        deferred = [(e, s) for e, s in self.deferred if e.j > self.last_closure]
        self.deferred = []
        if len(deferred) < 2:
            return
        poses = self.graph.poses
        best = max(deferred, key=lambda d: d[1])[0]
        agreeing = [(e, s) for e, s in deferred if e is best or self._agree(best, e, poses)]
        if len(agreeing) < 2:
            return
        for edge, score in agreeing:
            self._accept_loop(edge, score)
        self.stats["loop_deferred_taken"] += len(agreeing)
        self._solve_if_needed()

    def _agree(self, a: Edge, b: Edge, poses: FloatArray) -> bool:
        """Whether two closures imply the same correction: the motion between their
        keyframes as the closures put them, against the graph's, within the drift the front
        end can have made along the chains joining them (keyframes, and targets)."""
        keyframes_m = self.clouds.path_m(a.j, b.j)
        targets_m = self.clouds.path_m(a.i, b.i)
        if targets_m > keyframes_m + 2 * self.config.submap_m:
            return False  # targets far apart along the run: the chain between says little
        chains = keyframes_m + targets_m
        via = se2.between(se2.compose(poses[a.i], a.z), se2.compose(poses[b.i], b.z))
        graph = se2.between(poses[a.j], poses[b.j])
        miss = se2.between(graph, via)
        linear = LOOP_BASE_M + self.config.drift_m_per_m * chains
        angular = LOOP_BASE_RAD + math.radians(self.config.drift_deg_per_m) * chains
        return bool(math.hypot(miss[0], miss[1]) <= linear and abs(miss[2]) <= angular)

    def _loop_target(
        self, sub: Submap, nearest_kf: int, k: int, coarse_step: int
    ) -> tuple[int, LikelihoodField, LikelihoodField | None]:
        """What a loop closure matches against: the finished submap, or, when it holds fewer
        than LOOP_MIN_KEYFRAMES keyframes (a sparse log's submap of a scan every 2-3 m holds
        two), the keyframes of the run around the revisited one fused into one field in its
        frame: a revisit scores against a place seen from several scans, as on a dense log.
        Returns the anchor keyframe, the field and its coarse copy."""
        if len(sub.keyframes) >= LOOP_MIN_KEYFRAMES:
            self.cache.use(sub)
            coarse = sub.coarse(coarse_step) if coarse_step > 1 else None
            return sub.anchor, sub.field, coarse
        poses = self.graph.poses
        last = min(int(self.finished_index.last_keyframe.max()), k - LOOP_MIN_SEPARATION)
        near = [
            j
            for j in range(nearest_kf - LOOP_MIN_KEYFRAMES // 2, last + 1)
            if j >= 0 and self.kf_floor[j] == self.kf_floor[nearest_kf]
        ][:LOOP_MIN_KEYFRAMES]
        points = np.concatenate(
            [
                se2.transform_points(
                    se2.between(poses[nearest_kf], poses[j]), self.clouds.surfaces[j]
                )
                for j in near
            ]
        )
        res = self.config.resolution_m
        fld = LikelihoodField.from_points(points, res, res)
        return nearest_kf, fld, fld.pooled(coarse_step) if coarse_step > 1 else None

    def _stretch_target(
        self, nearest_kf: int, k: int, reach_m: float
    ) -> tuple[tuple[int, LikelihoodField, None], bool]:
        """What a wide closure matches against: the keyframes of the run within ``reach_m``
        of path either side of the revisited one, fused in its frame; and whether the run
        reaches that far on one side only (the start of the run, where a visit began or
        ends, what is not finished yet).

        A window of metres must hold the scan's true surroundings: against one submap a
        scan that is truly a few metres outside it (the robot coming back to where the run
        began, from behind) scores poorly where it is and well slid metres along the
        corridor onto the map, and consecutive keyframes slide alike, so they agree.
        Revisits are taken where the map reaches past the window on both sides; where it
        does not, a correction within LOOP_MAX_M is kept, to be taken only if the visit
        brings nothing better (_settle_deferred)."""
        last = min(int(self.finished_index.last_keyframe.max()), k - LOOP_MIN_SEPARATION)
        visit = self.kf_visit[nearest_kf]
        path = self.clouds.path_m
        lo = hi = nearest_kf
        while lo > 0 and self.kf_visit[lo - 1] == visit and path(lo, nearest_kf) < reach_m:
            lo -= 1
        while hi < last and self.kf_visit[hi + 1] == visit and path(nearest_kf, hi) < reach_m:
            hi += 1
        one_sided = path(lo, nearest_kf) < reach_m or path(nearest_kf, hi) < reach_m
        poses = self.graph.poses
        points = np.concatenate(
            [
                se2.transform_points(
                    se2.between(poses[nearest_kf], poses[j]), self.clouds.surfaces[j]
                )
                for j in range(lo, hi + 1)
            ]
        )
        res = self.config.resolution_m
        return (nearest_kf, LikelihoodField.from_points(points, res, res), None), one_sided

    def _solve_if_needed(self) -> None:
        if not self.unsolved:
            return
        _, chi2 = self.graph.edge_errors(edges=np.array(self.unsolved))
        if chi2.max() > SOLVE_ABOVE_CHI2 or len(self.unsolved) >= SOLVE_AFTER_LOOPS:
            self.graph.optimize(iterations=SOLVE_ITERATIONS)
            self.stats["solves"] += 1
            self.unsolved.clear()
            self._rebuild_active()

    def _rebuild_active(self) -> None:
        """The solve moved the keyframes of the submaps being built: build them again from
        the corrected poses, so the front end matches against the map as it now stands."""
        poses = self.graph.poses
        for sub in self.active:
            sub.relocate([se2.between(poses[sub.anchor], poses[k]) for k in sub.keyframes])


def run_slam(
    scans: ScanBlock,
    odom: FloatArray,
    floor: IntArray,
    visit: IntArray,
    *,
    config: SlamConfig | None = None,
    progress: Callable[[int], None] | None = None,
    travel: FloatArray | None = None,
    blind: BoolArray | None = None,
) -> SlamResult:
    """SLAM over a run: scans, odometry poses at the scan times, floor and visit per scan.

    ``travel``: the odometry's path and turning up to each scan, as the odometry came
    (:meth:`~baromap.mapping.run_data.RunData.travel`), where it came more often than the
    scans; it tells a silence of the laser by the drive inside it, not only by where the
    drive ended (None: the scans' own odometry is all there is).

    ``blind``: the scans the odometry said nothing about
    (:attr:`~baromap.mapping.run_data.RunData.blind`: the base unplugged while the
    laser went on). They are not mapped: without odometry a corridor lets the scans slide
    (the sim's blind minute, matched scan by scan with a constant-velocity guess, drifted
    metres while the robot sped up along one), and the step across them is taken as a laser
    silence is, begun again in new submaps and tied back by loop closure and the car. Their
    poses are drawn across the gap, for the record only."""
    config = config or SlamConfig()
    if blind is not None and blind.any():
        floor = np.where(blind, BETWEEN_FLOORS, floor)
    kf_scan = select_keyframes(odom, visit, floor, config)
    if len(kf_scan) == 0:
        raise MappingError("no scan is on a floor: nothing to map")
    slam = _Slam(
        scans,
        odom,
        kf_scan,
        kf_floor=floor[kf_scan],
        kf_visit=visit[kf_scan],
        config=config,
        travel=travel,
        blind=blind,
    )
    for k in range(len(kf_scan)):
        slam.add(k)
        if progress is not None:
            progress(int(kf_scan[k]))
    result = slam.finish()
    result.scan_poses = slam.register_scans(scans, floor)
    log.info("slam done", **{k: int(v) for k, v in result.stats.items()})
    return result


def scan_poses(
    odom: FloatArray,
    kf_scan: IntArray,
    kf_poses: FloatArray,
    *,
    silence: Int8Array | None = None,
) -> FloatArray:
    """Every scan's pose from the keyframes around it.

    Between two keyframes a and b, odometry from a is followed, and the correction the graph
    made to the stretch (where b is, against where odometry from a puts it) is spread along
    it in proportion to the motion so far, so the stretch ends exactly on b. Scans before the
    first keyframe or after the last follow odometry from it.

    ``silence`` (per scan): the scans between the keyframes of a step across a silence (the
    laser or the odometry silent on the way) follow odometry uncorrected, from the keyframe
    before it (-1: taken before the silence) or back from the one after it (+1). The graph's
    correction of such a step is metres and tens of degrees (a power-cycled base turned on
    the spot meanwhile), not a drift to spread along it.
    """
    s = np.arange(len(odom))
    if len(kf_scan) == 1:
        out: FloatArray = se2.compose(kf_poses[0], se2.between(odom[kf_scan[0]], odom))
        return out
    seg = np.clip(np.searchsorted(kf_scan, s, side="right") - 1, 0, len(kf_scan) - 2)
    a, b = kf_scan[seg], kf_scan[seg + 1]
    start = np.where(s < kf_scan[0], 0, seg)
    start = np.where(s > kf_scan[-1], len(kf_scan) - 1, start)
    rel = se2.between(odom[kf_scan[start]], odom)  # odometry since the keyframe before
    followed = se2.compose(kf_poses[start], rel)
    predicted_b = se2.compose(kf_poses[seg], se2.between(odom[a], odom[b]))
    miss = kf_poses[seg + 1] - predicted_b
    miss[:, 2] = se2.wrap(miss[:, 2])
    # how far along the stretch each scan is: by distance, or by turn where it turned in place
    step = se2.between(odom[a], odom[b])
    total = np.hypot(step[:, 0], step[:, 1]) + TURN_AS_M * np.abs(step[:, 2])
    done = np.hypot(rel[:, 0], rel[:, 1]) + TURN_AS_M * np.abs(rel[:, 2])
    frac = np.clip(done / np.maximum(total, 1e-9), 0.0, 1.0)
    frac[(s < kf_scan[0]) | (s > kf_scan[-1])] = 0.0
    poses: FloatArray = followed + frac[:, None] * miss
    poses[:, 2] = se2.wrap(poses[:, 2])
    if silence is not None:
        inside = (s > a) & (s < b)
        back = inside & (silence > 0)
        poses[back] = se2.compose(kf_poses[seg + 1][back], se2.between(odom[b[back]], odom[back]))
        before = inside & (silence < 0)
        poses[before] = followed[before]  # odometry from a, without the spread correction
    return poses
