"""A run's laser scans as arrays, in the robot frame, ready for matching and ray casting.

The whole run is held as one block of ranges (S, B) so that ray casting and point extraction
vectorise over scans; scans with another beam count than the first (a sensor reconfigured
mid-run) are resampled by index, which never happens on one robot but keeps the arrays square.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray
from baromap.mapping import se2
from baromap.messages import LaserScan, usable_beams


@dataclass(frozen=True, slots=True)
class ScanBlock:
    """Ranges of S scans of B beams; NaN where a beam has no usable range."""

    t_ns: npt.NDArray[np.int64]
    ranges_m: npt.NDArray[np.float32]  # (S, B)
    angles_rad: FloatArray  # (B,)
    range_max_m: float
    laser_offset: FloatArray  # (3,) laser pose in the robot frame

    def __len__(self) -> int:
        return int(self.ranges_m.shape[0])

    @classmethod
    def from_messages(
        cls, scans: list[LaserScan], laser_offset: FloatArray | None = None
    ) -> ScanBlock:
        offset = np.zeros(3) if laser_offset is None else np.asarray(laser_offset, np.float64)
        if not scans:
            return cls(
                np.zeros(0, np.int64), np.zeros((0, 1), np.float32), np.zeros(1), 0.0, offset
            )
        first = scans[0]
        beams = first.beam_count
        if all(scan.beam_count == beams for scan in scans):
            # one sensor setting all run long (always, on one robot): validity in one pass
            ranges = np.stack([scan.ranges_m for scan in scans])
            flags = np.stack([scan.flags for scan in scans])
            block = np.where(usable_beams(ranges, flags), ranges, np.float32(np.nan))
        else:
            block = np.full((len(scans), beams), np.nan, dtype=np.float32)
            for k, scan in enumerate(scans):
                one = np.where(scan.valid(), scan.ranges_m, np.float32(np.nan))
                if scan.beam_count != beams:
                    one = one[np.linspace(0, scan.beam_count - 1, beams).round().astype(int)]
                block[k] = one
        return cls(
            t_ns=np.array([s.t_ns for s in scans], dtype=np.int64),
            ranges_m=block,
            angles_rad=first.angles_rad(),
            range_max_m=float(first.range_max_m),
            laser_offset=offset,
        )

    def subset(self, indices: npt.NDArray[np.int64]) -> ScanBlock:
        """The scans ``indices`` only (a copy: small enough to send to another process)."""
        return ScanBlock(
            self.t_ns[indices],
            self.ranges_m[indices],
            self.angles_rad,
            self.range_max_m,
            self.laser_offset,
        )

    def surface(self, index: int, max_range_m: float, spacing: float) -> FloatArray:
        """:func:`surface_points` of one scan in the robot frame."""
        pts = surface_points(self.ranges_m[index], self.angles_rad, max_range_m, spacing)
        return se2.transform_points(self.laser_offset, pts)

    def sampled_endpoints(
        self, indices: npt.NDArray[np.int64], max_range_m: float, beams: int
    ) -> tuple[FloatArray, npt.NDArray[np.int64]]:
        """About ``beams`` evenly spread endpoints of each of many scans, in the robot frame,
        and the position in ``indices`` of the scan each came from (vectorised over scans)."""
        stride = max(1, -(-self.ranges_m.shape[1] // beams))
        r = self.ranges_m[indices, ::stride].astype(np.float64)
        ang = self.angles_rad[::stride]
        ok = np.isfinite(r) & (r > 0.05) & (r <= max_range_m)
        owner = np.nonzero(ok)[0].astype(np.int64)
        rr, aa = r[ok], np.broadcast_to(ang, r.shape)[ok]
        pts = np.stack([rr * np.cos(aa), rr * np.sin(aa)], axis=1)
        return se2.transform_points(self.laser_offset, pts), owner

    def endpoints(self, index: int, max_range_m: float) -> FloatArray:
        """Beam endpoints (N, 2) of one scan in the robot frame, up to ``max_range_m``."""
        r = self.ranges_m[index].astype(np.float64)
        ok = np.isfinite(r) & (r > 0.05) & (r <= max_range_m)
        ang = self.angles_rad[ok]
        pts = np.stack([r[ok] * np.cos(ang), r[ok] * np.sin(ang)], axis=1)
        return se2.transform_points(self.laser_offset, pts)


#: Two neighbouring beams' endpoints are one surface when they are at most this many times
#: their spacing at normal incidence apart (a wall seen at up to about 80 degrees of
#: incidence), and at most this far apart in any case.
SURFACE_GAP_FACTOR = 3.0
SURFACE_MAX_GAP_M = 1.0
FILL_ABOVE_SPACINGS = 2.0


def surface_points(
    ranges_m: npt.NDArray[np.floating], angles_rad: FloatArray, max_range_m: float, spacing: float
) -> FloatArray:
    """Points every ``spacing`` along what one scan saw, in the scanner's frame.

    A far wall returns one endpoint every range x beam step (35 cm at 20 m with 1 degree
    beams): a likelihood field stamped with those endpoints alone has gaps a matched point
    falls into, and the field of a sparse scan scores a correct pose poorly. Neighbouring
    endpoints close enough to lie on one surface are joined by a segment, sampled finely;
    a depth jump (an object before a wall) is not joined.
    """
    r = np.asarray(ranges_m, dtype=np.float64)
    ok = np.isfinite(r) & (r > 0.05) & (r <= max_range_m)
    x, y = r * np.cos(angles_rad), r * np.sin(angles_rad)
    ends = np.stack([x[ok], y[ok]], axis=1)
    if len(r) < 2:
        return ends
    step = float(np.median(np.abs(np.diff(angles_rad))))
    both = ok[:-1] & ok[1:]
    gap = np.hypot(np.diff(x), np.diff(y))
    near = np.minimum(r[:-1], r[1:])
    joined = both & (gap <= np.minimum(SURFACE_MAX_GAP_M, SURFACE_GAP_FACTOR * near * step))
    joined &= gap > 2 * spacing * FILL_ABOVE_SPACINGS
    first = np.flatnonzero(joined)
    counts = np.ceil(gap[first] / spacing).astype(np.int64) - 1  # inner samples
    counts = np.maximum(counts, 0)
    if counts.sum() == 0:
        return ends
    seg = np.repeat(first, counts)
    k = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    t = (k + 1) / np.repeat(counts + 1, counts)
    inner = np.stack(
        [x[seg] + t * (x[seg + 1] - x[seg]), y[seg] + t * (y[seg + 1] - y[seg])], axis=1
    )
    return np.concatenate([ends, inner])


def voxel_filter(points: FloatArray, size: float) -> FloatArray:
    """One point per ``size`` square (their mean): even density for the matcher's score."""
    if len(points) == 0:
        return points
    cells = np.floor(points / size).astype(np.int64)
    cells -= cells.min(axis=0)
    keys = cells[:, 0] * (int(cells[:, 1].max()) + 1) + cells[:, 1]
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    sums = np.stack(
        [np.bincount(inverse, weights=points[:, c], minlength=len(counts)) for c in (0, 1)], 1
    )
    filtered: FloatArray = sums / counts[:, None]
    return filtered
