"""Floor-aware graph SLAM over a whole run.

Keyframes: every ``keyframe_m`` metres or ``keyframe_rad`` of odometric motion, plus the first
and last scan of every floor visit (the robot in the elevator car, before and after a ride).

Front end: each keyframe is matched against a local submap of the previous keyframes of the
same visit, with odometry as a soft prior (so a featureless corridor cannot make it slide).
Both the odometry and the match enter the pose graph, the match with the information of its
own fit (weak along a corridor, strong across it).

Loop closures: each keyframe looks for keyframes of the *same floor* (the barometer's
verdict) that are near in the current estimate but outside its submap, and matches against
the submap around the nearest with a wide multi-resolution search; ambiguous matches and
corrections larger than the drift the front end can have accumulated are refused, and
accepted closures carry a Cauchy kernel. Different floors never close against each other:
stacked floors can look identical, and only the barometer tells them apart.

Floors: the ride joins two floors through odometry, refined by matching the closed car before
and after the ride (the car travels with the robot, so this is not a closure between floors);
a visit that starts and ends in the car is closed car-to-car. Together they keep all floors
in one frame, aligned at the lobby.

Scans that are not keyframes get the pose of the nearest keyframe composed with the odometry
motion between them: within a keyframe spacing odometry is good to a centimetre or two.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import structlog

from baromap.mapping import se2
from baromap.mapping.pose_graph import Edge, PoseGraph
from baromap.mapping.scan_matcher import (
    LikelihoodField,
    MatchResult,
    Prior,
    SearchWindow,
    match,
)
from baromap.mapping.scans import ScanBlock, voxel_filter

log = structlog.get_logger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

#: Floor label of scans taken while the barometer says the robot is between floors.
BETWEEN_FLOORS = -1


@dataclass(frozen=True, slots=True)
class SlamConfig:
    keyframe_m: float = 0.3
    keyframe_rad: float = math.radians(15.0)
    max_range_m: float = 20.0
    voxel_m: float = 0.05
    resolution_m: float = 0.05
    sigma_m: float = 0.05
    submap_keyframes: int = 20
    front_window: SearchWindow = field(
        default_factory=lambda: SearchWindow(
            linear_m=0.3, angular_rad=math.radians(6.0), angle_step_rad=math.radians(0.5)
        )
    )
    front_min_score: float = 0.3
    #: a match's Gauss-Newton covariance is inflated by this factor (scan points are not
    #: independent) and floored by these sigmas before it becomes an edge
    match_cov_scale: float = 4.0
    match_sigma_xy: float = 0.01
    match_sigma_theta: float = math.radians(0.2)
    odom_sigma_xy_per_m: float = 0.1
    odom_sigma_theta_per_m: float = math.radians(5.0)
    #: wheel odometry of a skid-steer base misjudges turns in place by several percent,
    #: systematically, so its rotation counts for little against a scan match
    odom_sigma_theta_per_rad: float = 0.1
    loop_every: int = 1
    loop_radius_m: float = 3.0
    loop_min_separation: int = 30
    loop_submap_half: int = 10
    loop_window: SearchWindow = field(
        default_factory=lambda: SearchWindow(
            linear_m=1.5,
            angular_rad=math.radians(20.0),
            angle_step_rad=math.radians(1.0),
            coarse_step_cells=4,
        )
    )
    loop_min_score: float = 0.55
    #: a weak pull of closures towards the current estimate: among equally good corridor
    #: alignments the one nearest the estimate wins
    loop_prior_sigma_m: float = 0.5
    loop_prior_sigma_rad: float = math.radians(5.0)
    #: a closure is ambiguous (a corridor with evenly spaced doors) when a pose at least
    #: 0.3 m away scores within this ratio of the best
    loop_max_ambiguity: float = 0.95
    #: largest plausible correction by a closure: this much plus this much per metre driven
    #: between the two keyframes (the front end's drift)
    loop_max_move_m: float = 0.1
    loop_max_move_per_m: float = 0.03
    #: weight of the odometry prior in front-end matching (see scan_matcher.Prior)
    prior_weight: float = 0.01
    loop_sigma_xy: float = 0.02
    loop_sigma_theta: float = math.radians(0.5)
    #: scans whose 90th-percentile range is shorter than this (the robot inside an elevator
    #: car) are too small and symmetric for a wide search: the box matches itself turned or
    #: shifted; they close loops with the narrow front-end window around the estimate instead
    loop_min_extent_m: float = 2.5
    #: least score of the car-to-car match across an elevator ride for it to join the floors
    #: (otherwise odometry alone does)
    ride_min_score: float = 0.6
    loop_robust_c: float = 3.0
    optimize_every: int = 10


@dataclass(slots=True)
class SlamResult:
    keyframes: IntArray  # scan index of each keyframe
    keyframe_poses: FloatArray  # (K, 3)
    scan_poses: FloatArray  # (S, 3), every scan
    graph: PoseGraph
    loop_edges: list[tuple[int, int]] = field(default_factory=list)  # keyframe ids
    stats: dict[str, float] = field(default_factory=dict)


def select_keyframes(
    odom: FloatArray, visit: IntArray, floor: IntArray, config: SlamConfig
) -> IntArray:
    """Scans where the robot has moved enough since the last keyframe of the same visit.

    The first and the last scan of every visit are keyframes too: they are the robot in the
    elevator car just before and just after a ride, the two scans that join the floors.
    """
    chosen: list[int] = []
    last = -1
    for s in range(len(odom)):
        if floor[s] == BETWEEN_FLOORS:
            continue
        if last < 0 or visit[s] != visit[last]:
            if s > 0 and last >= 0 and last != s - 1 and floor[s - 1] != BETWEEN_FLOORS:
                chosen.append(s - 1)
            elif last >= 0:
                prev = s - 1
                while prev > last and floor[prev] == BETWEEN_FLOORS:
                    prev -= 1
                if prev > last:
                    chosen.append(prev)
            chosen.append(s)
            last = s
            continue
        d = se2.between(odom[last], odom[s])
        if math.hypot(d[0], d[1]) >= config.keyframe_m or abs(d[2]) >= config.keyframe_rad:
            chosen.append(s)
            last = s
    return np.array(chosen, dtype=np.int64)


class _Keyframes:
    """Per-keyframe point clouds, filtered once."""

    def __init__(
        self, scans: ScanBlock, odom: FloatArray, indices: IntArray, config: SlamConfig
    ) -> None:
        self.points = [
            voxel_filter(scans.endpoints(int(s), config.max_range_m), config.voxel_m)
            for s in indices
        ]
        steps = np.hypot(*np.diff(odom[indices, :2], axis=0).T) if len(indices) > 1 else []
        self.distance = np.concatenate([[0.0], np.cumsum(steps)])
        self.extent = np.array(
            [
                float(np.percentile(np.hypot(p[:, 0], p[:, 1]), 90)) if len(p) else 0.0
                for p in self.points
            ]
        )

    def path_m(self, a: int, b: int) -> float:
        """Odometric path length between keyframes a and b."""
        return float(abs(self.distance[b] - self.distance[a]))

    def world_points(self, ids: list[int] | IntArray, poses: FloatArray) -> FloatArray:
        clouds = [se2.transform_points(poses[k], self.points[k]) for k in ids]
        return np.concatenate(clouds) if clouds else np.zeros((0, 2))


def _field_around(
    points: FloatArray, center: FloatArray, config: SlamConfig, margin: float, fine: bool = False
) -> LikelihoodField:
    """Likelihood field of submap points around where the scan can land.

    ``fine`` halves cell and kernel for a small enclosed scan (the elevator car): its walls
    are a metre away, where a degree of rotation moves points less than a 5 cm cell.
    """
    reach = config.max_range_m + margin
    bounds = (center[0] - reach, center[1] - reach, center[0] + reach, center[1] + reach)
    if len(points):
        lo = np.maximum(points.min(axis=0), [bounds[0], bounds[1]])
        hi = np.minimum(points.max(axis=0), [bounds[2], bounds[3]])
        bounds = (lo[0], lo[1], max(hi[0], lo[0]), max(hi[1], lo[1]))
    scale = 0.5 if fine else 1.0
    return LikelihoodField.from_points(
        points, config.resolution_m * scale, config.sigma_m * scale, bounds
    )


def _info(sigma_xy: float, sigma_theta: float) -> FloatArray:
    return np.diag([1 / sigma_xy**2, 1 / sigma_xy**2, 1 / sigma_theta**2])


def _match_info(
    information: FloatArray, scale: float, sigma_xy: float, sigma_theta: float
) -> FloatArray:
    """Edge information from a match: inflated GN covariance plus a floor, inverted (world
    frame; :func:`_rotate_info` takes it into the frame the edge's error is expressed in)."""
    try:
        cov = np.linalg.inv(information) * scale
    except np.linalg.LinAlgError:
        cov = np.diag([1.0, 1.0, 1.0])
    cov = cov + np.diag([sigma_xy**2, sigma_xy**2, sigma_theta**2])
    out: FloatArray = np.linalg.inv(cov)
    return out


def _rotate_info(info: FloatArray, theta: float) -> FloatArray:
    """World-frame information in the frame of the matched pose (heading ``theta``), where the
    pose graph expresses an edge's translational error."""
    c, s = math.cos(theta), math.sin(theta)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out: FloatArray = rot.T @ info @ rot
    return out


def run_slam(
    scans: ScanBlock,
    odom: FloatArray,
    floor: IntArray,
    visit: IntArray,
    *,
    config: SlamConfig | None = None,
    progress: Callable[[int], None] | None = None,
) -> SlamResult:
    """SLAM over a run: scans, odometry poses at the scan times, floor and visit per scan."""
    config = config or SlamConfig()
    kf_scan = select_keyframes(odom, visit, floor, config)
    if len(kf_scan) == 0:
        raise ValueError("no scan is on a floor: nothing to map")
    clouds = _Keyframes(scans, odom, kf_scan, config)
    kf_floor = floor[kf_scan]
    kf_visit = visit[kf_scan]
    graph = PoseGraph()
    graph.add_node(odom[kf_scan[0]])
    loops: list[tuple[int, int]] = []
    stats: dict[str, float] = {
        "front_matches": 0,
        "front_failures": 0,
        "loop_attempts": 0,
        "loops": 0,
    }
    visit_start = 0
    pending_loops = 0
    for k in range(1, len(kf_scan)):
        if kf_visit[k] != kf_visit[k - 1]:
            if _close_visit(visit_start, k - 1, graph, clouds, config):
                loops.append((visit_start, k - 1))
                graph.optimize(iterations=10)
                pending_loops = 0
            visit_start = k
        step = se2.between(odom[kf_scan[k - 1]], odom[kf_scan[k]])
        guess = se2.compose(graph.poses[k - 1], step)
        graph.add_node(guess)
        dist = math.hypot(step[0], step[1])
        sigma_xy = 0.02 + config.odom_sigma_xy_per_m * dist
        sigma_theta = (
            math.radians(0.5)
            + config.odom_sigma_theta_per_m * dist
            + config.odom_sigma_theta_per_rad * abs(step[2])
        )
        # odometry always enters the graph: along a featureless corridor it is the only
        # measurement of the motion, and the match edge's information says so
        graph.add_edge(Edge(k - 1, k, step, _info(sigma_xy, sigma_theta), "odometry"))
        if k == visit_start and _in_car(k - 1, k, clouds, config):
            # the ride: both scans see the closed car, which travels with the robot, so
            # matching them measures the little the robot turned while the floors changed
            fld = _field_around(
                clouds.world_points([k - 1], graph.poses), guess, config, 1.5, fine=True
            )
            prior = Prior(guess, sigma_xy, sigma_theta, config.prior_weight)
            result = match(fld, clouds.points[k], guess, config.front_window, prior=prior)
            if result.score >= config.ride_min_score:
                graph.poses[k] = result.pose
                graph.add_edge(_match_edge(graph, k - 1, k, result, config=config, kind="ride"))
                stats["ride_matches"] = stats.get("ride_matches", 0) + 1
        elif k > visit_start and len(clouds.points[k]) >= 10:
            ids = list(range(max(visit_start, k - config.submap_keyframes), k))
            ref = clouds.world_points(ids, graph.poses)
            fld = _field_around(
                ref,
                guess,
                config,
                config.front_window.linear_m + 1.0,
                fine=bool(clouds.extent[k] < config.loop_min_extent_m),
            )
            prior = Prior(guess, sigma_xy, sigma_theta, config.prior_weight)
            result = match(fld, clouds.points[k], guess, config.front_window, prior=prior)
            if result.score >= config.front_min_score:
                graph.poses[k] = result.pose
                graph.add_edge(_match_edge(graph, k - 1, k, result, config=config, kind="match"))
                stats["front_matches"] += 1
            else:
                stats["front_failures"] += 1
        if k % config.loop_every == 0:
            target = _try_loop(
                k,
                graph=graph,
                clouds=clouds,
                kf_floor=kf_floor,
                kf_visit=kf_visit,
                config=config,
                stats=stats,
            )
            if target is not None:
                loops.append((target, k))
                pending_loops += 1
        if pending_loops and (pending_loops >= 3 or k % config.optimize_every == 0):
            graph.optimize(iterations=10)
            pending_loops = 0
        if progress is not None:
            progress(int(kf_scan[k]))
    if _close_visit(visit_start, len(kf_scan) - 1, graph, clouds, config):
        loops.append((visit_start, len(kf_scan) - 1))
    graph.optimize(iterations=30)
    stats["keyframes"] = len(kf_scan)
    stats["loops"] = len(loops)
    scan_poses = _all_scan_poses(odom, kf_scan, graph.poses, floor)
    return SlamResult(kf_scan, graph.poses.copy(), scan_poses, graph, loops, stats)


def _match_edge(
    graph: PoseGraph, i: int, j: int, result: MatchResult, *, config: SlamConfig, kind: str
) -> Edge:
    """Edge i -> j from a match of keyframe j (against a map in the frame of the graph).

    Sequential and ride edges are trusted (plain least squares); loop closures get the
    robust kernel, their floor sigmas, and can be outvoted.
    """
    loop = kind == "loop"
    info = _match_info(
        result.information,
        config.match_cov_scale,
        config.loop_sigma_xy if loop else config.match_sigma_xy,
        config.loop_sigma_theta if loop else config.match_sigma_theta,
    )
    return Edge(
        i,
        j,
        se2.between(graph.poses[i], result.pose),
        _rotate_info(info, result.pose[2]),
        kind,
        robust_c=config.loop_robust_c if loop else None,
    )


def _in_car(a: int, b: int, clouds: _Keyframes, config: SlamConfig) -> bool:
    """Both keyframes are small enclosed scans (the robot inside a closed elevator car)."""
    return bool(
        len(clouds.points[a]) >= 30
        and len(clouds.points[b]) >= 30
        and clouds.extent[a] < config.loop_min_extent_m
        and clouds.extent[b] < config.loop_min_extent_m
    )


def _close_visit(
    first: int, last: int, graph: PoseGraph, clouds: _Keyframes, config: SlamConfig
) -> bool:
    """Close a floor visit that began and ends in the closed elevator car.

    The robot leaves the car, explores, and comes back into the same car: the two car scans
    are nearly the same scan, so matching them pins the visit's heading to within a tenth
    of a degree, where the turns inside the car (which wheel odometry misjudges most) would
    otherwise hand a degree or so of heading error to every floor that follows.
    """
    if last - first < config.loop_min_separation or not _in_car(first, last, clouds, config):
        return False
    poses = graph.poses
    fld = _field_around(clouds.world_points([first], poses), poses[last], config, 1.5, fine=True)
    prior = Prior(
        poses[last], config.loop_prior_sigma_m, config.loop_prior_sigma_rad, config.prior_weight
    )
    result = match(fld, clouds.points[last], poses[last], config.front_window, prior=prior)
    if result.score < config.ride_min_score:
        return False
    graph.add_edge(_match_edge(graph, first, last, result, config=config, kind="loop"))
    return True


def _try_loop(
    k: int,
    *,
    graph: PoseGraph,
    clouds: _Keyframes,
    kf_floor: IntArray,
    kf_visit: IntArray,
    config: SlamConfig,
    stats: dict[str, float],
) -> int | None:
    """Match keyframe k against the nearest old keyframe of its floor; add the edge if good."""
    poses = graph.poses
    old = np.arange(0, k - config.loop_min_separation)
    if len(old) == 0:
        return None
    old = old[(kf_floor[old] == kf_floor[k])]
    if len(old) == 0:
        return None
    dist = np.hypot(poses[old, 0] - poses[k, 0], poses[old, 1] - poses[k, 1])
    near = dist < config.loop_radius_m
    if not near.any():
        return None
    target = int(old[near][np.argmin(dist[near])])
    lo = target
    while lo > 0 and target - lo < config.loop_submap_half and kf_visit[lo - 1] == kf_visit[target]:
        lo -= 1
    hi = target
    while (
        hi < k - config.loop_min_separation
        and hi - target < config.loop_submap_half
        and kf_visit[hi + 1] == kf_visit[target]
    ):
        hi += 1
    ref = clouds.world_points(list(range(lo, hi + 1)), poses)
    if len(ref) < 50 or len(clouds.points[k]) < 30:
        return None
    stats["loop_attempts"] += 1
    if clouds.extent[k] < config.loop_min_extent_m:
        window = config.front_window
        fld = _field_around(ref, poses[k], config, window.linear_m + 1.0, fine=True)
        result = match(fld, clouds.points[k], poses[k], window)
    else:
        window = config.loop_window
        fld = _field_around(ref, poses[k], config, window.linear_m + 1.0)
        coarse = fld.max_filtered(window.coarse_step_cells)
        prior = Prior(
            poses[k], config.loop_prior_sigma_m, config.loop_prior_sigma_rad, config.prior_weight
        )
        result = match(fld, clouds.points[k], poses[k], window, coarse_field=coarse, prior=prior)
    if result.score < config.loop_min_score:
        return None
    moved = math.hypot(result.pose[0] - poses[k, 0], result.pose[1] - poses[k, 1])
    if moved > config.loop_max_move_m + config.loop_max_move_per_m * clouds.path_m(target, k):
        # a correction larger than the front end can have drifted since the target is an
        # alias (a similar room, the next door along), not a loop
        stats["loop_implausible"] = stats.get("loop_implausible", 0) + 1
        return None
    if result.runner_up >= config.loop_max_ambiguity * result.score:
        stats["loop_ambiguous"] = stats.get("loop_ambiguous", 0) + 1
        return None
    graph.add_edge(_match_edge(graph, target, k, result, config=config, kind="loop"))
    log.debug("loop closure", frm=target, to=k, score=round(result.score, 3))

    return target


def _all_scan_poses(
    odom: FloatArray, kf_scan: IntArray, kf_poses: FloatArray, floor: IntArray
) -> FloatArray:
    """Every scan's pose: the nearest keyframe's pose plus odometry from it."""
    s = np.arange(len(odom))
    pos = np.clip(np.searchsorted(kf_scan, s), 1, len(kf_scan) - 1) if len(kf_scan) > 1 else None
    if pos is None:
        nearest = np.zeros(len(odom), dtype=np.int64)
    else:
        left, right = kf_scan[pos - 1], kf_scan[pos]
        nearest = np.where(np.abs(s - left) <= np.abs(right - s), pos - 1, pos)
    anchor = kf_scan[nearest]
    rel = se2.between(odom[anchor], odom)
    poses: FloatArray = se2.compose(kf_poses[nearest], rel)
    return poses
