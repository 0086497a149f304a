"""The front end: each keyframe matched against the submap it drives through, in a window
as wide as odometry can be wrong, refused where ambiguous; the steps it pins down at both
ends teach the odometry calibration."""

from __future__ import annotations

from collections import Counter

import numpy as np

from baromap.arrays import FloatArray
from baromap.mapping import se2
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
from baromap.mapping.scans import voxel_filter
from baromap.mapping.slam.measurement import (
    diagonal_information,
    lattice_angle_step,
    match_edge,
    place_on_ridge,
    search_window,
)
from baromap.mapping.slam.settings import (
    CAR_EXTENT_M,
    FRONT_MAX_AMBIGUITY,
    FRONT_RETRY_BELOW,
    FRONT_RETRY_M,
    FRONT_RETRY_TURN_RAD,
    FRONT_RIDGE_SHARE,
    MAX_FRONT_WINDOW_M,
    MAX_FRONT_WINDOW_RAD,
    MIN_ANGLE_STEP_RAD,
    MIN_POINTS,
    MIN_WINDOW_M,
    MIN_WINDOW_RAD,
    PRIOR_WEIGHT,
    WINDOW_SIGMAS,
)
from baromap.mapping.slam.state import Chain, Keyframes, OdometryLearning, SlamPart, Submaps
from baromap.mapping.submaps import Submap


class FrontEnd(SlamPart):
    """Matching each keyframe against the map being built around it. It owns what the chain
    knows of its own doubt: where the current visit began and the last step the scan could
    not vouch for."""

    def __init__(
        self,
        keyframes: Keyframes,
        chain: Chain,
        submaps: Submaps,
        odometry: OdometryLearning,
        stats: Counter[str],
    ) -> None:
        super().__init__(keyframes, chain, stats)
        self.submaps = submaps
        self.odometry = odometry
        self.visit_start = 0
        #: keyframe of the last front-end step the scan could not vouch for (a weak, refused
        #: or missing match: odometry or a doubtful match placed it), -1 for none
        self.last_doubtful = -1

    def begin_visit(self, k: int) -> None:
        """A visit begins at keyframe k: the look back after a turn stays within it."""
        self.visit_start = k

    def match(
        self, k: int, guess: FloatArray, sigma_xy: float, sigma_theta: float, read: FloatArray
    ) -> None:
        """Keyframe k matched against the older submap being built, from odometry's
        ``guess`` within three of its sigmas; taken into the graph and taught to the odometry
        calibration unless too weak or ambiguous (``read``: the step as the wheels read it)."""
        points = self.clouds.points[k]
        if len(points) < MIN_POINTS or not self.submaps.active:
            self.stats["front_skipped"] += 1
            self.last_doubtful = k
            return
        sub = self.submaps.active[0]
        anchor = self.chain.graph.poses[sub.anchor]
        local_guess = se2.between(anchor, guess)
        prior = Prior(local_guess, sigma_xy, sigma_theta, PRIOR_WEIGHT)
        fld, result = self._search(k, sub, prior, turn=float(read[2]))
        ambiguous = result.runner_up >= FRONT_MAX_AMBIGUITY * result.score
        spread = self._ridge(fld, points, result) if ambiguous else None
        if spread is not None:
            ambiguous = False
            self.stats["front_ridges"] += 1
        if result.score < FRONT_RETRY_BELOW or ambiguous:
            self.last_doubtful = k
        if result.score < self.config.front_min_score:
            self.stats["front_failures"] += 1
            return
        if ambiguous:
            self.stats["front_ambiguous"] += 1
            return
        edge = match_edge(sub.anchor, k, result, kind="match", spread=spread)
        placed = result.pose
        if spread is not None:
            placed = place_on_ridge(
                local_guess, diagonal_information(sigma_xy, sigma_theta), result.pose, spread
            )
        self.chain.graph.poses[k] = se2.compose(anchor, placed)
        # the measurement is expressed from the previous keyframe, whose pose the submap
        # holds as the graph last had it: a solve that bends the run between the anchor and
        # the previous keyframe then moves this edge with it
        edge.i = k - 1
        edge.z = se2.between(se2.between(anchor, self.chain.graph.poses[k - 1]), result.pose)
        self.chain.graph.add_edge(edge)
        self.stats["front_matches"] += 1
        self.odometry.learn(k, read, edge)

    def _search(
        self, k: int, sub: Submap, prior: Prior, *, turn: float
    ) -> tuple[LikelihoodField, MatchResult]:
        """Keyframe k matched against the submap ``sub`` from the ``prior``'s pose (in the
        anchor's frame), within three of its sigmas: the field it was matched in and the
        match. ``turn``: the odometric turn since the last keyframe (a poor match after a
        turn is tried again, :meth:`_retry_after_turn`)."""
        config = self.config
        points = self.clouds.points[k]
        local_guess = prior.pose
        linear = min(MAX_FRONT_WINDOW_M, max(MIN_WINDOW_M, WINDOW_SIGMAS * prior.sigma_xy))
        angular = min(MAX_FRONT_WINDOW_RAD, max(MIN_WINDOW_RAD, WINDOW_SIGMAS * prior.sigma_theta))
        window = search_window(
            linear,
            angular,
            lattice_angle_step(self.clouds.typical_range[k], config.resolution_m),
            config.resolution_m,
        )
        if self.clouds.extent[k] < CAR_EXTENT_M:
            # a small enclosure (the elevator car): its walls are a metre away, where a 5 cm
            # cell blurs a degree of rotation, so it is matched in a field twice as fine made
            # of what the submap's keyframes saw of it
            fld = self._fine_field(sub, local_guess)
            window = SearchWindow(window.linear_m, window.angular_rad, MIN_ANGLE_STEP_RAD)
            return fld, match(fld, points, local_guess, window, prior=prior)
        fld = sub.field
        coarse = sub.coarse(window.coarse_step_cells) if window.coarse_step_cells > 1 else None
        result = match(fld, points, local_guess, window, coarse_field=coarse, prior=prior)
        if result.score < FRONT_RETRY_BELOW and abs(turn) > FRONT_RETRY_TURN_RAD:
            result = self._retry_after_turn(k, sub.anchor, result, window=window, prior=prior)
        return fld, result

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
        fails without it: odometry is several degrees off over such a turn, and the scan,
        looking back, overlaps the submap of the last metres (seen looking forward) too
        little to match. The retry roughly halves the heading error of the steps where it is
        taken (docs/decisions.md, "The front end takes weak matches").
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
        poses = self.chain.graph.poses
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
        keyframe stands where odometry puts it, degrees off after a turn, and the next scans
        match against it: one such keyframe a few degrees off turns hundreds of metres of the
        run. Two peaks with a valley
        between them (the next door along a corridor) stay ambiguous, and so do two answers
        turned against each other: a scan that cannot tell its heading to 5 degrees has not
        measured it (taken, such keyframes land further off than odometry puts them).
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
