"""A recording as the arrays mapping works on: scans, odometry at the scan times, pressure.

Odometry and the laser run on their own clocks (10 Hz SIPs, 5-75 Hz scans), so the odometry
pose is interpolated at each scan's stamp; a scan outside the odometry's time span takes the
nearest odometry pose.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TypeVar

import numpy as np
import structlog

from baromap import messages
from baromap.arrays import BoolArray, FloatArray, IntArray
from baromap.errors import InputFormatError
from baromap.mapping import se2
from baromap.mapping.arrival_stamps import stamped_on_arrival, tighten
from baromap.mapping.scans import ScanBlock
from baromap.odometry.integrator import ORIGIN_M, ORIGIN_RAD
from baromap.recording import (
    LaserMount,
    OdometrySeries,
    PressureSeries,
    carmen_import,
    load_pressures_and_odometry,
    read_messages,
    read_metadata,
    topics,
)
from baromap.recording.run_parts import Recording, run_parts

log = structlog.get_logger(__name__)

#: Scans further apart than this, and than SILENCE_INTERVALS of the recording's usual
#: interval, while the robot moved more than SILENCE_MOVED_M, are a stretch the laser was
#: silent (a 2D laser sends 5-75 scans a second; the daemon closes one that stops and opens
#: it again): said in the log, as the map of that stretch rests on odometry alone. A log kept
#: at a scan a metre (a scan every 1-2 s, some 15 s apart where the robot stood) is sparse by
#: design, not silent.
LASER_SILENCE_S = 1.0
SILENCE_INTERVALS = 10.0
SILENCE_MOVED_M = 2.0
#: The odometry is silent over a gap between its samples longer than this and this many of
#: its usual intervals (a base at 10 Hz: a second). A scan inside such a gap and further from
#: every sample than the stream's usual interval is one the odometry said nothing about; a
#: log that records the odometry with each scan has a sample at every scan, however long the
#: pause after it.
ODOMETRY_GAP_S = 1.0
ODOMETRY_GAP_INTERVALS = 10.0
#: A break in the odometry needs evidence, never a pause alone (odometry is cumulative: a
#: robot waiting at a lift for minutes, or a logger writing a pose with each scan 2-40 s
#: apart, goes on counting from where it was). Evidence: a move further than this speed times
#: the time between two samples plus TRACK_SLACK_M, which no base drives (indoor bases top
#: out at 1-1.5 m/s); or a pose at the odometry's origin (within the integrator's ORIGIN_M and
#: ORIGIN_RAD, the test baromapd makes) after one that was not, with at least
#: ODOMETRY_GAP_S between them (a power cycle takes seconds). Either way the base counts from
#: zero again in a frame of its own (power-cycled, under a recorder that does not join its
#: tracks as baromapd does). Where the times are no clock (a log whose stamps were replaced by
#: its scan order) a speed means nothing, and only the origin tells.
TRACK_SPEED_M_S = 2.0
TRACK_SLACK_M = 0.5


@dataclass(frozen=True, slots=True)
class RunData:
    scans: ScanBlock
    odom: FloatArray  # (S, 3) odometry pose at each scan
    pressure_t_ns: IntArray
    pressure_pa: FloatArray
    temperature_c: FloatArray  # NaN where absent
    metadata: dict[str, dict[str, str]]
    reference_t_ns: IntArray  # fixed reference barometer, empty when none was recorded
    reference_pa: FloatArray
    odometry_t_ns: IntArray  # the recording's odometry as it came (for the floor detector)
    odometry_poses: FloatArray  # (N, 3)
    #: (S,): scans the odometry said nothing about (see :func:`odometry_blind`), and those
    #: inside the silence of a break
    blind: BoolArray
    #: (S,): the odometry broke (counted from zero again; see :data:`TRACK_SPEED_M_S`) after
    #: the scan before this one: the step to it is not measured
    breaks: BoolArray

    def travel(self) -> FloatArray:
        """(S, 2): the odometry's path (m) and its turning, every turn counted (rad), from
        the start of the recording to each scan, as the odometry came.

        Between two scans far apart (the laser silent while the robot drove on) the pose at
        each end says only where the robot ended up; a robot that went 18 m and turned 440
        degrees to end 6 m on carries the doubt of the whole drive.
        """
        return odometric_travel(self.odometry_t_ns, self.odometry_poses, self.scans.t_ns)


def _gap_limit_ns(gaps_ns: IntArray) -> float:
    """A gap in the odometry: longer than ODOMETRY_GAP_S and ODOMETRY_GAP_INTERVALS of the
    stream's usual intervals (``gaps_ns``: between consecutive samples, in time order)."""
    return max(ODOMETRY_GAP_S * 1e9, ODOMETRY_GAP_INTERVALS * float(np.median(gaps_ns)))


def odometry_blind(t_src: IntArray, t_query: IntArray) -> BoolArray:
    """Which of the ``t_query`` stamps fall where the odometry stream said nothing: inside a
    gap between two samples longer than ODOMETRY_GAP_S and ten of the stream's usual
    intervals, or further than that before its first sample or after its last (the base
    unplugged or power-cycled while the laser went on). Odometry at such a stamp is a straight
    line drawn across the gap, not a measurement. An empty stream: every stamp."""
    blind = np.zeros(len(t_query), dtype=bool)
    if len(t_src) < 2:
        blind[:] = len(t_src) == 0
        return blind
    t = np.sort(t_src)
    gaps = np.diff(t)
    limit = _gap_limit_ns(gaps)
    after = np.searchsorted(t, t_query, side="right")
    inside = (after > 0) & (after < len(t))
    prev_t = t[np.clip(after - 1, 0, len(t) - 1)]
    next_t = t[np.clip(after, 0, len(t) - 1)]
    blind |= inside & (next_t - prev_t > limit)
    blind |= (after == 0) & (t[0] - t_query > limit)
    blind |= (after == len(t)) & (t_query - t[-1] > limit)
    # a scan as near a sample as the samples are to each other is spoken for by it
    nearest = np.minimum(np.abs(t_query - prev_t), np.abs(next_t - t_query))
    blind &= ~(nearest < float(np.median(gaps)))
    return blind


def join_odometry_tracks(
    t_src: IntArray, poses: FloatArray, *, clock: bool = True
) -> tuple[FloatArray, int]:
    """The odometry in one frame, and how many times it had to be joined.

    Where there is evidence that the base counted from zero again, in a frame of its own (a
    move no base drives in the time, or a return to the origin after a silence: see
    :data:`TRACK_SPEED_M_S`), the rest of the stream is moved rigidly so that it goes on
    from the pose before. The motion across the break is lost either way; what the join
    saves is every pose after it (a jump of metres is a step the SLAM would take for a
    drive). ``clock``: the times are a clock (see :func:`stamps_are_a_clock`). ``baromapd``
    joins its tracks as it records
    (:class:`~baromap.odometry.integrator.OdometryIntegrator`); this is for recordings made
    without it."""
    joined, breaks = _join_tracks(t_src, poses, clock)
    return joined, len(breaks)


def _join_tracks(
    t_src: IntArray, poses: FloatArray, clock: bool
) -> tuple[FloatArray, list[tuple[int, int]]]:
    """:func:`join_odometry_tracks`, and each break as the times of the samples either side."""
    if len(t_src) < 2:
        return poses, []
    order = np.argsort(t_src, kind="stable")
    t = t_src[order]
    p = poses[order].astype(np.float64)
    gaps = np.diff(t)
    moved = np.hypot(*np.diff(p[:, :2], axis=0).T)
    origin = (np.hypot(p[:, 0], p[:, 1]) <= ORIGIN_M) & (np.abs(se2.wrap(p[:, 2])) <= ORIGIN_RAD)
    restarted = origin[1:] & ~origin[:-1] & (gaps > ODOMETRY_GAP_S * 1e9)
    if clock:
        restarted |= moved > TRACK_SPEED_M_S * gaps / 1e9 + TRACK_SLACK_M
    starts = np.flatnonzero(restarted) + 1
    for b in starts:
        p[b:] = se2.compose(se2.compose(p[b - 1], se2.inverse(p[b])), p[b:])
    out = np.empty_like(p)
    out[order] = p
    return out, [(int(t[b - 1]), int(t[b])) for b in starts]


def stamps_are_a_clock(metadata: dict[str, dict[str, str]]) -> bool:
    """False where the recording says its times were made from the scan order (a CARMEN log
    whose stamps could not order its scans): a speed worked out from them means nothing."""
    header = metadata.get(carmen_import.METADATA_NAME, {})
    return header.get(carmen_import.STAMPS_KEY) != carmen_import.STAMPS_FROM_ORDER


def recorder_joined_tracks(metadata: dict[str, dict[str, str]]) -> bool:
    """Whether the recording says its recorder kept the odometry in one frame across the
    base's restarts (baromapd does). Then a jump across a gap is the robot's own: the host
    stalled while the base counted on (the demo's twins play six times faster than real time,
    and a one-second stall there is a drive of 3.6 m, beyond any real base's), and
    :func:`join_odometry_tracks` would cut a drive out of the run."""
    header = metadata.get(topics.METADATA_NAME, {})
    return header.get(topics.ODOMETRY_TRACKS_KEY) == topics.ODOMETRY_TRACKS_JOINED


def odometric_travel(t_src: IntArray, poses: FloatArray, t_query: IntArray) -> FloatArray:
    """Cumulative path and cumulative absolute turn of a pose stream at ``t_query`` (see
    :meth:`RunData.travel`); zeros when the stream is empty."""
    out = np.zeros((len(t_query), 2))
    if len(t_src) < 2:
        return out
    order = np.argsort(t_src, kind="stable")
    t = t_src[order].astype(np.float64)
    p = poses[order]
    step = np.diff(p, axis=0)
    path = np.concatenate([[0.0], np.cumsum(np.hypot(step[:, 0], step[:, 1]))])
    turn = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(np.unwrap(p[:, 2]))))])
    q = t_query.astype(np.float64)
    out[:, 0] = np.interp(q, t, path)
    out[:, 1] = np.interp(q, t, turn)
    return out


def interpolate_poses(t_src: IntArray, poses: FloatArray, t_query: IntArray) -> FloatArray:
    """Linear interpolation of (x, y, theta) with theta unwrapped; clamps at the ends."""
    if len(t_src) == 0:
        return np.zeros((len(t_query), 3))
    order = np.argsort(t_src, kind="stable")
    t = t_src[order].astype(np.float64)
    p = poses[order]
    theta = np.unwrap(p[:, 2])
    q = t_query.astype(np.float64)
    out = np.stack(
        [np.interp(q, t, p[:, 0]), np.interp(q, t, p[:, 1]), np.interp(q, t, theta)], axis=1
    )
    out[:, 2] = se2.wrap(out[:, 2])
    return out


def laser_offset_from_metadata(metadata: dict[str, dict[str, str]]) -> FloatArray:
    """Laser mounting (x, y, yaw) in the robot frame, from any metadata record that states it
    (:class:`~baromap.recording.LaserMount`), zeros when none does."""
    mount = LaserMount.from_metadata(metadata)
    if mount is None:
        return np.zeros(3)
    return np.array([mount.x_m, mount.y_m, mount.yaw_rad])


@dataclass(frozen=True, slots=True)
class RunSeries:
    """The run's barometers and odometry as columns: what :func:`load_series` reads."""

    pressure: PressureSeries
    odometry: OdometrySeries
    reference: PressureSeries


Series = TypeVar("Series", PressureSeries, OdometrySeries)


def _joined(parts: Sequence[Series]) -> Series:
    """One series of a run's parts, one after the other (baromapd splits a run between two
    messages: nothing is repeated)."""
    if len(parts) == 1:
        return parts[0]
    first = parts[0]
    return replace(
        first,
        **{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(first)},
    )


def _listed(parts: Recording) -> list[Path]:
    return [Path(parts)] if isinstance(parts, str | Path) else [Path(p) for p in parts]


def _named(parts: Sequence[Path]) -> str:
    return str(parts[0]) if len(parts) == 1 else f"{parts[0]} (and {len(parts) - 1} more parts)"


def load_series(parts: Recording) -> RunSeries:
    """Both barometers and odometry, in one pass over each file of the run, one after the
    other (``parts`` in order, as :func:`run_parts` gives them).

    Separate from the scans so that another process can read them while this one reads the
    scans (:mod:`baromap.mapping.build`): each pass decompresses the whole file.
    """
    parts = _listed(parts)
    loaded = [
        load_pressures_and_odometry(p, [topics.BARO, topics.REFERENCE_PRESSURE], topics.ODOM)
        for p in parts
    ]
    odometry = _joined([o for _, o in loaded])
    if len(odometry) == 0:
        raise InputFormatError(f"{_named(parts)}: no odometry on {topics.ODOM}")
    return RunSeries(
        _joined([p[topics.BARO] for p, _ in loaded]),
        odometry,
        _joined([p[topics.REFERENCE_PRESSURE] for p, _ in loaded]),
    )


def load_scans(parts: Recording) -> tuple[ScanBlock, dict[str, dict[str, str]]]:
    """The laser scans of a run's files (``parts`` in order, as :func:`run_parts` gives
    them) as one block, with the laser's mounting, and the metadata they came with (a later
    file's record of a name wins).

    Files of several runs (baromapd restarted during one exploration): their header no
    longer says the odometry is one frame. Each baromapd joined the base's restarts within
    its own run only; across a restart of the daemon, a base power-cycled meanwhile counts
    from zero, and :func:`join_odometry_tracks` is what finds that."""
    parts = _listed(parts)
    metadata: dict[str, dict[str, str]] = {}
    scans: list[messages.LaserScan] = []
    runs = set()
    for part in parts:
        read = read_metadata(part)
        runs.add(read.get(topics.METADATA_NAME, {}).get("run"))
        metadata.update(read)
        scans += [
            rec.message
            for rec in read_messages(part, [topics.SCAN])
            if isinstance(rec.message, messages.LaserScan)
        ]
    if not scans:
        raise InputFormatError(f"{_named(parts)}: no laser scans on {topics.SCAN}")
    if len(runs) > 1 and topics.METADATA_NAME in metadata:
        header = dict(metadata[topics.METADATA_NAME])
        header.pop(topics.ODOMETRY_TRACKS_KEY, None)
        metadata[topics.METADATA_NAME] = header
    return ScanBlock.from_messages(scans, laser_offset_from_metadata(metadata)), metadata


def load_run(recording: Recording, *, across_runs: bool = False) -> RunData:
    """Read the four topics mapping needs from a recording (its files as :func:`run_parts`
    orders them): scans, odometry, the robot's barometer and a reference station's.

    Pressure and odometry come as whole columns in one pass (the reader's series loaders);
    scans as messages, since a scan is an array already.
    """
    parts = run_parts(recording, across_runs=across_runs)
    block, metadata = load_scans(parts)
    return run_data(block, metadata, load_series(parts))


def _say_silences(t_ns: IntArray, odom: FloatArray) -> None:
    """A warning for the stretches without scans while the robot moved, if any: how many,
    the longest, the first."""
    gaps = np.diff(t_ns) / 1e9
    if not len(gaps):
        return
    limit = max(LASER_SILENCE_S, SILENCE_INTERVALS * float(np.median(gaps)))
    moved = np.hypot(*np.diff(odom[:, :2], axis=0).T)
    silent = np.flatnonzero((gaps > limit) & (moved > SILENCE_MOVED_M))
    if len(silent):
        log.warning(
            "laser silent",
            stretches=len(silent),
            longest_s=round(float(gaps[silent].max()), 1),
            first_after_s=round(float(t_ns[silent[0]] - t_ns[0]) / 1e9, 1),
            seconds=round(float(gaps[silent].sum()), 1),
        )


def _say_odometry_silences(t_ns: IntArray, blind: BoolArray) -> None:
    """A warning for the scans the odometry said nothing about, if any: how many stretches,
    how long in all, the first."""
    if not blind.any():
        return
    edges = np.flatnonzero(np.diff(np.concatenate([[0], blind.astype(np.int8), [0]])))
    starts, ends = edges[::2], edges[1::2] - 1
    log.warning(
        "odometry silent",
        stretches=len(starts),
        scans=int(blind.sum()),
        seconds=round(float((t_ns[ends] - t_ns[starts]).sum()) / 1e9, 1),
        first_after_s=round(float(t_ns[starts[0]] - t_ns[0]) / 1e9, 1),
    )


def _set_back_backlogs(
    block: ScanBlock, odometry: OdometrySeries
) -> tuple[ScanBlock, OdometrySeries]:
    """Scans and odometry with the late stamps of their backlogs set back
    (:mod:`baromap.mapping.arrival_stamps`)."""
    scans, odo = tighten(block.t_ns), tighten(odometry.t_ns)
    if scans.set_back or odo.set_back:
        log.info(
            "late stamps of backlogs set back",
            scans=scans.set_back,
            scans_most_ms=round(scans.most_ns / 1e6, 1),
            scan_period_ms=round(scans.period_ns / 1e6, 2),
            odometry=odo.set_back,
            odometry_most_ms=round(odo.most_ns / 1e6, 1),
            odometry_period_ms=round(odo.period_ns / 1e6, 2),
        )
    return replace(block, t_ns=scans.t_ns), replace(odometry, t_ns=odo.t_ns)


def run_data(block: ScanBlock, metadata: dict[str, dict[str, str]], series: RunSeries) -> RunData:
    """The run from its scans and series: odometry interpolated at every scan's stamp; where a
    host stamped them as they arrived, their backlogs' late stamps set back first."""
    pressure, odometry, reference = series.pressure, series.odometry, series.reference
    if stamped_on_arrival(metadata):
        block, odometry = _set_back_backlogs(block, odometry)
    odometry_poses = odometry.poses()
    t = block.t_ns
    breaks = np.zeros(len(t), dtype=bool)
    blind = odometry_blind(odometry.t_ns, t)
    if recorder_joined_tracks(metadata):
        # a stall of the recorder with the robot driving on is no restart: left to odometry
        log.debug("odometry in one frame as recorded: its recorder joined the base's restarts")
    else:
        odometry_poses, joins = _join_tracks(
            odometry.t_ns, odometry_poses, stamps_are_a_clock(metadata)
        )
        for before, after in joins:
            # the scans between the samples either side of the break are nobody's
            blind |= (t > before) & (t < after)
            first = int(np.searchsorted(t, after, side="left"))
            if 0 < first < len(t):
                breaks[first] = True
        if joins:
            log.warning(
                "odometry counted from zero again: joined at the pose before",
                times=len(joins),
                first_after_s=round(float(joins[0][1] - t[0]) / 1e9, 1),
            )
    odom = interpolate_poses(odometry.t_ns, odometry_poses, t)
    log.info("run loaded", scans=len(block), odometry=len(odometry), pressure=len(pressure.t_ns))
    _say_silences(t, odom)
    _say_odometry_silences(t, blind)
    return RunData(
        scans=block,
        odom=odom,
        pressure_t_ns=pressure.t_ns,
        pressure_pa=pressure.pressure_pa,
        temperature_c=pressure.temperature_c,
        metadata=metadata,
        reference_t_ns=reference.t_ns,
        reference_pa=reference.pressure_pa,
        odometry_t_ns=odometry.t_ns,
        odometry_poses=odometry_poses,
        blind=blind,
        breaks=breaks,
    )
