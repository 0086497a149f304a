"""The last solve, once every keyframe is in: odometry weighed as the run taught it,
doubtful matches given robust kernels, every kind of edge scaled to its scatter, and each
floor's keyframes refined against the map of the others."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
import structlog

from baromap.arrays import FloatArray, IntArray
from baromap.mapping import se2
from baromap.mapping.odometry_calibration import NOISE_OUTLIER_SIGMAS, OdometryNoise
from baromap.mapping.pose_graph import Edge, PoseGraph
from baromap.mapping.refine import concatenate, refine_batch
from baromap.mapping.slam.car import ElevatorCar
from baromap.mapping.slam.measurement import (
    diagonal_information,
    edge_covariance,
    finished_map_field,
    match_information,
    rotate_information,
)
from baromap.mapping.slam.settings import (
    FINAL_ITERATIONS,
    LOOP_ROBUST_C,
    MATCH_SIGMA_M,
    MATCH_SIGMA_RAD,
    MIN_SCATTER_EDGES,
    REFINE_ODOMETRY_INFLATION,
    REFINE_ODOMETRY_ROBUST,
    REFINE_PASSES,
    SCATTER_KINDS,
)
from baromap.mapping.slam.state import Chain, Keyframes, OdometryLearning, SlamPart, graph_of

log = structlog.get_logger(__name__)


@dataclass(frozen=True, slots=True)
class _MapFits:
    """Keyframes' poses as fitted to their floor's map, with each fit's information."""

    nodes: IntArray
    poses: FloatArray
    information: FloatArray


class FinalSolve(SlamPart):
    """The solves after the run (the car's core edges tie the floors there), on the chain's
    graph, which it replaces as it re-weighs the edges."""

    def __init__(
        self,
        keyframes: Keyframes,
        chain: Chain,
        odometry: OdometryLearning,
        car: ElevatorCar,
        stats: Counter[str],
    ) -> None:
        super().__init__(keyframes, chain, stats)
        self.odometry = odometry
        self.calibration = odometry.calibration
        self.car = car

    def solve(self, silent_steps: set[int]) -> None:
        """Odometry as the run taught it, doubtful matches doubted, every kind of edge
        weighed by its scatter, then the refinement against each floor's map.
        ``silent_steps``: the keyframes reached by a step the fitted noise does not
        describe (see :meth:`_odometry_as_learnt`)."""
        noise = self.odometry.fit_noise()
        self._odometry_as_learnt(noise, 1.0, silent_steps)
        if noise is not None:
            self._doubt_matches_beyond(noise)
        self.chain.graph.optimize(iterations=FINAL_ITERATIONS)
        if self._weigh_by_scatter():
            self.chain.graph.optimize(iterations=FINAL_ITERATIONS)
        if REFINE_PASSES:
            self._odometry_as_learnt(
                noise, REFINE_ODOMETRY_INFLATION, silent_steps, robust=REFINE_ODOMETRY_ROBUST
            )
        for _ in range(REFINE_PASSES):
            self._refine()

    def _odometry_as_learnt(
        self,
        noise: OdometryNoise | None,
        inflation: float,
        silent_steps: set[int],
        *,
        robust: bool = False,
    ) -> None:
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
        outside them (the simulated run's is 6 m and 19 degrees off, a hundred sigmas of the
        fit): weighed by the fit, that one edge holds every floor after it against the car.

        ``robust``: the fitted edges get the loop closures' Cauchy kernel. In the refinement
        the map fits place every keyframe, and a step the wheels misread by decimetres (a
        slip, a bump), far beyond the fitted noise, would pull its neighbours off the map as
        plain least squares; with the kernel it yields to the fits, while a step within a
        few sigmas (every step along a corridor, where only odometry measures the travel)
        weighs as before (docs/decisions.md, "Odometry yields to the map in the refinement").
        """
        edges = self.chain.graph.edges
        for e in edges:
            if e.kind != "odometry":
                continue
            read = self.keyframes.odometry_step(e.i, e.j)
            e.z = self.calibration.correct(read)
            if noise is not None and e.j not in silent_steps:
                sigma_xy, sigma_theta = noise.sigmas(math.hypot(read[0], read[1]), read[2])
                e.information = diagonal_information(inflation * sigma_xy, inflation * sigma_theta)
                if robust:
                    e.robust_c = LOOP_ROBUST_C
        self.chain.graph = graph_of(self.chain.graph.poses, edges)

    def _doubt_matches_beyond(self, noise: OdometryNoise) -> None:
        """Front-end matches that put a step further from corrected odometry than the noise
        the run showed allows get a robust kernel in the last solve, as loop closures have.

        A front-end match edge is plain least squares: the front end trusts its own matches,
        and along a sparse log's corridors and after its turns of 100-170 degrees that trust
        is where a map goes wrong. On the worst sparse runs, step by step against GMapping's
        relative pose of the two scans, the wrong keyframes are taken 0.5-1 m along a
        corridor (the next door along) or turned by 10-20 degrees where corrected odometry
        is 0.03-0.15 m and 1-5 degrees off; the next keyframe's match, against the submap,
        puts the robot back, so two match edges hold the wrong pose in place against two
        odometry edges, and no closure can move it. Given the reference's steps in place of
        those matches, such runs come out within a decimetre: those matches are what is left.

        A match is doubted when it and corrected odometry disagree by more than both can be
        wrong together: the miss weighed by the match's own covariance plus odometry's noise
        as fitted to the matched steps (:func:`fit_noise`), beyond NOISE_OUTLIER_SIGMAS (where
        that fit itself counts a step as a wrong match). Odometry's noise alone is not the
        test: a calibrated base's is millimetres a step, and by it matches a few centimetres
        along a corridor, where the match itself is weak, are doubted and the map bends. A
        doubted edge keeps its weight while the graph agrees with it
        and yields to odometry and the closures where they disagree; where match and
        odometry agree, the chain stays as stiff as plain least squares holds it.

        What it does not mend: the keyframes after a wrong match are matched against a submap
        that holds it and move with it as one piece, and the graph starts where the front end
        left them, at the doubted edges' own solution; where odometry's noise is several
        degrees (a turn) a Cauchy edge's pull, fading only as one over its residual, keeps
        them there (keyframes can stay turned by degrees). Leaving the doubted edges out of
        the solve mends that, but turns a floor of the simulated building by a tenth of a
        degree (docs/decisions.md, "Doubt a match that odometry contradicts").
        """
        edges = self.chain.graph.edges
        doubted = 0
        for e in edges:
            if e.kind != "match":
                continue
            read = self.keyframes.odometry_step(e.i, e.j)
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
        self.chain.graph = graph_of(self.chain.graph.poses, edges)

    def _weigh_by_scatter(self) -> bool:
        """Each kind of edge weighed by how it actually scatters against the solved graph.

        The information of a match is its fit's Gauss-Newton curvature inflated and floored
        (MATCH_COV_SCALE, MATCH_SIGMA_M, LOOP_SIGMA_M...): a guess at how far the shared
        errors of neighbouring beams spread it, made once for the front end's matches, loop
        closures and the car alike. Against the solved graph they show a sixth to a thirtieth
        of the variance they claim (median), and not one factor for all: in one run the kinds
        differ by up to five times, and one kind by several times between the runs of
        different robots. Every kind with enough edges to say is
        scaled to its median scatter and the graph solved again, so the kinds weigh against
        each other as the run shows, the way odometry's noise is fitted to the matched steps
        (:func:`fit_noise`). The robust kernels' scale is in sigmas, so a closure that
        disagrees is now judged against the closures' real spread. The median of each kind's
        residuals, not a full variance-component estimate: edges that decide their own nodes
        show less than their error, and a kind is only scaled once. Returns whether any was.
        """
        factors = {}
        for kind in SCATTER_KINDS:
            count, scatter = self.chain.graph.scatter(kind)
            if count >= MIN_SCATTER_EDGES and scatter > 0:
                self.chain.graph.scale_information(kind, 1.0 / scatter)
                factors[kind] = round(scatter, 3)
        log.info("edges weighed by their scatter", **factors)
        return bool(factors)

    def _refine(self) -> None:
        """Each floor's keyframes against the map of the others (see refine.py), in a graph of
        odometry, the elevator edges and the core; match and loop edges have had their say."""
        poses = self.chain.graph.poses.copy()
        fits = self._map_fits(poses)
        # odometry as the whole run taught it (see _odometry_as_learnt)
        kept = [e for e in self.chain.graph.edges if e.kind in ("odometry", "ride", "car")]
        kept += self.car.core_edges(poses)
        if len(np.unique(self.kf_floor)) > 1:
            self.chain.graph = self._solve_with_floor_frames(poses, kept, fits)
        else:  # one floor: nothing to turn it against, the fits hold it where it is
            graph = graph_of(poses, kept)
            graph.set_priors(fits.nodes, fits.poses, fits.information)
            # the fits are poses in the map's frame, so they fix the frame themselves: pinning
            # the first keyframe where the graph solve left it as well (the solver's usual
            # anchor) would keep the run's start off its own map, the place a run comes back
            # to at its end (pinned, the first scan lies several times further from its
            # revisits than free)
            graph.optimize(iterations=FINAL_ITERATIONS, anchor=None if len(fits.nodes) else 0)
            self.chain.graph = graph
        self.stats["refined"] = len(fits.nodes)

    def _map_fits(self, poses: FloatArray) -> _MapFits:
        """Each floor's keyframes (at ``poses``) fitted to the map of the others of their
        floor: the keyframes of one parity against a map of the other's."""
        config = self.config
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
                fld = finished_map_field(world, config.resolution_m)
                points, owner = concatenate([self.clouds.points[k] for k in mine])
                out = refine_batch(fld, points, owner, poses[mine])
                info = np.array(
                    [match_information(h, MATCH_SIGMA_M, MATCH_SIGMA_RAD) for h in out.information]
                )
                nodes.append(mine[out.usable])
                measured.append(out.poses[out.usable])
                infos.append(info[out.usable])
        return _MapFits(
            np.concatenate(nodes) if nodes else np.zeros(0, dtype=np.int64),
            np.concatenate(measured) if nodes else np.zeros((0, 3)),
            np.concatenate(infos) if nodes else np.zeros((0, 3, 3)),
        )

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
        graph = graph_of(poses, edges)
        frames = {int(f): graph.add_node(np.zeros(3)) for f in np.unique(self.kf_floor)}
        owner = np.array([frames[int(f)] for f in self.kf_floor[fits.nodes]], dtype=np.int64)
        for k, frame, z, info in zip(fits.nodes, owner, fits.poses, fits.information, strict=True):
            graph.add_edge(
                Edge(int(frame), int(k), z.copy(), rotate_information(info, z[2]), "map")
            )
        graph.optimize(iterations=FINAL_ITERATIONS)
        solved = graph.poses
        # the graph handed on: keyframes only, the fits as priors where their floors went
        final = graph_of(solved[:count], edges)
        if len(fits.nodes):
            moved = solved[owner]
            infos = np.array(
                [
                    rotate_information(i, -t)
                    for i, t in zip(fits.information, moved[:, 2], strict=True)
                ]
            )
            final.set_priors(fits.nodes, se2.compose(moved, fits.poses), infos)
        return final
