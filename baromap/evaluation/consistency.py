"""Revisit moves: how far each scan's pose would have to move to lie on its revisit partners,
in metres and degrees (the score itself, :mod:`baromap.mapping.revisits`, is a truncated
mean that the SLAM uses as well)."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from baromap.arrays import FloatArray, IntArray
from baromap.evaluation.trajectory import fit_rigid
from baromap.mapping import se2
from baromap.mapping.revisits import (
    TRUNCATE_M,
    ScanGeometry,
    partner_cloud,
)

#: Rounds of the alignment in :func:`revisit_corrections`: point to outline pairs found again
#: each round. Point to point slides slowly along a corridor (a ring bent by 0.48 deg a lap
#: settled in 10 rounds for 1 of 192 scans, in 30 for all); a scan that has not settled by
#: then counts as beyond reach.
CORRECTION_ROUNDS = 50
#: ... and at least this many of the scan's query points paired, for the move to count: a
#: fifth of QUERY_BEAMS, a wall and a corner's worth.
MIN_ALIGNED = 18


def revisit_corrections(
    geometry: ScanGeometry,
    poses: FloatArray,
    partners: list[IntArray],
    *,
    truncate_m: float = TRUNCATE_M,
) -> FloatArray:
    """For each scan, how far its pose would have to move to lie on its partners: (N, 3)
    distance [m], turn [rad] and share of its points then within ``truncate_m`` (NaN where
    the scan has no partner; distance and turn infinite where the alignment found too little
    in common to settle, MIN_ALIGNED points: the scan lies beyond its reach, a misplacement
    of decimetres at least, not a move of none).

    The score in metres and degrees rather than a truncated mean: each scan is aligned
    (point to outline, the outline sampled finely, pairs beyond ``truncate_m`` left out) to
    its partners placed by ``poses``, which stay where the trajectory put them. Under the
    true poses a revisit needs no move but the scans' own noise; a trajectory that closed a
    loop some centimetres off shows them here, at the scans of the revisit.
    """
    p = np.asarray(poses, dtype=np.float64)
    out = np.full((geometry.count, 3), np.nan)
    for i, mates in enumerate(partners):
        query = geometry.queries[i]
        if len(mates) == 0 or len(query) < 3:
            continue
        cloud = partner_cloud(geometry, p, mates)
        if len(cloud) < 3:
            continue
        tree = cKDTree(cloud)
        pose = p[i].copy()
        settled = False
        for _ in range(CORRECTION_ROUNDS):
            moved = se2.transform_points(pose, query)
            dist, idx = tree.query(moved, k=1)
            near = dist < truncate_m
            if np.count_nonzero(near) < MIN_ALIGNED:
                break
            step = fit_rigid(moved[near], cloud[idx[near]])
            pose = se2.compose(step, pose)
            if np.hypot(step[0], step[1]) < 1e-4 and abs(step[2]) < 1e-5:
                settled = True
                break
        near = tree.query(se2.transform_points(pose, query), k=1)[0] < truncate_m
        if not settled or np.count_nonzero(near) < MIN_ALIGNED:
            out[i] = (math.inf, math.inf, float(np.mean(near)))
            continue
        out[i] = (
            float(np.hypot(*(pose[:2] - p[i, :2]))),
            abs(float(se2.wrap(pose[2] - p[i, 2]))),
            float(np.mean(near)),
        )
    return out
