"""The SLAM's settings: what a caller may choose (:class:`SlamConfig`) and the tuned
constants, each with the reasoning and the measurements that chose it."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from baromap.errors import ConfigError

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
    #: degree beams) and often graze a wall, but across a hall they are what pins the heading,
    #: while the local accuracy hardly changes (docs/decisions.md, "Beams to 30 m"). A laser
    #: in its 8 m mode (the simulated robot's) never reaches it
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
    #: sees much its submap never saw, so a correct match there scores 0.2-0.3, and wrong
    #: matches of sparse scans score over 0.55 as often. Refusing those drives the front end
    #: on odometry and the map falls apart (metres); the ambiguity test and odometry's window
    #: are what keep wrong matches out (docs/decisions.md, "The front end takes weak
    #: matches"). A loop closure, judged against a map it may only partly share, keeps a high
    #: bar: a lower one lets wrong closures bend the map.
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
#: Two keyframes' scans this many of the log's usual intervals (per scan between them) apart
#: were parted by a silence, not by a sparse log's long step.
LONG_WAIT_INTERVALS = 3.0
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
#: last FRONT_RETRY_M of travel (:meth:`FrontEnd._retry_after_turn`). Dense logs, a keyframe
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
#: ridge, not two peaks (see :meth:`FrontEnd._ridge`).
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
#: A loop target holds at least this many keyframes (see :meth:`LoopCloser._loop_target`).
LOOP_MIN_KEYFRAMES = 5
#: A closure against a target of few scans (see :meth:`LoopCloser._loop_target`) scoring under the
#: loop threshold but at least this is taken once another keyframe's closure, from at most
#: this many keyframes before it, implies the same correction (:meth:`LoopCloser._propose`).
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
#: what lies this near the car is matched across floors (:meth:`ElevatorCar.core_edges`).
CORE_RADIUS_M = 4.0
CORE_REACH_M = 6.0
#: How far the car at a ride can be from where the rides' chain of car matches puts it.
CAR_WINDOW_M = 0.3
CAR_WINDOW_RAD = math.radians(5.0)
#: A ride none of whose car keyframes is found within CAR_WINDOW is looked for this far out
#: (:meth:`ElevatorCar._car_beyond`): a minute's drive without the laser at half a metre a second
#: leaves odometry metres and tens of degrees off (6 m and 19 degrees in the simulated run),
#: and a turn of 45 degrees stays clear of the box's own symmetries (a half turn, a quarter
#: turn of a square car).
CAR_FAR_WINDOW_M = 10.0
CAR_FAR_WINDOW_RAD = math.radians(45.0)
#: ... in the car's field at the map's resolution, by branch and bound with this many node
#: splits, its lattice turned a degree at a time (the car's walls are within 2.5 m, where a
#: degree moves a point half a cell; the refinement takes it from there), for at most this
#: many keyframes of each such ride. The pooled field of a 2 m box bounds thousands of nodes
#: near 1.0: with the loops' 300 splits, or a quarter-degree lattice, the budget runs out
#: and the search returns aliases; with these it settles in 0.5-1.4 s a keyframe.
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
#: place: the robot may turn 120 degrees on the spot in 5 s, or drive 18 m and turn 161
#: degrees in a minute (the simulated run's gaps), and the chain after the gap stands where
#: "no motion" puts it. So what
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
#: Scans between keyframes are matched against the finished map with up to this many beams,
#: every beam of any laser there is: a subsample of them costs local accuracy and saves no
#: measurable time.
#: REGISTER_CHUNK scans are fitted at a time (each on its own: the same poses, bounded memory).
REGISTER_BEAMS = 720
REGISTER_CHUNK = 2000
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
#: errors into odometry's (it cannot tell them apart), and the map fits carry covariances
#: several times their real error (MATCH_COV_SCALE and the floors above); at the fit itself in
#: the refinement too, odometry outweighs good fits and the local accuracy suffers. Weighing
#: the refinement's edges by their own scatter instead does not replace the factor: odometry
#: shows under half the variance it claims and the fits a quarter, yet the local accuracy
#: wants odometry weaker still (whether because odometry's errors are not independent step
#: to step or because the fits' residuals shrink where they decide their keyframes is not
#: measured; docs/decisions.md, "Odometry weighed by its measured noise, every edge kind by
#: its scatter").
REFINE_ODOMETRY_INFLATION = 3.0
#: ... and there odometry's edges are robust (the loop closures' Cauchy kernel): a step misread
#: by far more than the fitted noise yields to the map fits at both its ends (the Infinite
#: Corridor 0.431 -> 0.362 m mean ATE, Intel relations 0.0207 -> 0.0198 m, every other case of
#: the mapping gate within its seeds' spread).
REFINE_ODOMETRY_ROBUST = True
#: Matching against a finished map (the refinement, the elevator core, the scans between
#: keyframes) uses a field this fraction of the front end's cell and sigma. The front end's
#: field is as wide as its search needs: a correlative search over a window of decimetres
#: wants a basin a few cells wide, and a 5 cm sigma is five times a laser's range noise. Once
#: the graph has put every keyframe within a cell of where it belongs, only Gauss-Newton from
#: there is left, and a field that wide blurs the walls it aligns to. At half (2.5 cm, still
#: above a SICK's 1-2 cm noise and the map's own spread) the maps are sharper and the local
#: accuracy better beyond the spread of seeds, at the same time and memory
#: (docs/decisions.md, "The last alignment against a finer field").
FINISHED_MAP_FIELD_SCALE = 0.5
#: In the graph solve before the refinement every kind of edge with at least this many edges
#: is weighed by its own scatter against the solved graph (:meth:`FinalSolve._weigh_by_scatter`).
SCATTER_KINDS = ("odometry", "match", "ride", "loop", "car")
MIN_SCATTER_EDGES = 30
