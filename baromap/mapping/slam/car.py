"""The elevator car, the one place seen on every floor: the rides matched inside it, every
pair of car keyframes matched to tie the floors, and the core around the shaft."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import structlog

from baromap.arrays import FloatArray, IntArray
from baromap.mapping import se2
from baromap.mapping.pose_graph import Edge
from baromap.mapping.refine import concatenate, refine_batch
from baromap.mapping.scan_matcher import LikelihoodField, MatchResult, SearchWindow, match
from baromap.mapping.slam.measurement import (
    finished_map_field,
    match_edge,
    match_information,
    rotate_information,
    same_shift,
)
from baromap.mapping.slam.settings import (
    CAR_FAR_ANGLE_STEP_RAD,
    CAR_FAR_BUDGET,
    CAR_FAR_PER_RIDE,
    CAR_FAR_WINDOW_M,
    CAR_FAR_WINDOW_RAD,
    CAR_MIN_SCORE,
    CAR_WINDOW_M,
    CAR_WINDOW_RAD,
    COARSE_STEP_CELLS,
    CORE_RADIUS_M,
    CORE_REACH_M,
    FINAL_ITERATIONS,
    FRONT_MAX_AMBIGUITY,
    LOOP_MAX_AMBIGUITY,
    LOOP_ROBUST_C,
    LOOP_SIGMA_M,
    LOOP_SIGMA_RAD,
    MAX_FRONT_WINDOW_M,
    MAX_FRONT_WINDOW_RAD,
    MIN_ANGLE_STEP_RAD,
    MIN_WINDOW_M,
    MIN_WINDOW_RAD,
    WINDOW_SIGMAS,
)
from baromap.mapping.slam.state import Chain, Keyframes, SlamPart, graph_of

log = structlog.get_logger(__name__)


@dataclass(frozen=True, slots=True)
class CarModel:
    """The closed car's model: its walls seen from the first ride, in the anchor's frame."""

    anchor: int
    fine: LikelihoodField  # at half the map's cells: the car's walls are a metre away
    far: LikelihoodField  # at the map's cells, for the search beyond the chain's window
    coarse: LikelihoodField = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "coarse", self.fine.pooled(COARSE_STEP_CELLS))


class ElevatorCar(SlamPart):
    """The car and its shaft as the landmark that joins the floors. It owns the closures
    between the car at different rides."""

    def __init__(self, keyframes: Keyframes, chain: Chain, stats: Counter[str]) -> None:
        super().__init__(keyframes, chain, stats)
        #: closures between the closed car at different rides, (model anchor, keyframe)
        self.car_edges: list[tuple[int, int]] = []

    def _car_match(self, a: int, b: int, guess_b: FloatArray, window: SearchWindow) -> MatchResult:
        """Match car keyframe b against car keyframe a, in a's frame, on a fine field: the car's
        walls are a metre away, where a degree of rotation moves points less than a 5 cm cell."""
        res = self.config.resolution_m / 2
        fld = LikelihoodField.from_points(self.clouds.surfaces[a], res, res)
        local = se2.between(self.chain.graph.poses[a], guess_b)
        return match(fld, self.clouds.points[b], local, window)

    def ride(self, k: int, guess: FloatArray, sigma_xy: float, sigma_theta: float) -> None:
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
            self.chain.graph.poses[k] = se2.compose(self.chain.graph.poses[k - 1], result.pose)
            self.chain.graph.add_edge(match_edge(k - 1, k, result, kind="ride"))
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

    def car_to_car(self) -> None:
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
        poses = self.chain.graph.poses
        model, anchor = rides[0], rides[0][0]
        res = self.config.resolution_m / 2
        points = np.concatenate(
            [
                se2.transform_points(se2.between(poses[anchor], poses[m]), self.clouds.surfaces[m])
                for m in model
            ]
        )
        car = CarModel(
            anchor,
            LikelihoodField.from_points(points, res, res),
            LikelihoodField.from_points(points, 2 * res, 2 * res),
        )
        missed = [ride for ride in rides[1:] if not self._car_closures(car, ride)]
        self.stats["car_rides_missed"] = len(missed)
        if missed and self._car_beyond(car, missed):
            for ride in missed:
                self._car_closures(car, ride)

    def _car_closures(self, car: CarModel, ride: list[int]) -> int:
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
            self.chain.graph.add_edge(match_edge(car.anchor, b, result, kind="car"))
            self.car_edges.append((car.anchor, b))
            self.stats["car_closures"] += 1
            taken += 1
        return taken

    def _car_search(
        self, car: CarModel, b: int, window: SearchWindow, *, wide: bool = False
    ) -> MatchResult | None:
        """Car keyframe b matched against the car's model; None when ambiguous."""
        local = se2.between(self.chain.graph.poses[car.anchor], self.chain.graph.poses[b])
        if wide:
            result = match(
                car.far, self.clouds.points[b], local, window, wide=True, budget=CAR_FAR_BUDGET
            )
        else:
            result = match(car.fine, self.clouds.points[b], local, window, coarse_field=car.coarse)
        if result.runner_up >= LOOP_MAX_AMBIGUITY * result.score:
            return None
        return result

    def _car_beyond(self, car: CarModel, missed: list[list[int]]) -> bool:
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
        poses = self.chain.graph.poses
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
            if any(other is not shift and same_shift(shift, other) for _, _, other in found):
                edge = match_edge(car.anchor, b, result, kind="car")
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
        kept = list(self.chain.graph.edges)
        self.chain.graph = graph_of(poses, kept + pulls)
        self.chain.graph.optimize(iterations=FINAL_ITERATIONS)
        self.chain.graph = graph_of(self.chain.graph.poses, kept)
        return True

    def core_edges(self, poses: FloatArray) -> list[Edge]:
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
            others = np.concatenate([o for w, o in visits.items() if w != v])
            edges += self._core_matches(poses, center, ids, others)
        self.stats["core_edges"] = len(edges)
        return edges

    def _core_matches(
        self, poses: FloatArray, center: FloatArray, ids: IntArray, others: IntArray
    ) -> list[Edge]:
        """The keyframes ``others`` (of the other visits, near the car at ``center``) matched
        against the core as the visit's keyframes ``ids`` saw it, in the frame of the first
        of them: one robust edge each where the match is usable."""
        res = self.config.resolution_m
        edges: list[Edge] = []
        anchor = int(ids[0])
        clouds = []
        for k in ids:
            pts = se2.transform_points(poses[k], self.clouds.surfaces[k])
            keep = np.hypot(pts[:, 0] - center[0], pts[:, 1] - center[1]) < CORE_REACH_M
            clouds.append(se2.transform_points(se2.inverse(poses[anchor]), pts[keep]))
        fld = finished_map_field(np.concatenate(clouds), res)
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
                    rotate_information(info, out.poses[n, 2]),
                    "core",
                    robust_c=LOOP_ROBUST_C,
                )
            )
        return edges
