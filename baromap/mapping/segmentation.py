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

from baromap.arrays import BoolArray, FloatArray, IntArray
from baromap.mapping import se2
from baromap.mapping.slam import BETWEEN_FLOORS

#: Fewest pressure samples worth running a detector on.
MIN_PRESSURE_SAMPLES = 10

#: Scans this close to a detected transition belong to no floor. A car slows over its last
#: metre or so, and that tail of the pressure change is easily dated a second or two early;
#: the robot is in the closed car then, so these scans add nothing to a floor's map, and
#: keeping them out of loop closure keeps a scan taken between floors from being paired.
#: The guard never reaches a scan the robot moved at (:func:`label_scans`), so it holds
#: whatever the recording's time scale.
TRANSITION_GUARD_S = 3.0
#: An odometry step below this (m, and rad) between two scans is a robot standing still:
#: wheel encoders at rest report the same pose, a robot driving at 1 cm/s moves more.
STILL_STEP = 1e-4


@dataclass(frozen=True, slots=True)
class FloorInfo:
    index: int
    elevation_m: float
    level_pa: float | None
    visits: int
    #: the live detector's name for the floor (online method), else ``"floor <index>"``
    name: str = ""

    @property
    def label(self) -> str:
        return self.name or f"floor {self.index}"


@dataclass(frozen=True, slots=True)
class Ride:
    """A change of floor as the detector dated it (recording clock, Unix ns for a run)."""

    t_start_ns: int
    t_end_ns: int
    from_floor: int
    to_floor: int


@dataclass(frozen=True, slots=True)
class Segmentation:
    scan_floor: IntArray  # floor index per scan, BETWEEN_FLOORS inside transitions
    scan_visit: IntArray  # visit number per scan (-1 inside transitions)
    floors: tuple[FloorInfo, ...]
    source: str
    detection: Any = field(default=None, repr=False)  # FloorDetection, for the figure
    rides: tuple[Ride, ...] = ()


def single_floor(n_scans: int, source: str = "no barometer: one floor") -> Segmentation:
    return Segmentation(
        scan_floor=np.zeros(n_scans, dtype=np.int64),
        scan_visit=np.zeros(n_scans, dtype=np.int64),
        floors=(FloorInfo(0, 0.0, None, 1),),
        source=source,
    )


def moving_scans(scan_odom: FloatArray) -> BoolArray:
    """Whether the robot's odometry moved since the scan before (the first scan: as the next)."""
    if len(scan_odom) < 2:
        return np.zeros(len(scan_odom), dtype=bool)
    step = np.diff(scan_odom, axis=0)
    turn = np.abs(se2.wrap(step[:, 2]))
    moved = (np.hypot(step[:, 0], step[:, 1]) > STILL_STEP) | (turn > STILL_STEP)
    return np.concatenate([moved[:1], moved])


def label_scans(
    scan_t_ns: IntArray,
    segments: list[tuple[int, int, int]],
    guard_s: float = TRANSITION_GUARD_S,
    moving: BoolArray | None = None,
) -> tuple[IntArray, IntArray]:
    """Floor and visit of each scan from (t_start_ns, t_end_ns, floor) segments in time order.

    Scans before the first segment belong to it, scans after the last to the last (the robot
    was on a floor before the barometer's first sample); scans between two segments, or
    within ``guard_s`` of their ends there, are in a transition.

    ``moving`` (per scan) bounds the guard: a robot that drives is not riding, so the guard
    ends at the last scan it moved at before a transition and the first after. A recording
    whose clock runs faster than the robot's (a simulation sped up) has seconds of recording
    time that are many of the robot's: the turn in the car and the drive out of it are the
    scans that tie the floors together, and a guard in seconds alone would take them away.
    """
    floor = np.full(len(scan_t_ns), BETWEEN_FLOORS, dtype=np.int64)
    visit = np.full(len(scan_t_ns), -1, dtype=np.int64)
    if not segments:
        return np.zeros_like(floor), np.zeros_like(visit)
    guard = round(guard_s * 1e9)
    moved_t = scan_t_ns[moving] if moving is not None else np.zeros(0, dtype=np.int64)
    for k, (t0, t1, f) in enumerate(segments):
        lo = -np.inf if k == 0 else t0 + guard
        hi = np.inf if k == len(segments) - 1 else t1 - guard
        after = moved_t[moved_t >= t0]
        if len(after) and after[0] < lo:
            lo = int(after[0])
        before = moved_t[moved_t <= t1]
        if len(before) and before[-1] > hi:
            hi = int(before[-1])
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
    odometry: tuple[IntArray, FloatArray] | None = None,
    scan_odom: FloatArray | None = None,
) -> Segmentation:
    """Offline floor segmentation of a run's scans.

    ``reference`` is a fixed reference barometer's series (removes weather drift) when the
    run recorded one. ``odometry`` is the recording's ``(t_ns, (N, 3) poses)``: the detector
    takes a stop as a visit once the robot drove off, which settles floors sooner.
    ``scan_odom`` is the odometry pose at each scan, which bounds the transition guard by the
    robot's motion (:func:`label_scans`).
    """
    if len(pressure_t_ns) < MIN_PRESSURE_SAMPLES:
        return single_floor(len(scan_t_ns))
    from baromap.floors import detect_floors

    temps = None
    if temperature_c is not None and np.isfinite(temperature_c).all():
        temps = temperature_c
    if reference is not None and len(reference[0]) < MIN_PRESSURE_SAMPLES:
        reference = None
    odo = None if odometry is None else (odometry[0], odometry[1][:, 0], odometry[1][:, 1])
    detection = detect_floors(
        pressure_t_ns, pressure_pa, temps, method=method, reference=reference, odometry=odo
    )
    segments = [(int(s.t_start_ns), int(s.t_end_ns), int(s.floor)) for s in detection.segments]
    moving = None if scan_odom is None else moving_scans(scan_odom)
    floor, visit = label_scans(scan_t_ns, segments, moving=moving)
    floors = tuple(
        FloorInfo(int(f.index), float(f.elevation_m), float(f.level_pa), int(f.visits), f.name)
        for f in detection.floors
    )
    rides = tuple(
        Ride(int(t.t_start_ns), int(t.t_end_ns), int(t.from_floor), int(t.to_floor))
        for t in detection.transitions
    )
    return Segmentation(floor, visit, floors, f"barometer ({method})", detection, rides)
