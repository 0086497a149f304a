"""Submaps: a few metres of consecutive keyframes fused into one likelihood field.

A new keyframe is matched against the field of the submap it is driving through rather than
against the previous scan alone: the keyframes of the last metres, seen from different places,
fill the gaps of any one of them (a door the last scan looked past, a turn of 80 degrees that
left little overlap with the scan before). The field lives in the frame of the submap's first
keyframe, its *anchor*, and holds each keyframe where the SLAM placed it relative to the
anchor (Cartographer's local submaps, Hess et al. 2016).

The field is kept, not rebuilt: inserting a keyframe stamps only that keyframe's points. A
finished submap keeps its field, cropped to what it holds, for loop closure, with the pooled
copy the coarse search needs computed once. :class:`SubmapCache` bounds the memory finished
submaps hold: the least recently used give their fields up and stamp them again when a loop
closure asks (a long run has hundreds of submaps, a loop only needs those around it).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray
from baromap.mapping import se2
from baromap.mapping.scan_matcher import LikelihoodField, kernel_radius, stamp

#: A growing field is enlarged by at least this much on a side it outgrows, so a submap
#: driven through grows a handful of times rather than once per keyframe.
GROWTH_M = 8.0


class Submap:
    """A local likelihood field in the frame of keyframe ``anchor``.

    ``surfaces`` are every keyframe's points in its own frame (shared by all submaps of a
    run); the submap keeps which keyframes it holds and where, and can stamp its field again
    from them.
    """

    def __init__(
        self,
        anchor: int,
        floor: int,
        resolution: float,
        sigma: float,
        surfaces: Sequence[FloatArray],
    ) -> None:
        self.anchor = anchor
        self.floor = floor
        self.resolution = resolution
        self.sigma = sigma
        self.keyframes: list[int] = []
        self.local_poses: list[FloatArray] = []
        self.finished = False
        self._surfaces = surfaces
        self._data: npt.NDArray[np.float32] = np.zeros((0, 0), dtype=np.float32)
        self._origin = (0.0, 0.0)
        self._coarse: dict[int, LikelihoodField] = {}
        self._resident = True

    def insert(self, keyframe: int, local_pose: FloatArray) -> None:
        """Add a keyframe seen at ``local_pose`` (in the anchor's frame)."""
        self.keyframes.append(keyframe)
        self.local_poses.append(np.asarray(local_pose, dtype=np.float64).copy())
        self._stamp(keyframe, self.local_poses[-1])
        self._coarse.clear()

    def _stamp(self, keyframe: int, local_pose: FloatArray) -> None:
        points = se2.transform_points(local_pose, self._surfaces[keyframe])
        if len(points) == 0:
            return
        self._fit(points.min(axis=0), points.max(axis=0))
        stamp(self._data, self._origin, self.resolution, self.sigma, points)

    def origins(self) -> FloatArray:
        """Where the keyframes were, in the anchor's frame (K, 2)."""
        return np.array([p[:2] for p in self.local_poses]).reshape(-1, 2)

    def relocate(self, local_poses: Sequence[FloatArray]) -> None:
        """The keyframes moved (the graph was solved): stamp the field again where they are."""
        self.local_poses = [np.asarray(p, dtype=np.float64).copy() for p in local_poses]
        self._restamp()

    def _restamp(self) -> None:
        self._data = np.zeros((0, 0), dtype=np.float32)
        self._coarse.clear()
        for keyframe, pose in zip(self.keyframes, self.local_poses, strict=True):
            self._stamp(keyframe, pose)
        if self.finished:
            self._crop()
        self._resident = True

    def _fit(self, lo: FloatArray, hi: FloatArray) -> None:
        """Grow the grid so [lo, hi] plus a kernel and the zero border fit inside."""
        res = self.resolution
        pad = (kernel_radius(res, self.sigma) + 2) * res
        h, w = self._data.shape
        x0, y0 = self._origin
        if h and w:
            x1, y1 = x0 + (w - 1) * res, y0 + (h - 1) * res
            if lo[0] - pad >= x0 and lo[1] - pad >= y0 and hi[0] + pad <= x1 and hi[1] + pad <= y1:
                return
            grow = GROWTH_M
            nx0 = x0 - grow * math.ceil(max(0.0, x0 - (lo[0] - pad)) / grow)
            ny0 = y0 - grow * math.ceil(max(0.0, y0 - (lo[1] - pad)) / grow)
            nx1 = x1 + grow * math.ceil(max(0.0, hi[0] + pad - x1) / grow)
            ny1 = y1 + grow * math.ceil(max(0.0, hi[1] + pad - y1) / grow)
        else:
            nx0, ny0 = lo[0] - pad - GROWTH_M / 2, lo[1] - pad - GROWTH_M / 2
            nx1, ny1 = hi[0] + pad + GROWTH_M / 2, hi[1] + pad + GROWTH_M / 2
            x0, y0 = nx0, ny0
        col0 = round((nx0 - x0) / res)
        row0 = round((ny0 - y0) / res)
        width = math.ceil((nx1 - nx0) / res) + 1
        height = math.ceil((ny1 - ny0) / res) + 1
        data = np.zeros((height, width), dtype=np.float32)
        if h and w:
            data[-row0 : -row0 + h, -col0 : -col0 + w] = self._data
        self._data = data
        self._origin = (x0 + col0 * res, y0 + row0 * res)

    @property
    def field(self) -> LikelihoodField:
        if not self._resident:
            self._restamp()
        if not self._data.size:
            # keyframes that saw nothing (the laser blinded, or looking into a hall beyond its
            # range): a field of zeros, against which every pose scores nothing, so a match
            # is refused as any poor one is, instead of a lookup in an empty grid
            return LikelihoodField(np.zeros((2, 2), np.float32), self._origin, self.resolution)
        return LikelihoodField(self._data, self._origin, self.resolution)

    def coarse(self, step: int) -> LikelihoodField:
        """The field pooled over ``step`` cells (an upper bound for the coarse search), kept
        until the field changes."""
        cached = self._coarse.get(step)
        if cached is None:
            cached = self.field.pooled(step)
            self._coarse[step] = cached
        return cached

    def finish(self) -> None:
        """No more keyframes: crop the field to what it holds."""
        self.finished = True
        self._crop()

    def _crop(self) -> None:
        if not self._data.size:
            return
        rows = np.flatnonzero(self._data.any(axis=1))
        cols = np.flatnonzero(self._data.any(axis=0))
        if len(rows) == 0:
            return
        r0, r1 = max(rows[0] - 1, 0), min(rows[-1] + 2, self._data.shape[0])
        c0, c1 = max(cols[0] - 1, 0), min(cols[-1] + 2, self._data.shape[1])
        self._data = np.ascontiguousarray(self._data[r0:r1, c0:c1])
        self._origin = (
            self._origin[0] + c0 * self.resolution,
            self._origin[1] + r0 * self.resolution,
        )
        self._coarse.clear()

    @property
    def resident(self) -> bool:
        return self._resident

    def release(self) -> None:
        """Give the field up; it is stamped again when next asked for."""
        self._data = np.zeros((0, 0), dtype=np.float32)
        self._coarse.clear()
        self._resident = False

    def nbytes(self) -> int:
        return int(self._data.nbytes + sum(f.data.nbytes for f in self._coarse.values()))


class SubmapCache:
    """Finished submaps with their fields held up to a memory budget, least recently used
    released first."""

    def __init__(self, budget_bytes: int) -> None:
        self.budget = budget_bytes
        self._held: OrderedDict[int, Submap] = OrderedDict()
        self.releases = 0

    def use(self, sub: Submap) -> Submap:
        """Mark ``sub`` as just used (its field is about to be read), then keep the budget."""
        key = id(sub)
        self._held.pop(key, None)
        self._held[key] = sub
        total = sum(s.nbytes() for s in self._held.values())
        while total > self.budget and len(self._held) > 1:
            _, oldest = self._held.popitem(last=False)
            total -= oldest.nbytes()
            oldest.release()
            self.releases += 1
        return sub
