"""How well a trajectory agrees with its own scans where the robot came back: a score that
needs no reference, so the SLAM can use it to choose between runs of itself
(:mod:`baromap.mapping.restarts`) and the bench to judge trajectories whose
reference is itself an estimate.

The public logs' absolute trajectory error is measured against GMapping's poses, an estimate
itself; where there are no ground-truth relations nothing says whether a disagreement with
it is our error or GMapping's. The scans say it: a wall seen twice must lie
in one place under the right poses.

Choices, and why:

- Revisits only. Each scan is compared with scans taken near it (within its own median range
  of it, facing within ``max_turn_deg``) after the robot had driven at least ``min_travel_m``
  away and back. Near is relative to what the scan sees: moved by less than the typical
  distance to its walls, most of a view is shared; in a corridor (median range about 2 m)
  that is a metre or two, in a convention hall (6.5 m) several metres, where a fixed 2 m
  finds revisits for a few scans in a hundred.
  Consecutive scans agree under any trajectory a scan matcher produced, because the matcher
  made them agree; what the absolute error is made of (a corridor bent, a loop closed off by
  some centimetres) shows only where a place is seen again after a long way round.
- The same pairs for every trajectory compared. Which scans are partners is decided once,
  from one trajectory (the bench uses the reference's poses; any good estimate chooses nearly
  the same places) and the distance travelled along it, so two trajectories are scored on
  exactly the same comparisons and neither chooses the pairs that flatter it.
- Point to surface, not point to point. A scan's endpoints are compared with the partners'
  outlines (neighbouring endpoints on one surface joined and sampled every ``spacing_m``,
  :func:`baromap.mapping.scans.surface_points`), not with their endpoints: a far wall seen
  with 1 degree beams carries an endpoint every 35 cm at 20 m, and point to point distances
  there measure the beam spacing, not the poses.
- Distances truncated at ``TRUNCATE_M`` (0.2 m), then averaged, per scan and then over scans.
  A scan sees parts its partners never saw (a door open this time, the far side of a hall):
  such a point's distance is large under every trajectory and counts 0.2 m whatever its
  size, the same offset for all trajectories compared. The disagreements in question (the
  ATE against GMapping is 0.06-0.14 m) count in full below 0.2 m, and two different surfaces
  are rarely that close. Not a median per scan: a scan overlapping its partners by less than
  half would score its non-overlap, and on a log of narrow corridors those scans make most
  of the mean over scans (several times what the median scan scores); nor a median over
  scans, which hides a trajectory misplaced in one part of the building (one with twice the
  relations' error of the others scores as well as they do).

It measures self-consistency, not truth: a trajectory bent smoothly between two revisits, or
along a corridor seen once, is as consistent as a straight one. Whether it ranks trajectories
as the ground truth does has to be checked on the logs that have relations
(``bench/consistency.py``).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from baromap.arrays import FloatArray, IntArray
from baromap.mapping import se2
from baromap.mapping.scans import ScanBlock, surface_points

#: A revisit: at least this much driving between the two scans. A loop of a few rooms; any
#: shorter and the two scans are neighbours the matcher aligned with each other directly.
MIN_TRAVEL_M = 10.0
#: ... with the two scan poses within the scan's median range of each other (most of both
#: views overlap), but at least this ...
MIN_RADIUS_M = 1.0
#: ... and facing within this of each other (a 180 degree scanner's views overlap).
MAX_TURN_DEG = 60.0
#: At most this many partners per scan, the nearest: a revisit is seen by a few scans; more
#: only costs time.
MAX_PARTNERS = 6
#: The partners' outlines are sampled this finely: distances below it are not resolved.
SPACING_M = 0.02
#: Beams beyond this are left out (far returns graze and scatter). The range the measure is
#: validated at (against the ground-truth relations), so its figures stay comparable.
MAX_RANGE_M = 20.0
#: A scan's points used as queries, spread evenly over its beams.
QUERY_BEAMS = 90
#: A point's distance counts at most this much (see the module's docstring).
TRUNCATE_M = 0.2


@dataclass(frozen=True, slots=True)
class Consistency:
    """Per-scan revisit consistency of one trajectory (NaN: the scan has no partner)."""

    #: mean over the scan's points of their distance to the partners' outlines, each
    #: truncated at TRUNCATE_M
    per_scan_m: FloatArray
    #: the share of the scan's points within that distance of the partners' outlines
    overlap: FloatArray

    @property
    def scored(self) -> int:
        return int(np.count_nonzero(np.isfinite(self.per_scan_m)))

    @property
    def mean_m(self) -> float:
        """Mean over scored scans: the trajectory's score (lower is more consistent)."""
        return self.mean_over(np.ones(len(self.per_scan_m), dtype=bool))

    @property
    def overlap_mean(self) -> float:
        ok = np.isfinite(self.overlap)
        return float(np.mean(self.overlap[ok])) if ok.any() else math.nan

    def mean_over(self, scans: npt.NDArray[np.bool_]) -> float:
        """The same mean over the scans selected by ``scans`` only (a stretch of the run)."""
        ok = np.isfinite(self.per_scan_m) & scans
        return float(np.mean(self.per_scan_m[ok])) if ok.any() else math.nan


def travel_m(poses: FloatArray) -> FloatArray:
    """Distance driven from the first pose to each pose, along ``poses`` (N, 3)."""
    steps = np.hypot(np.diff(poses[:, 0]), np.diff(poses[:, 1]))
    return np.concatenate([[0.0], np.cumsum(steps)])


def revisit_partners(
    poses: FloatArray,
    radius_m: FloatArray,
    *,
    min_travel_m: float = MIN_TRAVEL_M,
    max_turn_deg: float = MAX_TURN_DEG,
    max_partners: int = MAX_PARTNERS,
    group: IntArray | None = None,
) -> list[IntArray]:
    """For each scan, the scans that revisit its place along ``poses`` (within ``radius_m``
    of it, one radius per scan: :attr:`ScanGeometry.radius_m`), nearest first.

    Decided once and then used for every trajectory scored, so all are compared on the same
    pairs. ``min_travel_m`` of 0 gives the neighbours as well (a local measure). ``group``
    (one per scan) keeps partners within a scan's own group: a building's floors share
    coordinates, not walls; a scan of a negative group (on no floor) has none.
    """
    p = np.asarray(poses, dtype=np.float64)
    travel = travel_m(p)
    groups = None if group is None else np.asarray(group, dtype=np.int64)
    radii = np.broadcast_to(np.asarray(radius_m, dtype=np.float64), (len(p),))
    tree = cKDTree(p[:, :2])
    turn = math.radians(max_turn_deg)
    partners: list[IntArray] = []
    for i, near in enumerate(tree.query_ball_point(p[:, :2], radii)):
        cand = np.asarray(near, dtype=np.int64)
        cand = cand[np.abs(travel[cand] - travel[i]) >= max(min_travel_m, 1e-9)]
        cand = cand[np.abs(se2.wrap(p[cand, 2] - p[i, 2])) <= turn]
        if groups is not None:
            cand = cand[groups[cand] == groups[i]] if groups[i] >= 0 else cand[:0]
        if len(cand) > max_partners:
            d = np.hypot(p[cand, 0] - p[i, 0], p[cand, 1] - p[i, 1])
            cand = cand[np.argsort(d, kind="stable")[:max_partners]]
        partners.append(cand)
    return partners


class ScanGeometry:
    """A log's scans prepared once for scoring many trajectories: each scan's query points
    and its outline, in the robot frame."""

    def __init__(
        self,
        scans: ScanBlock,
        *,
        max_range_m: float = MAX_RANGE_M,
        spacing_m: float = SPACING_M,
        query_beams: int = QUERY_BEAMS,
    ) -> None:
        self.count = len(scans)
        r = scans.ranges_m.astype(np.float64)
        seen = np.where(np.isfinite(r) & (r <= max_range_m), r, np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a scan with no return: NaN
            median = np.nanmedian(seen, axis=1) if seen.shape[1] else np.full(self.count, np.nan)
        #: how near another scan has to be to share most of this one's view
        self.radius_m = np.maximum(np.nan_to_num(median, nan=0.0), MIN_RADIUS_M)
        self.outlines = [
            se2.transform_points(
                scans.laser_offset,
                surface_points(scans.ranges_m[k], scans.angles_rad, max_range_m, spacing_m),
            )
            for k in range(self.count)
        ]
        points, owner = scans.sampled_endpoints(
            np.arange(self.count, dtype=np.int64), max_range_m, query_beams
        )
        order = np.argsort(owner, kind="stable")
        bounds = np.searchsorted(owner[order], np.arange(self.count + 1))
        self.queries = [points[order[bounds[k] : bounds[k + 1]]] for k in range(self.count)]


def partner_cloud(geometry: ScanGeometry, poses: FloatArray, mates: IntArray) -> FloatArray:
    """The partners' outlines, each placed by its pose: what a scan is held against."""
    return np.concatenate([se2.transform_points(poses[j], geometry.outlines[j]) for j in mates])


def consistency(
    geometry: ScanGeometry,
    poses: FloatArray,
    partners: list[IntArray],
    *,
    truncate_m: float = TRUNCATE_M,
) -> Consistency:
    """Each scan's truncated mean distance to its partners' outlines, all placed by ``poses``."""
    p = np.asarray(poses, dtype=np.float64)
    if len(p) != geometry.count or len(partners) != geometry.count:
        raise ValueError(f"{len(p)} poses, {len(partners)} partner lists for {geometry.count}")
    out = np.full(geometry.count, np.nan)
    overlap = np.full(geometry.count, np.nan)
    for i, mates in enumerate(partners):
        query = geometry.queries[i]
        if len(mates) == 0 or len(query) == 0:
            continue
        cloud = partner_cloud(geometry, p, mates)
        if len(cloud) == 0:
            continue
        dist, _ = cKDTree(cloud).query(se2.transform_points(p[i], query), k=1)
        out[i] = float(np.mean(np.minimum(dist, truncate_m)))
        overlap[i] = float(np.mean(dist < truncate_m))
    return Consistency(per_scan_m=out, overlap=overlap)
