"""Scoring a floor detection against ground truth.

Truth is a list of true transitions, each a *window* ``[t_begin, t_end]`` during which the
change happened between two known floors, plus the true floor as a step function (None while
in transition or unknown).

- Simulator truth: the window is exactly the ride (``/truth/floor`` is None while riding).
- IPIN waypoints: the walker was on floor a at waypoint i and on floor b at waypoint i+1, so
  the change happened somewhere in between; the window is the span between the two
  waypoints. Outside the first and last waypoint nothing is known and nothing is scored
  per sample (transitions detected there still count as false).

Matching, one to one in time order: a detected transition matches a true one when its
interval ``[t_start, t_end]`` overlaps the true window widened by ``tolerance_s`` (the
smoothing and the start estimate blur the edges by a second or two), and, when
``max_delay_s`` is given, it was decided no later than that after the window ended. The
post-run segmentation is scored without that limit: when the live detector decided is a
figure of its own (a visit is decided once the robot drove off or stayed long enough).
Everything unmatched is missed or false.

Direction and storey count compare ``to - from`` of the detected indices (ranked by height
over the floors the run visited) with the true floor numbers. Per-sample accuracy aligns the
detected indices to the true floor numbers by the one constant offset that fits best (a
detector cannot know that the lowest floor it saw is called -2). Delay is decision time minus
the end of the true window: for IPIN the window ends at the next waypoint, after the real end
of the stairs, so those delays are lower bounds.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from baromap.errors import InputFormatError
from baromap.floors.detection import FloorDetection, Transition
from baromap.messages import NS_PER_S

TOLERANCE_S = 2.0


@dataclass(frozen=True, slots=True)
class TrueTransition:
    """A floor change the truth knows of, somewhere in ``[t_begin_ns, t_end_ns]``."""

    t_begin_ns: int
    t_end_ns: int
    #: True floor numbers (the simulator's, or the IPIN waypoints').
    from_floor: int
    to_floor: int
    #: When the air pressure itself came to rest afterwards (simulator only).
    t_settled_ns: int | None = None


@dataclass(frozen=True, slots=True, eq=False)
class FloorTruth:
    """True transitions and the true floor at given times (NaN = in transition/unknown)."""

    transitions: tuple[TrueTransition, ...]
    t_ns: npt.NDArray[np.int64]
    floor: npt.NDArray[np.float64]
    heights_m: dict[int, float] | None = None

    def floor_at(self, t_ns: npt.NDArray[np.int64]) -> npt.NDArray[np.float64]:
        """Step function: the truth holding at each time (NaN outside the known span)."""
        k = np.searchsorted(self.t_ns, t_ns, side="right") - 1
        out = np.where(k >= 0, self.floor[np.clip(k, 0, None)], np.nan)
        out[(t_ns > self.t_ns[-1]) | (t_ns < self.t_ns[0])] = np.nan
        return out


def truth_from_waypoints(waypoints: Sequence[tuple[int, int]]) -> FloorTruth:
    """Truth from ``(t_ns, floor)`` waypoints (IPIN ``POSI`` lines)."""
    points = sorted(waypoints)
    if not points:
        raise InputFormatError("no waypoints to take the truth from")
    transitions = []
    times = []
    floors = []
    for (t0, f0), (t1, f1) in itertools.pairwise(points):
        times.append(t0)
        if f0 == f1:
            floors.append(float(f0))
        else:
            floors.append(np.nan)
            transitions.append(TrueTransition(t0, t1, f0, f1))
    times.append(points[-1][0])
    floors.append(float(points[-1][1]))
    return FloorTruth(
        tuple(transitions), np.asarray(times, dtype=np.int64), np.asarray(floors, dtype=float)
    )


def truth_from_series(
    t_ns: npt.ArrayLike, floor: npt.ArrayLike, z_m: npt.ArrayLike | None = None
) -> FloorTruth:
    """Truth from a sampled true floor (NaN while between floors), e.g. ``/truth/floor``.

    A stretch in between that starts and ends on the same floor is no transition; the true
    height of each floor is the median of ``z_m`` over its samples when given.
    """
    t = np.asarray(t_ns, dtype=np.int64)
    f = np.asarray(floor, dtype=np.float64)
    known = np.flatnonzero(np.isfinite(f))
    transitions = []
    for a, b in itertools.pairwise(known):
        if f[a] != f[b]:
            transitions.append(TrueTransition(int(t[a]), int(t[b]), int(f[a]), int(f[b])))
    heights = None
    if z_m is not None:
        z = np.asarray(z_m, dtype=np.float64)
        heights = {int(k): float(np.median(z[f == k])) for k in np.unique(f[known])}
    return FloorTruth(tuple(transitions), t, f, heights)


class _Counted(Protocol):
    @property
    def true(self) -> int: ...
    @property
    def found(self) -> int: ...
    @property
    def false(self) -> int: ...


class DetectionRates:
    """Recall and precision of whatever counts true, found and false transitions: one case's
    :class:`Score`, or scores summed over many."""

    __slots__ = ()

    @property
    def recall(self: _Counted) -> float:
        """Share of the true transitions found; 1 where there was none to find."""
        return self.found / self.true if self.true else 1.0

    @property
    def precision(self: _Counted) -> float:
        """Share of the detections that were true; 1 where nothing was detected."""
        detected = self.found + self.false
        return self.found / detected if detected else 1.0


@dataclass(frozen=True, slots=True)
class Score(DetectionRates):
    true: int
    found: int
    missed: int
    false: int
    direction_right: int
    storeys_right: int
    accuracy: float
    offset: int
    delays_s: tuple[float, ...]
    height_error_m: float | None
    flushed: int
    settled_delays_s: tuple[float, ...] = ()

    @property
    def median_delay_s(self) -> float:
        return float(np.median(self.delays_s)) if self.delays_s else float("nan")

    @property
    def max_delay_s(self) -> float:
        return float(np.max(self.delays_s)) if self.delays_s else float("nan")


def match(
    detection: FloorDetection,
    truth: FloorTruth,
    tolerance_s: float = TOLERANCE_S,
    max_delay_s: float | None = None,
) -> list[tuple[TrueTransition, Transition]]:
    """The detected transitions matched to the true ones (see the module docstring), as
    ``(true, detected)`` pairs in the truth's order; the unmatched are left out."""
    tol = round(tolerance_s * NS_PER_S)
    late = None if max_delay_s is None else round(max_delay_s * NS_PER_S)
    detected = detection.transitions
    used = [False] * len(detected)
    matches = []
    for true in truth.transitions:
        for j, det in enumerate(detected):
            if used[j]:
                continue
            overlaps = (
                det.t_start_ns <= true.t_end_ns + tol and det.t_end_ns >= true.t_begin_ns - tol
            )
            if overlaps and (late is None or det.t_detect_ns <= true.t_end_ns + late):
                used[j] = True
                matches.append((true, det))
                break
    return matches


def score(
    detection: FloorDetection,
    truth: FloorTruth,
    tolerance_s: float = TOLERANCE_S,
    max_delay_s: float | None = None,
) -> Score:
    detected = detection.transitions
    matches = match(detection, truth, tolerance_s, max_delay_s)
    direction = sum(
        1
        for true, det in matches
        if np.sign(det.to_floor - det.from_floor) == np.sign(true.to_floor - true.from_floor)
    )
    storeys = sum(
        1
        for true, det in matches
        if det.to_floor - det.from_floor == true.to_floor - true.from_floor
    )
    delays = tuple((det.t_detect_ns - true.t_end_ns) / NS_PER_S for true, det in matches)
    settled = tuple(
        (det.t_detect_ns - true.t_settled_ns) / NS_PER_S
        for true, det in matches
        if true.t_settled_ns is not None
    )
    accuracy, offset = _accuracy(detection, truth)
    height_error = _height_error(detection, truth, offset)
    return Score(
        true=len(truth.transitions),
        found=len(matches),
        missed=len(truth.transitions) - len(matches),
        false=len(detected) - len(matches),
        direction_right=direction,
        storeys_right=storeys,
        accuracy=accuracy,
        offset=offset,
        delays_s=delays,
        height_error_m=height_error,
        flushed=sum(1 for _, det in matches if det.at_end),
        settled_delays_s=settled,
    )


#: "At rest" for the air pressure: within this of its later course (0.1 m of height).
SETTLED_BAND_PA = 1.2
#: How long after a ride the settling is looked for, and how much of its end defines "later".
SETTLE_SEARCH_S = 30.0
SETTLE_TAIL_S = 10.0


def with_settle_times(
    truth: FloorTruth, t_ns: npt.NDArray[np.int64], true_pressure_pa: npt.NDArray[np.float64]
) -> FloorTruth:
    """Add when the noise-free pressure settled after each true transition.

    The car stopping is not the pressure settling: the doors are still shut (the car is
    slightly pressurised) and ventilation spikes fade over a second or two after they open.
    ``true_pressure_pa`` should be free of weather and of any sensor (the simulator's
    noise-free pressure at the robot minus its noise-free pressure at the reference station:
    gusts, about 1.5 Pa RMS, would otherwise hide any settling, and a sensor's noise would
    push the settle late and so flatter the delay). Settled is the first moment from which it
    stays within
    ``SETTLED_BAND_PA`` of a line fitted to its last ``SETTLE_TAIL_S`` (the weather keeps
    drifting) up to ``SETTLE_SEARCH_S`` after the stop, or the next transition.
    """
    out = []
    for k, true in enumerate(truth.transitions):
        limit = true.t_end_ns + round(SETTLE_SEARCH_S * NS_PER_S)
        if k + 1 < len(truth.transitions):
            limit = min(limit, truth.transitions[k + 1].t_begin_ns)
        limit = min(limit, int(t_ns[-1]) + 1)  # the data may end sooner
        i0, i1 = np.searchsorted(t_ns, (true.t_end_ns, limit))
        j0 = np.searchsorted(t_ns, limit - round(SETTLE_TAIL_S * NS_PER_S))
        if i1 - i0 < 3 or i1 - j0 < 3:
            out.append(true)
            continue
        tail_t = (t_ns[j0:i1] - t_ns[i0]) / NS_PER_S
        slope, intercept = np.polyfit(tail_t, true_pressure_pa[j0:i1], 1)
        course = intercept + slope * (t_ns[i0:i1] - t_ns[i0]) / NS_PER_S
        outside = np.flatnonzero(np.abs(true_pressure_pa[i0:i1] - course) > SETTLED_BAND_PA)
        settled = true.t_end_ns
        if outside.size:  # the sample after the last one outside the band (if any is left)
            settled = int(t_ns[min(i0 + int(outside[-1]) + 1, i1 - 1)])
        out.append(dataclasses.replace(true, t_settled_ns=settled))
    return dataclasses.replace(truth, transitions=tuple(out))


def _accuracy(detection: FloorDetection, truth: FloorTruth) -> tuple[float, int]:
    t = detection.t_ns
    true_floor = truth.floor_at(t)
    scored = np.isfinite(true_floor)
    if not scored.any():
        return float("nan"), 0
    found = detection.floor_array(t)[scored]
    expected = true_floor[scored]
    offsets = (expected - found)[np.isfinite(found)]
    if offsets.size == 0:
        return 0.0, 0
    values, counts = np.unique(offsets, return_counts=True)
    offset = int(values[np.argmax(counts)])
    return float(np.mean(found + offset == expected)), offset


def _height_error(detection: FloorDetection, truth: FloorTruth, offset: int) -> float | None:
    """Largest error of floor elevations relative to the lowest floor both know."""
    if truth.heights_m is None:
        return None
    pairs = [
        (floor.elevation_m, truth.heights_m[floor.index + offset])
        for floor in detection.floors
        if floor.index + offset in truth.heights_m
    ]
    if len(pairs) < 2:
        return None
    found = np.array([a for a, _ in pairs])
    true = np.array([b for _, b in pairs])
    base = int(np.argmin(true))
    return float(np.max(np.abs((found - found[base]) - (true - true[base]))))
