"""Which scans of a run carry weight: one every so much motion.

The same rule picks SLAM's keyframes (from odometry, per floor visit) and the scans a floor's
occupancy grid is built from (from the corrected trajectory, per floor): a robot standing
still repeats the same evidence, and one that moves on leaves a new view behind.
"""

from __future__ import annotations

import math

import numpy as np

from baromap.arrays import FloatArray, IntArray


def motion_spaced(
    poses: FloatArray, group: IntArray, min_m: float, min_rad: float, *, last_of_group: bool
) -> IntArray:
    """Indices where a pose has moved ``min_m`` or turned ``min_rad`` since the last chosen
    pose of its group.

    Poses whose group is negative are skipped; a group's first pose is always chosen, and with
    ``last_of_group`` its last one too (the two ends of a floor visit are the robot in the
    elevator car, the scans that join the floors). A group is a run of equal values: a floor
    visited twice is two groups when the visits are numbered, one when the floors are.
    """
    xs, ys, ths = (poses[:, c].tolist() for c in range(3))
    groups = np.asarray(group).tolist()
    chosen: list[int] = []
    last_index = -1
    last_group = None
    for s, g in enumerate(groups):
        if g < 0:
            continue
        if g != last_group:
            if last_of_group and last_index >= 0 and chosen[-1] != last_index:
                chosen.append(last_index)
            chosen.append(s)
            anchor = s
            last_group = g
        else:
            moved = math.hypot(xs[s] - xs[anchor], ys[s] - ys[anchor])
            turned = abs(math.remainder(ths[s] - ths[anchor], math.tau))
            if moved >= min_m or turned >= min_rad:
                chosen.append(s)
                anchor = s
        last_index = s
    if last_of_group and last_index >= 0 and chosen[-1] != last_index:
        chosen.append(last_index)
    return np.array(chosen, dtype=np.int64)
