"""What one SLAM run keeps while it is fed keyframes, in the parts the front end, loop
closure, the car, the search after a silence and the last solve are handed: the keyframes
(:class:`Keyframes`, fixed before the run), the submaps (:class:`Submaps`), the pose graph
with its closures (:class:`Chain`) and what the run learns about odometry
(:class:`OdometryLearning`). Each part keeps its own state (the front end its doubt, loop
closure the closures that wait, the car its closures, the search after a silence the lost
chain); the pose graph in :class:`Chain` is where they all put their edges and poses."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import structlog

from baromap.arrays import BoolArray, FloatArray, IntArray
from baromap.mapping import se2
from baromap.mapping.odometry_calibration import OdometryCalibration, OdometryNoise, fit_noise
from baromap.mapping.pose_graph import Edge, PoseGraph
from baromap.mapping.scan_matcher import LikelihoodField, SearchWindow
from baromap.mapping.scans import ScanBlock, voxel_filter
from baromap.mapping.slam.measurement import edge_covariance, rotate_information
from baromap.mapping.slam.settings import (
    CAR_EXTENT_M,
    CAR_MIN_POINTS,
    LONG_WAIT_INTERVALS,
    MIN_NOISE_STEPS,
    ODOMETRY_SIGMA_M,
    ODOMETRY_SIGMA_RAD,
    SOLVE_ABOVE_CHI2,
    SOLVE_AFTER_LOOPS,
    SOLVE_ITERATIONS,
    SUBMAP_MAX_KEYFRAMES,
    SUBMAP_MEMORY_BYTES,
    SlamConfig,
)
from baromap.mapping.submaps import Submap, SubmapCache

log = structlog.get_logger(__name__)


class KeyframeClouds:
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


def graph_of(poses: FloatArray, edges: list[Edge]) -> PoseGraph:
    graph = PoseGraph()
    for pose in poses:
        graph.add_node(pose)
    for edge in edges:
        graph.add_edge(edge)
    return graph


@dataclass(slots=True)
class Lost:
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


class SubmapIndex:
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


class Keyframes:
    """The run as the SLAM sees it before it places anything: the keyframes' scans, floors,
    visits and clouds, the odometry at each, and which steps between keyframes the odometry
    did not measure. Nothing in it changes while the run is fed."""

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
        breaks: BoolArray | None = None,
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
        if breaks is not None and breaks.any() and len(kf_scan) > 1:
            # a break in the odometry (it counted from zero again, joined at the pose before)
            # between a keyframe's scan and the next's: that step is not measured at all
            counted = np.concatenate([[0], np.cumsum(breaks)])
            ends = np.asarray(kf_scan)
            broken = np.zeros(len(kf_scan), dtype=bool)
            broken[1:] = counted[ends[1:] + 1] - counted[ends[:-1] + 1] > 0
            self.blind_step |= broken
            self.unmeasured_step |= broken
        self.t_ns = scans.t_ns
        steps = np.diff(scans.t_ns)
        #: the log's usual time from one scan to the next
        self.interval_ns = float(np.median(steps[steps > 0])) if (steps > 0).any() else 0.0
        self.scans = scans
        self.blind = np.zeros(len(odom), dtype=bool) if blind is None else blind
        self.kf_scan = kf_scan
        self.kf_floor = kf_floor
        self.kf_visit = kf_visit
        self.clouds = KeyframeClouds(scans, odom, kf_scan, config)

    def long_wait(self, k: int) -> bool:
        """Whether the scans of keyframes k-1 and k lie further apart in time than the scans
        between them take at the log's usual interval, LONG_WAIT_INTERVALS times over: the
        laser was silent, or nothing was logged (a log that keeps a scan a metre is sparse,
        not silent)."""
        a, b = int(self.kf_scan[k - 1]), int(self.kf_scan[k])
        return bool(self.t_ns[b] - self.t_ns[a] > LONG_WAIT_INTERVALS * (b - a) * self.interval_ns)

    def odometry_step(self, a: int, b: int) -> FloatArray:
        """Odometry's motion from keyframe a to keyframe b, as the wheels read it."""
        return se2.between(self.odom[self.kf_scan[a]], self.odom[self.kf_scan[b]])

    def drive(self, k: int, step: FloatArray) -> FloatArray | None:
        """The odometric ``step`` to keyframe k as the odometry drove it: its path and every
        turn on the way, as a step (path, 0, turn); None when the odometry came only with
        the scans."""
        if self.travel is None:
            return None
        path, turn = self.travel[self.kf_scan[k]] - self.travel[self.kf_scan[k - 1]]
        return np.array([max(path, math.hypot(step[0], step[1])), 0.0, max(turn, abs(step[2]))])

    def odometry_sigmas(self, step: FloatArray) -> tuple[float, float]:
        """What odometry can have got wrong over ``step`` as the configuration says (the
        front end's search sigmas)."""
        config = self.config
        dist = math.hypot(step[0], step[1])
        sigma_xy = ODOMETRY_SIGMA_M + config.odometry_sigma_m_per_m * dist
        sigma_theta = (
            ODOMETRY_SIGMA_RAD
            + math.radians(config.odometry_sigma_deg_per_m) * dist
            + config.odometry_sigma_per_rad * abs(step[2])
        )
        return sigma_xy, sigma_theta


class Submaps:
    """The submaps: the two being built around the chain, and the finished ones (their
    fields cached within SUBMAP_MEMORY_BYTES, indexed for loop closure)."""

    def __init__(self, keyframes: Keyframes) -> None:
        self.keyframes = keyframes
        self.active: list[Submap] = []
        self.finished: list[Submap] = []
        self.cache = SubmapCache(SUBMAP_MEMORY_BYTES)
        self.index = SubmapIndex()

    def insert(self, k: int, poses: FloatArray) -> None:
        """Keyframe k (at ``poses[k]``) into the submaps being built; a new one begins every
        ``submap_m`` of path or SUBMAP_MAX_KEYFRAMES, and the oldest of three is finished."""
        config = self.keyframes.config
        clouds = self.keyframes.clouds
        newest = self.active[-1] if self.active else None
        if (
            newest is None
            or clouds.path_m(newest.anchor, k) >= config.submap_m
            or len(newest.keyframes) >= SUBMAP_MAX_KEYFRAMES
        ):
            self.active.append(
                Submap(
                    k,
                    int(self.keyframes.kf_floor[k]),
                    config.resolution_m,
                    config.resolution_m,
                    clouds.surfaces,
                )
            )
            if len(self.active) > 2:
                self._finish(self.active.pop(0))
        for sub in self.active:
            sub.insert(k, se2.between(poses[sub.anchor], poses[k]))

    def _finish(self, sub: Submap) -> None:
        sub.finish()
        if len(sub.keyframes) >= 2:
            self.finished.append(sub)
            self.index.add(sub)
            self.cache.use(sub)

    def finish_active(self) -> None:
        """The submaps being built are finished: the next keyframe begins new ones."""
        while self.active:
            self._finish(self.active.pop(0))

    def rebuild_active(self, poses: FloatArray) -> None:
        """A solve moved the keyframes of the submaps being built: build them again from
        the corrected ``poses``, so the front end matches against the map as it now stands."""
        for sub in self.active:
            sub.relocate([se2.between(poses[sub.anchor], poses[k]) for k in sub.keyframes])


class Chain:
    """The pose graph of the keyframes and the closures it holds: the closures enter here,
    and the graph is solved when one disagrees with it."""

    def __init__(self, submaps: Submaps, stats: Counter[str]) -> None:
        self.graph = PoseGraph()
        self.submaps = submaps
        self.stats = stats
        self.loops: list[tuple[int, int]] = []
        self._pairs: set[tuple[int, int]] = set()  # the keyframes of ``loops``
        #: the motion each of ``loops`` measured, in the same order
        self.loop_motions: list[FloatArray] = []
        self.unsolved: list[int] = []  # loop edges added since the last solve
        self.last_closure = 0  # keyframe of the last accepted closure (or visit start)

    def begin_visit(self, k: int) -> None:
        """A visit begins at keyframe k: the ride ties it to the last, as a closure would."""
        self.last_closure = k

    def accept_loop(self, edge: Edge, score: float) -> None:
        """Put a closure into the graph, unless one between the same two keyframes is there.

        One keyframe's scan matched against one place is one measurement, however many
        searches found it: two loop targets can frame the same revisited keyframe (a wide
        search against the run around it is the same search for both), and a closure taken
        twice weighs double in the graph. Its first finding stands."""
        if (edge.i, edge.j) in self._pairs:
            self.stats["loop_repeats"] += 1
            return
        self._pairs.add((edge.i, edge.j))
        # the largest correction a closure made to the graph as it stood: the front end's
        # drift at the first revisit after a long drive, for the bench to print
        poses = self.graph.poses
        fix = se2.between(se2.between(poses[edge.i], poses[edge.j]), edge.z)
        moved_mm = round(1000 * math.hypot(fix[0], fix[1]))
        self.stats["loop_max_correction_mm"] = max(self.stats["loop_max_correction_mm"], moved_mm)
        index = self.graph.add_edge(edge)
        self.unsolved.append(index)
        self.loops.append((edge.i, edge.j))
        self.loop_motions.append(edge.z.copy())
        self.last_closure = max(self.last_closure, edge.j)
        log.debug("loop closure", frm=edge.i, to=edge.j, score=round(score, 3))

    def solve_if_needed(self) -> None:
        """Solve the graph when a closure since the last solve disagrees with it, or
        SOLVE_AFTER_LOOPS wait; the submaps being built follow the solve."""
        if not self.unsolved:
            return
        _, chi2 = self.graph.edge_errors(edges=np.array(self.unsolved))
        if chi2.max() > SOLVE_ABOVE_CHI2 or len(self.unsolved) >= SOLVE_AFTER_LOOPS:
            self.graph.optimize(iterations=SOLVE_ITERATIONS)
            self.stats["solves"] += 1
            self.unsolved.clear()
            self.submaps.rebuild_active(self.graph.poses)


class SlamPart:
    """What every part of a run is handed: the keyframes it reads, the chain it puts its
    edges and poses into, and the statistics it counts in."""

    def __init__(self, keyframes: Keyframes, chain: Chain, stats: Counter[str]) -> None:
        self.keyframes = keyframes
        self.clouds = keyframes.clouds
        self.config = keyframes.config
        self.kf_scan = keyframes.kf_scan
        self.kf_floor = keyframes.kf_floor
        self.kf_visit = keyframes.kf_visit
        self.chain = chain
        self.stats = stats


class OdometryLearning:
    """What the run teaches about odometry: its systematic errors, learnt from front-end
    matches (:mod:`baromap.mapping.odometry_calibration`), and, at the end, the noise
    corrected odometry still shows against the steps matched at both ends."""

    def __init__(self, config: SlamConfig) -> None:
        self.config = config
        self.calibration = OdometryCalibration()
        #: covariance of each front-matched keyframe's pose (its own frame), for calibration
        self.front_cov: dict[int, FloatArray] = {}
        #: steps matched at both ends, (odometric, matched): what odometry's noise is learnt from
        self.matched_steps: list[tuple[FloatArray, FloatArray]] = []
        #: corrected odometry's noise as the run showed it (set at the end, when it can say)
        self.noise: OdometryNoise | None = None

    def learn(self, k: int, read: FloatArray, edge: Edge) -> None:
        """Keyframe k was matched: with k - 1 matched too, the step between them is measured at
        both ends, a sample of what odometry got wrong (:mod:`odometry_calibration`)."""
        # k's pose, in k's own frame
        cov = edge_covariance(edge.information)
        self.front_cov[k] = cov
        before = self.front_cov.get(k - 1)
        if before is not None:
            # k's covariance in the frame of k - 1 (k stands turned by z's heading in it)
            in_before = rotate_information(cov, -float(edge.z[2]))
            self.calibration.observe(read, edge.z, before + in_before)
            self.matched_steps.append((read.copy(), edge.z.copy()))

    def fit_noise(self) -> OdometryNoise | None:
        """Corrected odometry's noise, fitted to the matched steps' residuals (None when too
        few steps were matched at both ends to say); kept as :attr:`noise`."""
        self.noise = self._fit_noise()
        return self.noise

    def _fit_noise(self) -> OdometryNoise | None:
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
