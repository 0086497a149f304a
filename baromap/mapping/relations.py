"""The relation metric of Kuemmerle et al. 2009 ("On measuring the accuracy of SLAM algorithms").

A map cannot be compared with ground truth directly, so the metric compares relative motions:
for each reference relation (t1, t2, motion from the pose at t1 to the pose at t2 in t1's frame),
the estimate's own relative motion between the same two instants is compared with it, and the
translational and rotational parts of the difference are averaged. Relations whose ends are not
both among the estimated poses cannot be scored and are counted as unused.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baromap.arrays import FloatArray, IntArray
from baromap.errors import InputFormatError
from baromap.mapping import se2
from baromap.recording.carmen import parse_time_ns

#: Two stamps closer than this are the same instant. The published Intel relations were made
#: from a differently rounded copy of the log: two of their stamps sit 0.78 ms from the scan
#: they refer to, the next-nearest non-matching stamps 0.94 ms. 0.8 ms recovers exactly the
#: 92 usable relations (and GMapping's 0.036 m / 0.51 deg) the dataset's README quotes.
MATCH_TOLERANCE_NS = 800_000


@dataclass(frozen=True, slots=True)
class Relations:
    t1_ns: IntArray
    t2_ns: IntArray
    motion: FloatArray  # (N, 3): x, y, yaw


@dataclass(frozen=True, slots=True)
class RelationErrors:
    used: int
    unused: int
    trans_m: FloatArray
    rot_deg: FloatArray

    @property
    def trans_mean(self) -> float:
        return float(np.mean(self.trans_m)) if self.used else float("nan")

    @property
    def trans_std(self) -> float:
        return float(np.std(self.trans_m)) if self.used else float("nan")

    @property
    def rot_mean(self) -> float:
        return float(np.mean(self.rot_deg)) if self.used else float("nan")

    @property
    def rot_std(self) -> float:
        return float(np.std(self.rot_deg)) if self.used else float("nan")

    def summary(self) -> str:
        return (
            f"{self.trans_mean:.4f} +- {self.trans_std:.4f} m, "
            f"{self.rot_mean:.3f} +- {self.rot_std:.3f} deg over {self.used} relations"
        )


def read_relations(path: str | Path) -> Relations:
    """Read ``t1 t2 x y z roll pitch yaw`` lines."""
    t1: list[int] = []
    t2: list[int] = []
    motion: list[tuple[float, float, float]] = []
    with Path(path).open(encoding="ascii") as handle:
        for number, line in enumerate(handle, 1):
            tokens = line.split()
            if not tokens or tokens[0].startswith("#"):
                continue
            if len(tokens) < 8:
                raise InputFormatError(f"{path}:{number}: expected 8 fields, got {len(tokens)}")
            try:
                t1.append(parse_time_ns(tokens[0]))
                t2.append(parse_time_ns(tokens[1]))
                motion.append((float(tokens[2]), float(tokens[3]), float(tokens[7])))
            except ValueError as exc:
                raise InputFormatError(f"{path}:{number}: {exc}") from exc
    return Relations(
        np.array(t1, dtype=np.int64),
        np.array(t2, dtype=np.int64),
        np.array(motion, dtype=np.float64).reshape(-1, 3),
    )


def _lookup(times_ns: IntArray, query: IntArray) -> IntArray:
    """Index of each query stamp among sorted ``times_ns``, or -1 when absent."""
    if len(times_ns) == 0:
        return np.full(len(query), -1, dtype=np.int64)
    pos = np.clip(np.searchsorted(times_ns, query), 1, len(times_ns) - 1)
    left, right = times_ns[pos - 1], times_ns[pos]
    pick = np.where(np.abs(query - left) <= np.abs(right - query), pos - 1, pos)
    if len(times_ns) == 1:
        pick = np.zeros(len(query), dtype=np.int64)
    ok = np.abs(times_ns[pick] - query) <= MATCH_TOLERANCE_NS
    return np.where(ok, pick, -1).astype(np.int64)


def relation_pairs(
    times_ns: IntArray, relations: Relations
) -> tuple[IntArray, IntArray, FloatArray, int]:
    """The relations whose both ends are among the sorted stamps ``times_ns``: the index of
    each end, the relation's motion, and how many relations were left out."""
    times = np.asarray(times_ns, dtype=np.int64)
    i1 = _lookup(times, relations.t1_ns)
    i2 = _lookup(times, relations.t2_ns)
    usable = (i1 >= 0) & (i2 >= 0)
    return i1[usable], i2[usable], relations.motion[usable], int((~usable).sum())


def relation_errors(times_ns: IntArray, poses: FloatArray, relations: Relations) -> RelationErrors:
    """Score poses (N, 3) at sorted stamps ``times_ns`` against the relations.

    The error of one relation is the motion that takes the reference relative pose to the
    estimated one, ``(-)ref (+) est``: its length is the translational error and its angle the
    rotational error, as in the metric's reference implementation.
    """
    order = np.argsort(times_ns, kind="stable")
    times = np.asarray(times_ns, dtype=np.int64)[order]
    sorted_poses = np.asarray(poses, dtype=np.float64)[order]
    i1, i2, motion, unused = relation_pairs(times, relations)
    estimated = se2.between(sorted_poses[i1], sorted_poses[i2])
    error = se2.between(motion, estimated)
    return RelationErrors(
        used=len(i1),
        unused=unused,
        trans_m=np.hypot(error[:, 0], error[:, 1]),
        rot_deg=np.degrees(np.abs(error[:, 2])),
    )
