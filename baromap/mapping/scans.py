"""A run's laser scans as arrays, in the robot frame, ready for matching and ray casting.

The whole run is held as one block of ranges (S, B) so that ray casting and point extraction
vectorise over scans; scans with another beam count than the first (a sensor reconfigured
mid-run) are resampled by index, which never happens on one robot but keeps the arrays square.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from baromap.mapping import se2
from baromap.messages import LaserScan

FloatArray = npt.NDArray[np.float64]


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
        block = np.full((len(scans), beams), np.nan, dtype=np.float32)
        for k, scan in enumerate(scans):
            ranges = np.where(scan.valid(), scan.ranges_m, np.float32(np.nan))
            if scan.beam_count != beams:
                ranges = ranges[np.linspace(0, scan.beam_count - 1, beams).round().astype(int)]
            block[k] = ranges
        return cls(
            t_ns=np.array([s.t_ns for s in scans], dtype=np.int64),
            ranges_m=block,
            angles_rad=first.angles_rad(),
            range_max_m=float(first.range_max_m),
            laser_offset=offset,
        )

    def endpoints(self, index: int, max_range_m: float) -> FloatArray:
        """Beam endpoints (N, 2) of one scan in the robot frame, up to ``max_range_m``."""
        r = self.ranges_m[index].astype(np.float64)
        ok = np.isfinite(r) & (r > 0.05) & (r <= max_range_m)
        ang = self.angles_rad[ok]
        pts = np.stack([r[ok] * np.cos(ang), r[ok] * np.sin(ang)], axis=1)
        return se2.transform_points(self.laser_offset, pts)


def voxel_filter(points: FloatArray, size: float) -> FloatArray:
    """One point per ``size`` square (their mean): even density for the matcher's score."""
    if len(points) == 0:
        return points
    keys = np.floor(points / size).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(counts), 2))
    np.add.at(sums, inverse, points)
    filtered: FloatArray = sums / counts[:, None]
    return filtered
