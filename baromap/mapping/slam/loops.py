"""Loop closure within a floor: revisits found by where the chain is, matched in a window
as wide as the front end can have drifted, refused where ambiguous or beyond the drift, and
the doubtful ones taken only when another closure agrees."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray
from baromap.mapping import se2
from baromap.mapping.pose_graph import Edge
from baromap.mapping.scan_matcher import LikelihoodField, MatchResult, Prior, SearchWindow, match
from baromap.mapping.slam.front_end import FrontEnd
from baromap.mapping.slam.measurement import lattice_angle_step, match_edge, search_window
from baromap.mapping.slam.settings import (
    CAR_MIN_POINTS,
    LOOP_BASE_M,
    LOOP_BASE_RAD,
    LOOP_GROUP_KEYFRAMES,
    LOOP_GROUP_MIN_SCORE,
    LOOP_MAX_AMBIGUITY,
    LOOP_MAX_M,
    LOOP_MAX_RAD,
    LOOP_MIN_KEYFRAMES,
    LOOP_MIN_SEPARATION,
    LOOP_PRIOR_SIGMA_M,
    LOOP_PRIOR_SIGMA_RAD,
    LOOP_RETRY_M,
    LOOP_TARGETS,
    LOOP_WIDE_M,
    MAX_FRONT_WINDOW_RAD,
    MIN_WINDOW_M,
    MIN_WINDOW_RAD,
    PRIOR_WEIGHT,
)
from baromap.mapping.slam.state import Chain, Keyframes, SlamPart, Submaps
from baromap.mapping.submaps import Submap


@dataclass(frozen=True, slots=True)
class _LoopSearch:
    """One loop search of keyframe ``k`` against the target ``target`` (its anchor keyframe)
    around the revisited keyframe ``nearest_kf``: the drift ``bounds`` (metres, radians) it
    was sized by, its window, where it started and what it found."""

    k: int
    nearest_kf: int
    target: int
    bounds: tuple[float, float]
    window: SearchWindow
    local_guess: FloatArray
    result: MatchResult
    sparse_target: bool
    wide: bool
    following: bool
    #: searched against the run around the revisit, not the submap (:meth:`_stretch_target`)
    stretched: bool
    #: ... which the run frames on one side only
    one_sided: bool

    @property
    def moved(self) -> float:
        """How far the match moved k from where the search started."""
        pose, start = self.result.pose, self.local_guess
        return math.hypot(pose[0] - start[0], pose[1] - start[1])

    @property
    def turned(self) -> float:
        return abs(float(se2.wrap(self.result.pose[2] - self.local_guess[2])))

    def beyond_drift(self, resolution_m: float) -> bool:
        """A correction larger than the front end can have drifted along the way (to a cell
        and a step of the lattice's angle)."""
        bound_m, bound_rad = self.bounds
        return (
            self.moved > bound_m + resolution_m
            or self.turned > bound_rad + self.window.angle_step_rad
        )


class LoopCloser(SlamPart):
    """Closing loops against the finished submaps of the same floor. It owns the closures
    that wait: proposals waiting for another to agree, those of them beyond the drift model,
    and those against a target the run frames on one side only."""

    def __init__(
        self,
        keyframes: Keyframes,
        chain: Chain,
        submaps: Submaps,
        front_end: FrontEnd,
        stats: Counter[str],
    ) -> None:
        super().__init__(keyframes, chain, stats)
        self.submaps = submaps
        self.front_end = front_end
        #: closures under the threshold waiting for another to agree (see _propose)
        self.pending: list[tuple[Edge, float]] = []
        #: those of them beyond the drift model, searched for again (see _follow_beyond)
        self.beyond: list[Edge] = []
        #: closures against a target the run frames on one side only, kept until the visit
        #: ends in case no closure framed on both sides comes (see settle_deferred)
        self.deferred: list[tuple[Edge, float]] = []

    def close(self, k: int) -> None:
        """Keyframe k's closures: the finished submaps it may revisit, each matched, and the
        closure beyond the drift model waiting for a partner followed from k."""
        points = self.clouds.points[k]
        if len(points) < CAR_MIN_POINTS or not self.submaps.finished:
            return
        index = self.submaps.index
        travelled = float(self.clouds.distance[k])
        since_closure = self.clouds.path_m(self.chain.last_closure, k)
        near = index.last_keyframe <= k - LOOP_MIN_SEPARATION
        near &= travelled - index.tried_at >= LOOP_RETRY_M
        for n, nearest_kf, repeat in self._loop_candidates(
            k, self.chain.graph.poses[k], since_closure, near
        ):
            index.tried_at[n] = travelled
            if not repeat:
                self._try_loop(k, self.submaps.finished[n], nearest_kf, since_closure)
        self._follow_beyond(k)

    def _loop_candidates(
        self, k: int, here: FloatArray, since_closure: float, near: npt.NDArray[np.bool_]
    ) -> list[tuple[int, int, bool]]:
        """The finished submaps (of those ``near`` allows) a revisit at ``here`` may match,
        nearest first, at most LOOP_TARGETS: (submap, revisited keyframe, repeat). Two small
        submaps sharing the revisited keyframe stand for the same target (the keyframes
        around it): the second is a repeat, one match of the target is enough."""
        index = self.submaps.index
        poses = self.chain.graph.poses
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
            sub = self.submaps.finished[m]
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
            if len(self.submaps.finished[n].keyframes) < LOOP_MIN_KEYFRAMES:
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
        cannot see it (a keyframe scores well at a correction of tens of degrees, the next
        windows reach a few degrees less, and unfollowed the run ends metres off).
        Searched around where the proposal puts keyframe k (the window sized by the drift
        since the proposal, never wide), the next scan either fits there as a loop does
        (score past loop_min_score, unambiguous, within that drift) and the two must still
        agree, or does not and the proposal lapses as any unconfirmed one does: the window
        says where to look, the scans decide. Only until a closure is taken at or after the
        proposal's keyframe: the graph has then placed the run anew (following on after
        that, a proposal whose sibling was taken confirms itself through weak targets).
        """
        # a closure taken since (here or after the proposal) has placed the run anew: the
        # proposal is then either what the graph holds or contradicted, nothing to follow
        self.beyond = [
            e
            for e in self.beyond
            if e.j > self.chain.last_closure and k - e.j <= LOOP_GROUP_KEYFRAMES
        ]
        earlier = [
            (edge, score)
            for edge, score in self.pending
            if edge.j < k and any(edge is e for e in self.beyond)
        ]
        if not earlier:
            return
        proposal = max(earlier, key=lambda p: p[1])[0]
        poses = self.chain.graph.poses
        # keyframe k, moved with the keyframe the proposal places
        placed = se2.compose(poses[proposal.i], proposal.z)
        guess = se2.compose(placed, se2.between(poses[proposal.j], poses[k]))
        since = self.clouds.path_m(proposal.j, k)
        near = self.submaps.index.last_keyframe <= k - LOOP_MIN_SEPARATION
        for n, nearest_kf, repeat in self._loop_candidates(k, guess, since, near):
            if repeat:
                continue
            self.stats["loop_follows"] += 1
            self._try_loop(k, self.submaps.finished[n], nearest_kf, since, guess=guess)
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
        guess: FloatArray | None = None,
    ) -> None:
        """Match keyframe k against a finished submap it may revisit, and take, propose or
        refuse the closure. ``guess`` is where to search from when not k's estimate (a
        proposal followed, :meth:`_follow_beyond`): what it finds is then only proposed.

        Past LOOP_MAX_M of drift the window is searched by branch and bound against the run
        around the revisit (:meth:`_stretch_target`), and what it finds must agree with
        another keyframe's closure: a window of metres holds aliases. Where that correction
        turns out within LOOP_MAX_M, the capped search against the submap decides instead,
        alone: the front end has drifted no further than the capped window reaches.
        """
        drift = min(since_closure, self.clouds.path_m(nearest_kf, k))
        bound_m = LOOP_BASE_M + self.config.drift_m_per_m * drift
        bound_rad = LOOP_BASE_RAD + math.radians(self.config.drift_deg_per_m) * drift
        # a followed proposal is looked for where it puts k, not searched for afresh
        wide = bound_m > LOOP_MAX_M and guess is None
        found = self._search_loop(k, sub, nearest_kf, (bound_m, bound_rad), wide=wide, guess=guess)
        if found.stretched and found.moved <= LOOP_MAX_M:
            # against a target the run frames on one side only, the capped window's closure
            # is kept in case no closure framed on both sides follows (see settle_deferred)
            capped = self._search_loop(k, sub, nearest_kf, (bound_m, bound_rad), wide=False)
            self._judge_loop(capped, defer=found.one_sided)
            return
        if found.one_sided:
            self.stats["loop_unframed"] += 1
            return
        self._judge_loop(found, defer=False)

    def _search_loop(
        self,
        k: int,
        sub: Submap,
        nearest_kf: int,
        bounds: tuple[float, float],
        *,
        wide: bool,
        guess: FloatArray | None = None,
    ) -> _LoopSearch:
        """Keyframe k matched against its loop target, in a window as wide as the drift
        ``bounds`` (metres, radians), capped at LOOP_MAX_M unless ``wide`` (then at
        LOOP_WIDE_M, by branch and bound, against the run around the revisit when the
        target is dense), from ``guess`` or k's estimate."""
        config = self.config
        poses = self.chain.graph.poses
        bound_m, bound_rad = bounds
        # any target: after a long drive without a closure (a big building's loop of
        # hundreds of metres) the front end is metres off, and a window capped at LOOP_MAX_M
        # would hold only the aliases, the best of which scores like a loop; a dense target
        # is then the run around the revisit
        sparse_target = len(sub.keyframes) < LOOP_MIN_KEYFRAMES
        stretch = None
        one_sided = False
        if wide and not sparse_target:
            stretch, one_sided = self._stretch_target(nearest_kf, k, min(LOOP_WIDE_M, bound_m))
        linear = min(LOOP_WIDE_M if wide else LOOP_MAX_M, bound_m)
        angular = min(LOOP_MAX_RAD, bound_rad)
        window = search_window(
            max(linear, MIN_WINDOW_M),
            max(angular, MIN_WINDOW_RAD),
            lattice_angle_step(self.clouds.typical_range[k], config.resolution_m),
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
        return _LoopSearch(
            k,
            nearest_kf,
            target,
            bounds,
            window,
            local_guess,
            result,
            sparse_target=sparse_target,
            wide=wide,
            following=guess is not None,
            stretched=stretch is not None,
            one_sided=one_sided,
        )

    def _judge_loop(self, found: _LoopSearch, *, defer: bool) -> None:
        """Take, propose, defer or refuse the closure a loop search found."""
        config = self.config
        result = found.result
        low = LOOP_GROUP_MIN_SCORE if found.sparse_target else config.loop_min_score
        if found.following:
            # the window is centred on the proposal: only a scan that fits there as a
            # loop does (a weak one fits anywhere near) says the proposal is right
            low = config.loop_min_score
        if result.score < low:
            return
        beyond = found.beyond_drift(config.resolution_m)
        if beyond and (
            found.following
            or self.front_end.last_doubtful <= max(self.chain.last_closure, found.nearest_kf)
            or result.score < config.loop_min_score
            or found.moved > LOOP_MAX_M
            or found.turned > MAX_FRONT_WINDOW_RAD
        ):
            # beyond the drift: an alias (a similar room, the next door along), unless the
            # chain it corrects holds a step the scan could not vouch for (a front-end match
            # gone wrong after a turn, which no drift model foresees and only such a closure
            # can put right) and it scores as a loop within the capped loop window and the
            # front end's widest turn of the estimate
            self.stats["loop_implausible"] += 1
            return
        if result.runner_up >= LOOP_MAX_AMBIGUITY * result.score:
            self.stats["loop_ambiguous"] += 1
            return
        edge = match_edge(found.target, found.k, result, kind="loop")
        if defer:  # a dense target: its score is past loop_min_score here
            self.deferred.append((edge, result.score))
            self.stats["loop_deferred"] += 1
            return
        if result.score < config.loop_min_score or found.wide or beyond or found.following:
            if beyond:
                self.stats["loop_beyond_drift"] += 1
                self.beyond.append(edge)
            self._propose(edge, result.score)
            return
        self.chain.accept_loop(edge, result.score)

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
        poses = self.chain.graph.poses
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
        # by identity: an Edge compares its arrays, and a list's remove compares by equality
        taken = {id(other) for other, _ in agreeing}
        self.pending = [p for p in self.pending if id(p[0]) not in taken]
        for other, other_score in agreeing:
            self.chain.accept_loop(other, other_score)
        self.chain.accept_loop(edge, score)
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
        around the turned estimate and confirm neither; left waiting, the two lose to weak
        closures metres off. Beyond-drift proposals are rarely wrong, and the pairs one scan
        makes were never wrong where measured (docs/decisions.md, "Closures that need a
        second opinion")."""
        beyond = {id(e) for e in self.beyond}
        return (
            a.i != b.i
            and id(a) in beyond
            and id(b) in beyond
            and min(a_score, b_score) >= self.config.loop_min_score
        )

    def settle_deferred(self) -> None:
        """At the end of a visit, the closures against one-sided targets made since the
        last accepted closure: taken when at least two agree, else dropped.

        A revisit of the run's first metres after a long drive (a run that ends just past
        where it began) can only be matched against a map the run frames on one side: the
        scan, truly a little behind where the run began, sees walls beside it the map never
        saw, and slid a metre or two along the corridor onto the map it scores better than
        where it is (taken at once, one such closure lands a metre or more along and the
        capped closures after it follow it). Where the run goes on, a closure framed on both
        sides comes and decides instead, as if these were never made; where it ends, these
        are all there is, and they are right far more often than not (a loop driven a few
        metres past its start ends metres off without them, decimetres with them)."""
        deferred = [(e, s) for e, s in self.deferred if e.j > self.chain.last_closure]
        self.deferred = []
        if len(deferred) < 2:
            return
        poses = self.chain.graph.poses
        best = max(deferred, key=lambda d: d[1])[0]
        agreeing = [(e, s) for e, s in deferred if e is best or self._agree(best, e, poses)]
        if len(agreeing) < 2:
            return
        for edge, score in agreeing:
            self.chain.accept_loop(edge, score)
        self.stats["loop_deferred_taken"] += len(agreeing)
        self.chain.solve_if_needed()

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
            self.submaps.cache.use(sub)
            coarse = sub.coarse(coarse_step) if coarse_step > 1 else None
            return sub.anchor, sub.field, coarse
        poses = self.chain.graph.poses
        last = min(int(self.submaps.index.last_keyframe.max()), k - LOOP_MIN_SEPARATION)
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
        brings nothing better (settle_deferred)."""
        last = min(int(self.submaps.index.last_keyframe.max()), k - LOOP_MIN_SEPARATION)
        visit = self.kf_visit[nearest_kf]
        path = self.clouds.path_m
        lo = hi = nearest_kf
        while lo > 0 and self.kf_visit[lo - 1] == visit and path(lo, nearest_kf) < reach_m:
            lo -= 1
        while hi < last and self.kf_visit[hi + 1] == visit and path(nearest_kf, hi) < reach_m:
            hi += 1
        one_sided = path(lo, nearest_kf) < reach_m or path(nearest_kf, hi) < reach_m
        poses = self.chain.graph.poses
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
