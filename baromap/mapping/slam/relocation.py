"""After a step across the odometry's silence with no motion measured (a power-cycled
base), the chain looks for its place in the map of its floor from before the gap."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import structlog

from baromap.arrays import FloatArray
from baromap.mapping import se2
from baromap.mapping.occupancy import OccupancyGrid, build_grid
from baromap.mapping.scan_matcher import LikelihoodField, SearchWindow, match
from baromap.mapping.scans import voxel_filter
from baromap.mapping.slam.measurement import match_edge, same_shift
from baromap.mapping.slam.settings import (
    CAR_FAR_ANGLE_STEP_RAD,
    LOOP_MAX_AMBIGUITY,
    RELOCATE_BUDGET,
    RELOCATE_EVERY_M,
    RELOCATE_FREE_CELL_M,
    RELOCATE_FREE_PENALTY,
    RELOCATE_MAX_M,
    RELOCATE_MIN_POINTS,
    RELOCATE_MIN_SCORE,
    RELOCATE_NEAR_WALL,
    RELOCATE_RECENT_M,
    RELOCATE_TRIES,
    RELOCATE_VIEW_M,
    WINDOW_SIGMAS,
)
from baromap.mapping.slam.state import Chain, Keyframes, Lost, SlamPart

log = structlog.get_logger(__name__)


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


class Relocation(SlamPart):
    """Finding the chain again after an unmeasured step. It owns the search while the chain
    looks for its place (:class:`Lost`)."""

    def __init__(self, keyframes: Keyframes, chain: Chain, stats: Counter[str]) -> None:
        super().__init__(keyframes, chain, stats)
        #: the chain after a step across the odometry's silence, until it finds its place
        self.lost: Lost | None = None

    def start(self, k: int, sigma_xy: float, sigma_theta: float) -> None:
        """Keyframe k comes after a step the odometry did not measure: the chain looks for
        its place from here (:meth:`_lost_at`), in place of any search still going on."""
        self.lost = self._lost_at(k, sigma_xy, sigma_theta)

    def give_up(self) -> None:
        """The visit ended before the chain found its place: the car ties the floors after
        the ride."""
        if self.lost is not None:
            log.info("the chain did not find its place after the odometry's silence")
            self.stats["relocate_failed"] += 1
            self.lost = None

    def _lost_at(self, k: int, sigma_xy: float, sigma_theta: float) -> Lost | None:
        """The search for keyframe k's place after a step across the odometry's silence
        (RELOCATE_*): the map of its floor from before, near enough to be seen from where
        the step may have taken it; None when there is no such map."""
        poses = self.chain.graph.poses
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
            self.keyframes.scans,
            self.keyframes.kf_scan[seen],
            poses[seen],
            resolution=RELOCATE_FREE_CELL_M,
        )
        fld = _free_space_costs(LikelihoodField.from_points(local, res, res), poses[before], grid)
        return Lost(before, k, window, fld)

    def relocate(self, k: int) -> None:
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
        if lost is None:
            return
        travelled = float(self.clouds.distance[k])
        if k != lost.start and travelled - lost.tried_at < RELOCATE_EVERY_M:
            return
        if lost.tried >= RELOCATE_TRIES:
            return
        lost.tried += 1
        lost.tried_at = travelled
        poses = self.chain.graph.poses
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
        agrees = any(same_shift(shift, other) for other in lost.found)
        lost.found.append(shift)
        if not agrees:
            return
        was = poses[start].copy()
        poses[start:] = se2.compose(shift, poses[start:])
        moved = se2.between(was, poses[start])
        self.chain.accept_loop(match_edge(lost.before, start, result, kind="loop"), result.score)
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
