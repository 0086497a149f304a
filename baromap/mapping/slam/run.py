"""One SLAM run over a recording's scans: keyframes chosen, fed one by one, solved at the
end, and every scan's pose from the keyframes around it."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import structlog

from baromap.arrays import BoolArray, FloatArray, Int8Array, IntArray
from baromap.mapping import se2
from baromap.mapping.errors import MappingError
from baromap.mapping.keyframes import motion_spaced
from baromap.mapping.pose_graph import Edge, PoseGraph
from baromap.mapping.refine import Pull, refine_batch
from baromap.mapping.scan_matcher import LikelihoodField
from baromap.mapping.scans import ScanBlock
from baromap.mapping.slam.car import ElevatorCar
from baromap.mapping.slam.final_solve import FinalSolve
from baromap.mapping.slam.front_end import FrontEnd
from baromap.mapping.slam.loops import LoopCloser
from baromap.mapping.slam.measurement import diagonal_information, finished_map_field
from baromap.mapping.slam.relocation import Relocation
from baromap.mapping.slam.settings import (
    BETWEEN_FLOORS,
    BLIND_SPEED_M_S,
    BLIND_TURN_RAD_S,
    MAX_FRONT_WINDOW_M,
    MAX_FRONT_WINDOW_RAD,
    ODOMETRY_SIGMA_M,
    ODOMETRY_SIGMA_RAD,
    REGISTER_BEAMS,
    REGISTER_CHUNK,
    TURN_AS_M,
    WINDOW_SIGMAS,
    SlamConfig,
)
from baromap.mapping.slam.state import Chain, Keyframes, OdometryLearning, Submaps

log = structlog.get_logger(__name__)


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
    #: keyframes placed against the start's part of the map by odometry across a gap alone,
    #: one array per part (:meth:`_Slam._untied`); empty when every part is tied
    untied: list[IntArray] = field(default_factory=list)
    #: for each of ``untied``, what cut it from the rest: the evidence of the break
    untied_evidence: list[str] = field(default_factory=list)
    #: (S,): the keyframes, and the scans between them whose pose the finished map of their
    #: floor confirmed (:meth:`_Slam.register_scans`); empty until registered
    scan_registered: BoolArray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    #: (L, 3): the motion from i to j each of ``loop_edges`` measured (the refinement's
    #: ``graph`` holds no closure): what the scans said, beside where the run placed them
    loop_motions: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))


def select_keyframes(
    odom: FloatArray, visit: IntArray, floor: IntArray, config: SlamConfig
) -> IntArray:
    """Scans where the robot has moved enough since the last keyframe of the same visit, and
    the first and last scan of every visit (the car before and after a ride)."""
    group = np.where(floor == BETWEEN_FLOORS, -1, visit)
    return motion_spaced(odom, group, config.keyframe_m, config.keyframe_rad, last_of_group=True)


class _Slam:
    """One SLAM run, fed one keyframe at a time: the keyframes and what the odometry said,
    the submaps, the chain of keyframes in its pose graph, the front end, loop closure, the
    car, the search after an unmeasured step and the last solve, each keeping its own state,
    and the statistics they all count into."""

    def __init__(self, keyframes: Keyframes) -> None:
        self.keyframes = keyframes
        self.config = keyframes.config
        self.stats: Counter[str] = Counter()
        self.submaps = Submaps(keyframes)
        self.chain = Chain(self.submaps, self.stats)
        self.odometry = OdometryLearning(keyframes.config)
        self.front_end = FrontEnd(keyframes, self.chain, self.submaps, self.odometry, self.stats)
        self.loops = LoopCloser(keyframes, self.chain, self.submaps, self.front_end, self.stats)
        self.car = ElevatorCar(keyframes, self.chain, self.stats)
        self.relocation = Relocation(keyframes, self.chain, self.stats)
        self.final = FinalSolve(keyframes, self.chain, self.odometry, self.car, self.stats)
        #: keyframes reached by a step the fitted odometry noise does not describe: beyond the
        #: front end's window (the laser silent), or across a gap in the odometry
        self.silent_steps: set[int] = set()

    def add(self, k: int) -> None:
        run = self.keyframes
        graph = self.chain.graph
        if k == 0:
            graph.add_node(run.odom[run.kf_scan[0]])
            self.submaps.insert(k, self.chain.graph.poses)
            return
        new_visit = bool(run.kf_visit[k] != run.kf_visit[k - 1])
        if new_visit:
            self._end_visit()
            self.relocation.give_up()
        read = run.odometry_step(k - 1, k)
        step = self.odometry.calibration.correct(read)
        guess = se2.compose(graph.poses[k - 1], step)
        graph.add_node(guess)
        sigma_xy, sigma_theta = self._step_sigmas(k, step, read)
        blind = bool(run.blind_step[k])
        if blind:
            self.stats["odometry_gaps"] += 1
        if not new_visit and self._beyond_front_window(
            blind, sigma_xy, sigma_theta, run.drive(k, read) is not None
        ):
            # a step longer than the front end's widest window can search odometry's doubt
            # over (the laser silent while the robot drove on: unplugged, power-cycled): the
            # scan is not matched against the submaps from before it, where a capped window
            # holds only aliases; it begins new ones, and loop closure, whose search widens
            # with the drift, ties them back
            self.stats["front_after_gap"] += 1
            self.silent_steps.add(k)
            self.submaps.finish_active()
        # odometry always enters the graph: along a featureless corridor it is the only
        # measurement of the motion, and the match edge's information says so
        graph.add_edge(
            Edge(k - 1, k, step, diagonal_information(sigma_xy, sigma_theta), "odometry")
        )
        if new_visit:
            self.front_end.begin_visit(k)
            self.chain.begin_visit(k)
            self.car.ride(k, guess, sigma_xy, sigma_theta)
        else:
            self.front_end.match(k, guess, sigma_xy, sigma_theta, read)
        self.submaps.insert(k, self.chain.graph.poses)
        if run.unmeasured_step[k] and not new_visit:
            self.relocation.start(k, sigma_xy, sigma_theta)
        self.relocation.relocate(k)
        if not run.clouds.in_car(k) and k - self.front_end.visit_start >= 1:
            self.loops.close(k)
        self.chain.solve_if_needed()

    def _step_sigmas(self, k: int, step: FloatArray, read: FloatArray) -> tuple[float, float]:
        """What odometry can have got wrong over the (corrected) ``step`` to keyframe k: over
        a drive beyond the front end's window, the whole drive's doubt, not its end's; across
        scans the odometry said nothing about, as far as the robot can drive and turn in the
        time (odometry drew a straight line there)."""
        run = self.keyframes
        sigma_xy, sigma_theta = run.odometry_sigmas(step)
        drive = run.drive(k, read)
        if drive is not None:
            drive_xy, drive_theta = run.odometry_sigmas(drive)
            if (
                WINDOW_SIGMAS * drive_xy > MAX_FRONT_WINDOW_M
                or WINDOW_SIGMAS * drive_theta > MAX_FRONT_WINDOW_RAD
            ):
                sigma_xy, sigma_theta = max(sigma_xy, drive_xy), max(sigma_theta, drive_theta)
        if run.blind_step[k]:
            seconds = float(run.t_ns[run.kf_scan[k]] - run.t_ns[run.kf_scan[k - 1]]) / 1e9
            sigma_xy = max(sigma_xy, BLIND_SPEED_M_S * seconds / WINDOW_SIGMAS)
            sigma_theta = max(sigma_theta, BLIND_TURN_RAD_S * seconds / WINDOW_SIGMAS)
        return sigma_xy, sigma_theta

    @staticmethod
    def _beyond_front_window(
        blind: bool, sigma_xy: float, sigma_theta: float, driven: bool
    ) -> bool:
        """Whether a step is beyond what the front end's widest window searches: across a
        gap, or with more doubt in position (or, where the odometry's drive is known, in
        heading) than it holds."""
        return (
            blind
            or WINDOW_SIGMAS * sigma_xy > MAX_FRONT_WINDOW_M
            or (driven and WINDOW_SIGMAS * sigma_theta > MAX_FRONT_WINDOW_RAD)
        )

    def finish(self) -> SlamResult:
        self._end_visit()
        self.car.car_to_car()
        self.final.solve(self.silent_steps)
        run = self.keyframes
        calibration = self.odometry.calibration
        self.stats["keyframes"] = len(run.kf_scan)
        self.stats["odometry_samples"] = calibration.samples
        scale = calibration.scale()
        turn, creep = calibration.turn_terms()
        log.info(
            "odometry calibration",
            samples=calibration.samples,
            rejected=calibration.rejected,
            scale=round(scale, 5),
            turn=round(turn, 5),
            creep_deg_per_m=round(math.degrees(creep), 4),
        )
        self.stats["loops"] = len(self.chain.loops)
        self.stats["submaps"] = len(self.submaps.finished)
        self.stats["submap_releases"] = self.submaps.cache.releases
        untied, evidence = self._untied()
        self.stats["untied_keyframes"] = sum(len(part) for part in untied)
        poses = self.chain.graph.poses.copy()
        return SlamResult(
            run.kf_scan,
            poses,
            np.zeros((0, 3)),
            self.chain.graph,
            self.chain.loops,
            self.car.car_edges,
            {k: float(v) for k, v in self.stats.items()},
            (scale, turn, creep),
            untied,
            evidence,
            loop_motions=np.array(self.chain.loop_motions, dtype=np.float64).reshape(-1, 3),
        )

    def _untied(self) -> tuple[list[IntArray], list[str]]:
        """The keyframes that nothing but odometry across a gap places against the part of
        the map where the run began, one array per part.

        A step over a laser silence or a gap in the odometry (``silent_steps``, and a gap
        in the odometry at a ride) is not matched; loop closures, the car at a ride or the
        chain found again after a power cycle tie what comes after it back. Where none does
        (the robot drove on through ground it never saw again, runs of two explorations
        given as one) that part stands where the odometry across the gap put it, metres and
        degrees off for all the scans can say, and its own map may be right while the
        building's is not."""
        run = self.keyframes
        across = self.silent_steps | set(np.flatnonzero(run.blind_step | run.unmeasured_step))
        if not across:
            return [], []
        gaps = np.array(
            [e.kind == "odometry" and e.j in across for e in self.chain.graph.edges], dtype=bool
        )
        if not gaps.any():
            return [], []
        part = self.chain.graph.parts(gaps)
        untied = [np.flatnonzero(part == p) for p in range(1, int(part.max()) + 1)]
        if not untied:
            return [], []
        # a part's first keyframe is reached by a step across a gap: what made it one
        said = [self._gap_evidence(int(p[0])) for p in untied]
        evidence = [text for text, _ in said]
        t = run.t_ns[run.kf_scan]
        for broke, event in ((True, "a gap"), (False, "a long step")):
            parts = [p for p, (_, b) in zip(untied, said, strict=True) if b == broke]
            if not parts:
                continue
            # a break (a silence in time, odometry counted again) is a fault to look at; a
            # sparse log's step longer than the front end searches, in the scans' usual
            # time, is what such a log is
            (log.warning if broke else log.info)(
                f"part of the run is placed by odometry across {event} alone",
                parts=len(parts),
                keyframes=sum(len(p) for p in parts),
                first_after_s=[round(float(t[p[0]] - t[0]) / 1e9, 1) for p in parts],
                floors=sorted({int(f) for p in parts for f in run.kf_floor[p] if f >= 0}),
                evidence=[text for text, b in said if b == broke],
            )
        return untied, evidence

    def _gap_evidence(self, k: int) -> tuple[str, bool]:
        """What made the step to keyframe ``k`` a gap, in words, and whether it is a break: in
        the odometry (the scans either side of it are blind too, so it is said first), scans
        the odometry said nothing about, a drive with no scan for longer than the scans
        usually take; or not a break, a step longer than the front end searches taken in the
        scans' usual time (a sparse log)."""
        run = self.keyframes
        a, b = int(run.kf_scan[k - 1]), int(run.kf_scan[k])
        if run.unmeasured_step[k]:
            return "odometry counted from zero again", True
        silent = np.flatnonzero(run.blind[a + 1 : b + 1]) + a + 1
        if len(silent):
            seconds = float(run.t_ns[silent[-1]] - run.t_ns[silent[0]]) / 1e9
            return f"odometry silent for {seconds:.0f} s while the laser went on", True
        step = se2.between(run.odom[a], run.odom[b])
        moved = f"{math.hypot(step[0], step[1]):.1f} m and {math.degrees(abs(step[2])):.0f} deg"
        if run.long_wait(k):
            seconds = float(run.t_ns[b] - run.t_ns[a]) / 1e9
            return f"laser silent for {seconds:.0f} s while the robot drove {moved}", True
        return (
            f"a step of {moved} in the scans' usual time, longer than the matching searches",
            False,
        )

    def _end_visit(self) -> None:
        self.loops.settle_deferred()
        self.submaps.finish_active()

    def _sides_of_silences(self) -> Int8Array:
        """For the scans between the keyframes of a silent step: -1 before the silence, +1
        after it, split at the longest wait between two scans the odometry spoke for (the
        gap, with the scans it said nothing about inside; the robot may have stood a while
        before it, so the middle of the step is not the gap); 0 for every other scan."""
        run = self.keyframes
        side = np.zeros(len(run.odom), dtype=np.int8)
        t = run.t_ns
        for k in sorted(self.silent_steps):
            a, b = int(run.kf_scan[k - 1]), int(run.kf_scan[k])
            s = np.arange(a + 1, b)
            heard = np.concatenate([[a], s[~run.blind[s]], [b]])
            resumed = heard[int(np.argmax(np.diff(t[heard]))) + 1]
            side[s] = np.where(s >= resumed, 1, -1)
        return side

    def register_scans(self, scans: ScanBlock, floor: IntArray) -> tuple[FloatArray, BoolArray]:
        """Every scan's pose, and which of them the map confirmed: keyframes as the graph has
        them; the scans between them interpolated (:func:`scan_poses`) and then matched
        against the finished map of their floor, pulled towards the interpolation as odometry
        would (a corridor cannot make a scan slide). A scan that finds too little of the map
        keeps its interpolated pose, unconfirmed.

        The pull's sigmas are corrected odometry's noise as the run showed it
        (:meth:`OdometryLearning.fit_noise`) over the travel and turn to the nearer keyframe,
        where the interpolation is pinned: what the interpolation can be wrong by. The front end's
        search sigmas (2 cm + 7 %/m, wide on purpose to hold an uncalibrated robot) are used
        only when the run matched too few steps to fit the noise."""
        run = self.keyframes
        config = self.config
        kf_poses = self.chain.graph.poses
        poses = scan_poses(run.odom, run.kf_scan, kf_poses, silence=self._sides_of_silences())
        is_kf = np.zeros(len(poses), dtype=bool)
        is_kf[run.kf_scan] = True
        confirmed = is_kf.copy()
        to_kf, turn_to_kf = _odometry_to_nearer_keyframe(run.odom, run.kf_scan)
        for f in np.unique(run.kf_floor):
            todo = np.flatnonzero((floor == f) & ~is_kf)
            if len(todo) == 0:
                continue
            fld = self._floor_field(f, kf_poses)
            # a few thousand scans at a time: each is fitted on its own, and every beam of a
            # long run's scans at once would hold gigabytes
            for part in np.array_split(todo, -(-len(todo) // REGISTER_CHUNK)):
                points, owner = scans.sampled_endpoints(part, config.max_range_m, REGISTER_BEAMS)
                pull = self._pull(to_kf[part], turn_to_kf[part])
                out = refine_batch(fld, points, owner, poses[part], pull)
                poses[part[out.usable]] = out.poses[out.usable]
                confirmed[part[out.usable]] = True
                self.stats["registered"] += int(out.usable.sum())
        return poses, confirmed

    def _floor_field(self, f: int, kf_poses: FloatArray) -> LikelihoodField:
        """The finished map of floor f (its keyframes at ``kf_poses``), to match scans on."""
        run = self.keyframes
        ids = np.flatnonzero(run.kf_floor == f)
        world = np.concatenate(
            [se2.transform_points(kf_poses[k], run.clouds.surfaces[k]) for k in ids]
        )
        return finished_map_field(world, self.config.resolution_m)

    def _pull(self, d: FloatArray, turn: FloatArray) -> Pull:
        """What an interpolated pose can be wrong by, ``d`` metres and ``turn`` radians of
        odometry from the keyframe it is pinned to: corrected odometry's noise as the run
        showed it, or the front end's search sigmas where the run could not fit it."""
        config = self.config
        noise = self.odometry.noise
        if noise is not None:
            return Pull(*noise.sigmas_many(d, turn))
        return Pull(
            ODOMETRY_SIGMA_M + config.odometry_sigma_m_per_m * d,
            ODOMETRY_SIGMA_RAD + math.radians(config.odometry_sigma_deg_per_m) * d,
        )


def _odometry_to_nearer_keyframe(
    odom: FloatArray, kf_scan: IntArray
) -> tuple[FloatArray, FloatArray]:
    """Every scan's odometric travel and turn to the nearer of the keyframes around it: how
    much odometry its interpolated pose holds."""
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(odom[:, :2], axis=0).T))])
    kf_travel = travelled[kf_scan]
    pos = np.clip(np.searchsorted(kf_travel, travelled), 1, max(len(kf_travel) - 1, 1))
    after = np.minimum(pos, len(kf_travel) - 1)

    def to_nearer_keyframe(along: FloatArray) -> FloatArray:
        at_kf = along[kf_scan]
        return np.minimum(np.abs(along - at_kf[pos - 1]), np.abs(at_kf[after] - along))

    turned = np.concatenate([[0.0], np.cumsum(np.abs(se2.wrap(np.diff(odom[:, 2]))))])
    return to_nearer_keyframe(travelled), to_nearer_keyframe(turned)


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
    breaks: BoolArray | None = None,
) -> SlamResult:
    """SLAM over a run: scans, odometry poses at the scan times, floor and visit per scan.

    ``travel``: the odometry's path and turning up to each scan, as the odometry came
    (:meth:`~baromap.mapping.run_data.RunData.travel`), where it came more often than the
    scans; it tells a silence of the laser by the drive inside it, not only by where the
    drive ended (None: the scans' own odometry is all there is).

    ``blind``: the scans the odometry said nothing about
    (:attr:`~baromap.mapping.run_data.RunData.blind`: the base unplugged while the
    laser went on). They are not mapped: without odometry a corridor lets the scans slide
    (the sim's blind minute, matched scan by scan with a constant-velocity guess, drifts
    metres where the robot speeds up along one), and the step across them is taken as a laser
    silence is, begun again in new submaps and tied back by loop closure and the car. Their
    poses are drawn across the gap, for the record only.

    ``breaks``: the scans after which the odometry broke (:attr:`RunData.breaks
    <baromap.mapping.run_data.RunData.breaks>`): the step across is not measured, and the
    chain is looked for again as after a power-cycled base."""
    config = config or SlamConfig()
    if blind is not None and blind.any():
        floor = np.where(blind, BETWEEN_FLOORS, floor)
    kf_scan = select_keyframes(odom, visit, floor, config)
    if len(kf_scan) == 0:
        raise MappingError("no scan is on a floor: nothing to map")
    slam = _Slam(
        Keyframes(
            scans,
            odom,
            kf_scan,
            kf_floor=floor[kf_scan],
            kf_visit=visit[kf_scan],
            config=config,
            travel=travel,
            blind=blind,
            breaks=breaks,
        )
    )
    for k in range(len(kf_scan)):
        slam.add(k)
        if progress is not None:
            progress(int(kf_scan[k]))
    result = slam.finish()
    result.scan_poses, result.scan_registered = slam.register_scans(scans, floor)
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
