"""Batch entry point: a whole run's pressure in, floors, transitions and segments out.

Both methods end in the same :class:`FloorDetection`, so the mapping step, the plots and the
evaluation treat them alike. Floor indices are ranked by height, 0 = lowest visited.

The online method's transitions are the live detector's published transitions with their
corrections applied, one for one (the live decisions are what the run is cut by); hindsight
only tightens their time bounds and measures the floors' heights.

Elevations differ by method on purpose: the paper's method takes them from the mean pressure
of each floor's segments (as the paper does, and as drift spoils); the online method's come
from the steps across transitions combined by least squares (:mod:`baromap.floors.elevation`).
"""

from __future__ import annotations

import bisect
import dataclasses
import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from baromap.errors import ConfigError, InputFormatError
from baromap.floors.config import FloorDetectorConfig
from baromap.floors.elevation import (
    STEP_GUARD_AFTER_S,
    STEP_GUARD_S,
    STEP_WINDOW_S,
    Step,
    measure_step,
    solve_levels,
)
from baromap.floors.height import height_difference_m, pressure_drop_pa
from baromap.messages import NS_PER_S, FloorEvent, RideEvent

#: Span next to a transition whose median is the level it left or reached (for sharpening).
SHARPEN_LOCAL_S = 3.0
METHODS: tuple[str, ...] = ("online", "paper")


@dataclass(frozen=True, slots=True)
class Floor:
    """One floor: ``level_pa`` is its pressure referred to the start of the run.

    ``name`` is the live detector's name for it (online method; empty for the paper's).
    """

    index: int
    level_pa: float
    elevation_m: float
    visits: int
    name: str = ""


@dataclass(frozen=True, slots=True)
class Transition:
    """A change of floor. ``t_detect_ns`` is when the method knew (the end, for batch)."""

    t_start_ns: int
    t_end_ns: int
    t_detect_ns: int
    from_floor: int
    to_floor: int
    delta_pa: float
    delta_m: float
    at_end: bool = False


@dataclass(frozen=True, slots=True)
class Segment:
    """A stretch of the run spent on one floor."""

    t_start_ns: int
    t_end_ns: int
    floor: int


@dataclass(frozen=True, slots=True, eq=False)
class FloorDetection:
    method: str
    floors: tuple[Floor, ...]
    transitions: tuple[Transition, ...]
    segments: tuple[Segment, ...]
    t_ns: npt.NDArray[np.int64]
    smoothed_pa: npt.NDArray[np.float64]
    rate_pa_per_s: npt.NDArray[np.float64]
    #: The paper's rate threshold (mean + 2 sigma of the run), for its Figure 4; None online.
    threshold_pa_per_s: float | None = None
    #: What the live detector published while the online method ran (corrections included,
    #: in order): the transitions above are these with the corrections applied. Empty for
    #: the paper's method.
    events: tuple[FloorEvent, ...] = ()
    #: The rides it announced, ended and withdrawn, in order (online method).
    rides: tuple[RideEvent, ...] = ()

    def floor_of(self, t_ns: int) -> int | None:
        """Floor at a time, None between segments (during a transition) or outside the run."""
        starts = [s.t_start_ns for s in self.segments]
        k = bisect.bisect_right(starts, t_ns) - 1
        if k < 0:
            return None
        segment = self.segments[k]
        return segment.floor if t_ns <= segment.t_end_ns else None

    def floor_array(self, t_ns: npt.NDArray[np.int64]) -> npt.NDArray[np.float64]:
        """:meth:`floor_of` for many times at once (NaN for None)."""
        out = np.full(np.shape(t_ns), np.nan)
        for segment in self.segments:
            inside = (t_ns >= segment.t_start_ns) & (t_ns <= segment.t_end_ns)
            out[inside] = segment.floor
        return out

    def to_json(self) -> dict[str, Any]:
        """The JSON of ``baromap detect --json`` (times in seconds of the input's clock)."""

        def s(t: int) -> float:
            return round(t / NS_PER_S, 3)

        return {
            "method": self.method,
            "floors": [
                {
                    "index": f.index,
                    "level_pa": round(f.level_pa, 2),
                    "elevation_m": round(f.elevation_m, 3),
                    "visits": f.visits,
                    "name": f.name,
                }
                for f in self.floors
            ],
            "transitions": [
                {
                    "t_start": s(tr.t_start_ns),
                    "t_end": s(tr.t_end_ns),
                    "t_detect": s(tr.t_detect_ns),
                    "from": tr.from_floor,
                    "to": tr.to_floor,
                    "delta_pa": round(tr.delta_pa, 2),
                    "delta_m": round(tr.delta_m, 3),
                }
                for tr in self.transitions
            ],
            "segments": [
                {"t_start": s(sg.t_start_ns), "t_end": s(sg.t_end_ns), "floor": sg.floor}
                for sg in self.segments
            ],
        }


@dataclass(frozen=True, slots=True)
class _Raw:
    """A transition by floor id, before indices and heights are settled."""

    t_start_ns: int
    t_end_ns: int
    t_detect_ns: int
    from_id: int
    to_id: int
    delta_pa: float
    at_end: bool = False


def detect_floors(
    t_ns: npt.ArrayLike,
    pressure_pa: npt.ArrayLike,
    temperature_c: npt.ArrayLike | None = None,
    *,
    method: str = "online",
    reference: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
    config: FloorDetectorConfig | None = None,
    odometry: tuple[npt.ArrayLike, npt.ArrayLike, npt.ArrayLike] | None = None,
) -> FloorDetection:
    """Detect floors in a whole run.

    ``reference`` is ``(t_ns, pressure_pa)`` of a reference station (a barometer that stays
    put), which removes weather drift when present. ``odometry`` is ``(t_ns, x_m, y_m)`` of
    the robot's odometry (online method: a stop is a visit once the robot drove off). Non-finite
    pressures and repeated stamps are left out, so the result's ``t_ns`` (with ``smoothed_pa``
    and ``rate_pa_per_s``) holds the samples actually used.
    """
    config = config or FloorDetectorConfig()
    if method not in METHODS:
        raise ConfigError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    t = np.asarray(t_ns, dtype=np.int64)
    p = np.asarray(pressure_pa, dtype=np.float64)
    if t.ndim != 1 or t.shape != p.shape:
        raise InputFormatError("time and pressure must be 1-D arrays of equal length")
    temp = (
        np.full(t.shape, np.nan)
        if temperature_c is None
        else np.asarray(temperature_c, dtype=np.float64)
    )
    if temp.shape != t.shape:
        raise InputFormatError("temperature must match the pressure samples")
    # a NaN pressure would turn every smoothed value and every step fit after it into NaN
    keep = np.isfinite(p)
    t, p, temp = t[keep], p[keep], temp[keep]
    if t.size == 0:
        raise InputFormatError("no pressure samples")
    if np.any(np.diff(t) <= 0):
        order = np.argsort(t, kind="stable")
        t, p, temp = t[order], p[order], temp[order]
        keep = np.concatenate(([True], np.diff(t) > 0))
        t, p, temp = t[keep], p[keep], temp[keep]
    run = _Run(t, p, temp, reference)
    if method == "online":
        return _online(run, config, odometry)
    return _paper(run, config)


@dataclass(frozen=True, slots=True, eq=False)
class _Run:
    """A run's clean samples (finite, strictly increasing times) and its reference station."""

    t: npt.NDArray[np.int64]
    p: npt.NDArray[np.float64]
    temp: npt.NDArray[np.float64]
    reference: tuple[npt.ArrayLike, npt.ArrayLike] | None

    def weather_free(self) -> npt.NDArray[np.float64]:
        """The pressure with the reference station's change since its first reading removed
        (as it is when there is no station)."""
        if self.reference is None:
            return self.p
        ref_t = np.asarray(self.reference[0], dtype=np.float64)
        if ref_t.size < 2:
            return self.p
        ref_p = np.asarray(self.reference[1], dtype=np.float64)
        change = np.interp(self.t.astype(np.float64), ref_t, ref_p) - ref_p[0]
        out: npt.NDArray[np.float64] = self.p - change
        return out


def _online(
    run: _Run,
    config: FloorDetectorConfig,
    odometry: tuple[npt.ArrayLike, npt.ArrayLike, npt.ArrayLike] | None,
) -> FloorDetection:
    from baromap.floors.replay import replay

    detector, smoothed, rate = replay(
        run.t, run.p, run.temp, config, reference=run.reference, odometry=odometry
    )
    registry = detector.registry
    # Stable live ids to dense ids (floors merged into others are gone); the start floor is 0.
    dense = {floor_id: k for k, floor_id in enumerate(registry.ids())}
    raw = [
        _Raw(
            ev.t_start_ns,
            ev.t_end_ns,
            ev.t_ns,
            dense[registry.resolve(ev.from_id)],
            dense[registry.resolve(ev.to_id)],
            ev.delta_pa,
            ev.at_end,
        )
        for ev in detector.transitions
    ]
    detection = _assemble(
        "online",
        dataclasses.replace(run, p=run.weather_free()),
        smoothed,
        rate=rate,
        raw=raw,
        n_ids=len(dense),
        config=config,
        names=[registry.name(floor_id) for floor_id in dense],
    )
    return dataclasses.replace(
        detection, events=tuple(detector.events), rides=tuple(detector.rides)
    )


def _paper(run: _Run, config: FloorDetectorConfig) -> FloorDetection:
    from baromap.floors.paper import segment_paper

    run = dataclasses.replace(run, p=run.weather_free())
    t = run.t
    seg = segment_paper(t, run.p, config)
    raw: list[_Raw] = []
    for before, after in itertools.pairwise(seg.pieces):
        t_start, t_end = int(t[before[1] - 1]), int(t[after[0]])
        delta = seg.floor_means[after[2]] - seg.floor_means[before[2]]
        raw.append(_Raw(t_start, t_end, t_end, before[2], after[2], delta))
    levels = np.asarray(seg.floor_means)
    return _assemble(
        "paper",
        run,
        seg.smoothed_pa,
        rate=seg.rate_pa_per_s,
        raw=raw,
        n_ids=len(levels),
        config=config,
        segment_levels=levels,
        threshold_pa_per_s=seg.threshold_pa_per_s,
    )


def _assemble(
    method: str,
    run: _Run,
    smoothed: npt.NDArray[np.float64],
    *,
    rate: npt.NDArray[np.float64],
    raw: Sequence[_Raw],
    n_ids: int,
    config: FloorDetectorConfig,
    segment_levels: npt.NDArray[np.float64] | None = None,
    threshold_pa_per_s: float | None = None,
    names: Sequence[str] | None = None,
) -> FloorDetection:
    t, p, temp = run.t, run.p, run.temp
    valid_temp = temp[np.isfinite(temp)]
    temperature = float(np.median(valid_temp)) if valid_temp.size else config.default_temperature_c
    # Floor visits: the stretches between transitions.
    bounds: list[tuple[int, int, int]] = []
    start = int(t[0])
    first_id = raw[0].from_id if raw else 0
    current = first_id
    for tr in raw:
        bounds.append((start, tr.t_start_ns, current))
        start, current = tr.t_end_ns, tr.to_id
    bounds.append((start, int(t[-1]), current))
    n_ids = max(n_ids, 1)
    if segment_levels is not None:
        # The paper: levels are segment means; heights from those, as the paper does.
        reference_level = segment_levels[first_id]
        relative_pa = segment_levels - reference_level
        heights = np.array(
            [height_difference_m(reference_level, level, temperature) for level in segment_levels]
        )
        base_level = reference_level
    else:
        steps, _ = _steps(t, p, temp, raw, bounds, default_temperature=temperature)
        raw, bounds = _sharpen(t, smoothed, raw, bounds, config=config)
        relative_pa = solve_levels(steps, n_ids, "delta_pa")
        heights = solve_levels(steps, n_ids, "height_m")
        base_level = _level_at_start(t, p, bounds[0])
    order = sorted(range(n_ids), key=lambda i: (heights[i], i))
    index_of = {floor_id: rank for rank, floor_id in enumerate(order)}
    lowest = np.nanmin(heights) if np.isfinite(heights).any() else 0.0
    visits = [0] * n_ids
    for _, _, floor_id in bounds:
        visits[floor_id] += 1
    floors = tuple(
        Floor(
            index=index_of[i],
            level_pa=float(base_level + relative_pa[i]),
            elevation_m=float(heights[i] - lowest),
            visits=visits[i],
            # a run that never settled anywhere knows no floor by name: its one floor has none
            name=names[i] if names is not None and i < len(names) else "",
        )
        for i in order
    )
    transitions = tuple(
        Transition(
            t_start_ns=tr.t_start_ns,
            t_end_ns=tr.t_end_ns,
            t_detect_ns=tr.t_detect_ns,
            from_floor=index_of[tr.from_id],
            to_floor=index_of[tr.to_id],
            delta_pa=float(relative_pa[tr.to_id] - relative_pa[tr.from_id]),
            delta_m=float(heights[tr.to_id] - heights[tr.from_id]),
            at_end=tr.at_end,
        )
        for tr in raw
    )
    segments = tuple(Segment(a, b, index_of[i]) for a, b, i in bounds if b >= a)
    return FloorDetection(
        method, floors, transitions, segments, t, smoothed, rate, threshold_pa_per_s
    )


def _steps(
    t: npt.NDArray[np.int64],
    p: npt.NDArray[np.float64],
    temp: npt.NDArray[np.float64],
    raw: Sequence[_Raw],
    bounds: Sequence[tuple[int, int, int]],
    *,
    default_temperature: float,
) -> tuple[list[Step], list[tuple[float, float]]]:
    """Steps by floor id, and the (before, after) levels each was measured between."""
    window = round(STEP_WINDOW_S * NS_PER_S)
    guard = round(STEP_GUARD_S * NS_PER_S)
    guard_after = round(STEP_GUARD_AFTER_S * NS_PER_S)
    steps = []
    measured = []
    for k, tr in enumerate(raw):
        before_end = max(bounds[k][0], tr.t_start_ns - guard)
        before_start = max(bounds[k][0], before_end - window)
        after_start = min(bounds[k + 1][1], tr.t_end_ns + guard_after)
        after_end = min(bounds[k + 1][1], after_start + window)
        levels = measure_step(t, p, (before_start, before_end), (after_start, after_end), temp)
        if levels is None:
            level_before = float(np.interp(tr.t_start_ns, t, p))
            levels = (level_before, level_before + tr.delta_pa)
        measured.append(levels)
        delta = levels[1] - levels[0]
        i0, i1 = np.searchsorted(t, (before_start, after_end))
        local = temp[i0:i1]
        local = local[np.isfinite(local)]
        temperature = float(np.median(local)) if local.size else default_temperature
        steps.append(
            Step(
                tr.from_id, tr.to_id, delta, height_difference_m(levels[0], levels[1], temperature)
            )
        )
    return steps, measured


def _sharpen(
    t: npt.NDArray[np.int64],
    smoothed: npt.NDArray[np.float64],
    raw: Sequence[_Raw],
    bounds: Sequence[tuple[int, int, int]],
    *,
    config: FloorDetectorConfig,
) -> tuple[list[_Raw], list[tuple[int, int, int]]]:
    """Tighten each transition to where the pressure actually left and reached the floors.

    The online detector dates a change causally: its start is the last calm moment it saw and
    its end the start of the quiet stretch that confirmed it, which on a walker's jittery
    phone can be seconds late. With the whole run at hand, the transition is where the
    smoothed pressure is more than ``start_m`` away from both floors' levels. Decision times
    are kept as they were.
    """
    out_raw: list[_Raw] = []
    out_bounds = list(bounds)
    local = round(SHARPEN_LOCAL_S * NS_PER_S)
    for k, tr in enumerate(raw):
        lo, hi = np.searchsorted(t, (out_bounds[k][0], bounds[k + 1][1]))
        i0, i1 = np.searchsorted(t, (tr.t_start_ns, tr.t_end_ns))
        i1 = max(min(i1, hi - 1), i0 + 1)
        # Levels right next to the change (not the drift-corrected fit, which extrapolates).
        b0 = np.searchsorted(t, tr.t_start_ns - local)
        a1 = np.searchsorted(t, tr.t_end_ns + local)
        before = float(np.median(smoothed[max(b0, lo) : i0 + 1]))
        after = float(np.median(smoothed[i1 : max(a1, i1 + 1)]))
        margin = pressure_drop_pa(config.start_m, before, config.default_temperature_c)
        away = np.abs(smoothed[i0:i1] - before) > margin
        left = np.flatnonzero(away)
        if left.size == 0:
            out_raw.append(tr)
            continue
        start = i0 + int(left[0])
        arrived = np.flatnonzero(np.abs(smoothed[start:hi] - after) <= margin)
        end = start + int(arrived[0]) if arrived.size else i1
        t_start = int(t[max(start - 1, lo)])
        t_end = max(int(t[min(end, hi - 1)]), t_start)
        out_raw.append(dataclasses.replace(tr, t_start_ns=t_start, t_end_ns=t_end))
        out_bounds[k] = (out_bounds[k][0], t_start, out_bounds[k][2])
        out_bounds[k + 1] = (t_end, out_bounds[k + 1][1], out_bounds[k + 1][2])
    return out_raw, out_bounds


def _level_at_start(
    t: npt.NDArray[np.int64], p: npt.NDArray[np.float64], first: tuple[int, int, int]
) -> float:
    """Pressure of the first floor near the start of the run."""
    i0, i1 = np.searchsorted(t, (first[0], min(first[1], first[0] + 10 * NS_PER_S)))
    return float(p[i0 : max(i1, i0 + 1)].mean())
