"""Which floor each scan was taken on, from the barometer.

The cut is recomputed from the whole recorded pressure series (``baromap.floors.detect_floors``)
rather than taken from the live /floor/event messages, whose floor indices can shift while the
run goes on (a newly found lower floor renumbers the others): the recomputation sees the whole
run, can use a reference station and the finished floor identities, and its default method
("online", the daemon's detector replayed) takes floor heights from the steps across
transitions, which weather drift does not spoil.

Scans inside a transition (the elevator moving) belong to no floor: they are
neither mapped nor used for loop closure, only their odometry joins the floors. A run without
a barometer (a public laser log) is one floor.

A *visit* is one uninterrupted stay on a floor; the SLAM front end never matches a new visit
against the previous one's submap (that is the floor it just left); only the closed car
before and after a ride is matched across the boundary.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from baromap.mapping.slam import BETWEEN_FLOORS

IntArray = npt.NDArray[np.int64]

#: Fewest pressure samples worth running a detector on.
MIN_PRESSURE_SAMPLES = 10

#: Scans this close to a detected transition belong to no floor. A car slows over its last
#: metre or so, and that tail of the pressure change is easily dated a second or two early;
#: the robot is in the closed car then, so these scans add nothing to a floor's map, and
#: keeping them out of loop closure keeps a scan taken between floors from being paired.
TRANSITION_GUARD_S = 3.0


@dataclass(frozen=True, slots=True)
class FloorInfo:
    index: int
    elevation_m: float
    level_pa: float | None
    visits: int


@dataclass(frozen=True, slots=True)
class Segmentation:
    scan_floor: IntArray  # floor index per scan, BETWEEN_FLOORS inside transitions
    scan_visit: IntArray  # visit number per scan (-1 inside transitions)
    floors: tuple[FloorInfo, ...]
    source: str
    detection: Any = field(default=None, repr=False)  # FloorDetection, for the figure


def single_floor(n_scans: int, source: str = "no barometer: one floor") -> Segmentation:
    return Segmentation(
        scan_floor=np.zeros(n_scans, dtype=np.int64),
        scan_visit=np.zeros(n_scans, dtype=np.int64),
        floors=(FloorInfo(0, 0.0, None, 1),),
        source=source,
    )


def label_scans(
    scan_t_ns: IntArray,
    segments: list[tuple[int, int, int]],
    guard_s: float = TRANSITION_GUARD_S,
) -> tuple[IntArray, IntArray]:
    """Floor and visit of each scan from (t_start_ns, t_end_ns, floor) segments in time order.

    Scans before the first segment belong to it, scans after the last to the last (the robot
    was on a floor before the barometer's first sample); scans between two segments, or
    within ``guard_s`` of their ends there, are in a transition.
    """
    floor = np.full(len(scan_t_ns), BETWEEN_FLOORS, dtype=np.int64)
    visit = np.full(len(scan_t_ns), -1, dtype=np.int64)
    if not segments:
        return np.zeros_like(floor), np.zeros_like(visit)
    guard = round(guard_s * 1e9)
    for k, (t0, t1, f) in enumerate(segments):
        lo = -np.inf if k == 0 else t0 + guard
        hi = np.inf if k == len(segments) - 1 else t1 - guard
        inside = (scan_t_ns >= lo) & (scan_t_ns <= hi)
        floor[inside] = f
        visit[inside] = k
    return floor, visit


def segment_run(
    scan_t_ns: IntArray,
    pressure_t_ns: IntArray,
    pressure_pa: npt.NDArray[np.float64],
    temperature_c: npt.NDArray[np.float64] | None = None,
    *,
    method: str = "online",
    reference: tuple[IntArray, npt.NDArray[np.float64]] | None = None,
) -> Segmentation:
    """Offline floor segmentation of a run's scans.

    ``reference`` is a fixed reference barometer's series (removes weather drift) when the
    run recorded one.
    """
    if len(pressure_t_ns) < MIN_PRESSURE_SAMPLES:
        return single_floor(len(scan_t_ns))
    from baromap.floors import detect_floors

    temps = None
    if temperature_c is not None and np.isfinite(temperature_c).all():
        temps = temperature_c
    if reference is not None and len(reference[0]) < MIN_PRESSURE_SAMPLES:
        reference = None
    detection = detect_floors(pressure_t_ns, pressure_pa, temps, method=method, reference=reference)
    segments = [(int(s.t_start_ns), int(s.t_end_ns), int(s.floor)) for s in detection.segments]
    floor, visit = label_scans(scan_t_ns, segments)
    floors = tuple(
        FloorInfo(int(f.index), float(f.elevation_m), float(f.level_pa), int(f.visits))
        for f in detection.floors
    )
    return Segmentation(floor, visit, floors, f"barometer ({method})", detection)
