"""The baseline: batch floor segmentation as in Ozkil et al., "Mapping of Multi-Floor Buildings:
A Barometric Approach".

The paper smooths the whole run with double exponential smoothing, calls every sample whose
rate of change ``|b|`` exceeds ``mean(|b|) + 2 sigma(|b|)`` (statistics over the whole run)
part of a transition, cuts the run into segments between transitions, and gives each segment
the mean of its pressure; floors, and their elevations, come from those segment means.

Two things the paper leaves open are filled in generously here, so that the comparison is
with the method and not with a strawman: segments whose means lie within the minimum
transition height of a known floor's mean are that floor (the nearest), and adjacent segments
on the same floor are merged, so a spike between two pieces of the same floor is no event.

Where it must fail, and why (figures in docs/results.md): the threshold is relative to
the run's own statistics, so in a long run that is mostly still it sits at the noise level and
every gust or ventilation spike crosses it, while the mean of a segment drifts with the
weather (1.5 hPa/h is one storey in 15-20 minutes), so a revisited floor lands on another
floor's mean, or on none.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from baromap.floors.config import FloorDetectorConfig
from baromap.floors.height import pressure_drop_pa
from baromap.floors.smoothing import double_exponential_smoothing
from baromap.messages import NS_PER_S


@dataclass(frozen=True, slots=True, eq=False)
class PaperSegmentation:
    """Output of the paper's method, by floor id in order of discovery.

    ``pieces`` are ``(i_start, i_end, floor_id)`` sample index ranges (end exclusive) of the
    merged segments; what lies between two pieces is a transition. ``floor_means`` is each
    floor's mean pressure over all its samples (the paper's floor level).
    """

    smoothed_pa: npt.NDArray[np.float64]
    rate_pa_per_s: npt.NDArray[np.float64]
    threshold_pa_per_s: float
    pieces: tuple[tuple[int, int, int], ...]
    floor_means: tuple[float, ...]


def segment_paper(
    t_ns: npt.NDArray[np.int64],
    pressure_pa: npt.NDArray[np.float64],
    config: FloorDetectorConfig,
) -> PaperSegmentation:
    p = np.asarray(pressure_pa, dtype=np.float64)
    smoothed, trend = double_exponential_smoothing(p, config.paper_alpha, config.paper_gamma)
    n = p.size
    dt = float(np.median(np.diff(t_ns))) / NS_PER_S if n > 1 else 1.0
    rate = trend / dt
    if n < 3:
        pieces = ((0, n, 0),) if n else ()
        return PaperSegmentation(smoothed, rate, np.inf, pieces, (float(p.mean()),) if n else ())
    magnitude = np.abs(trend)
    threshold = float(magnitude.mean() + config.paper_sigmas * magnitude.std())
    moving = magnitude > threshold
    # Segments: maximal runs of samples that are not moving.
    still = np.concatenate(([False], ~moving, [False])).view(np.int8)
    starts = np.flatnonzero(np.diff(still) == 1)
    ends = np.flatnonzero(np.diff(still) == -1)
    tolerance = pressure_drop_pa(
        config.min_transition_m, float(np.median(p)), config.default_temperature_c
    )
    means: list[float] = []
    sums: list[float] = []
    counts: list[int] = []
    raw: list[tuple[int, int, int]] = []
    for i0, i1 in zip(starts.tolist(), ends.tolist(), strict=True):
        mean = float(p[i0:i1].mean())
        distances = [abs(m - mean) for m in means]
        if distances and min(distances) < tolerance:
            floor = int(np.argmin(distances))
        else:
            floor = len(means)
            means.append(mean)
            sums.append(0.0)
            counts.append(0)
        sums[floor] += float(p[i0:i1].sum())
        counts[floor] += i1 - i0
        means[floor] = sums[floor] / counts[floor]
        raw.append((i0, i1, floor))
    merged: list[tuple[int, int, int]] = []
    for piece in raw:
        if merged and merged[-1][2] == piece[2]:
            merged[-1] = (merged[-1][0], piece[1], piece[2])
        else:
            merged.append(piece)
    return PaperSegmentation(smoothed, rate, threshold / dt, tuple(merged), tuple(means))
