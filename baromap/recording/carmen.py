"""CARMEN log parser: public laser datasets (Intel, FR079, ...) as typed records.

CARMEN logs are text, one message per line. Three messages matter for mapping:

- ``FLASER n r_1..r_n laser_x laser_y laser_theta robot_x robot_y robot_theta ipc_t host log_t``
  (old front-laser format; CARMEN's reader assumes a 180 degree field of view starting at -90
  degrees, one beam per degree for 180/181 beams, half a degree for 360/361; 400/401 beams are
  an LMS over 100 degrees at a quarter degree; another count takes the step of the log's
  ``PARAM laser_front_laser_resolution``, centred, if it has one);
- ``ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode n r_1..r_n
  m e_1..e_m laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv fwd side turn
  ipc_t host log_t`` (carries its own geometry);
- ``ODOM x y theta tv rv accel ipc_t host log_t``.

The robot pose on laser lines is the best pose the log's producer had: raw odometry in a raw
log, a SLAM solution in a "corrected" log. Corrected logs often carry no usable ``ODOM`` (the
Intel log's are all zeros); :func:`baromap.odometry.synthesis.synthesize_odometry` degrades
the reference poses instead, and :mod:`baromap.recording.carmen_import` writes a recording.

Malformed lines are skipped and counted (a long public log always has a few); a file with no
laser line at all is an :class:`~baromap.errors.InputFormatError`.
"""

from __future__ import annotations

import gzip
import math
import warnings
import zlib
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from decimal import Decimal, InvalidOperation
from itertools import pairwise
from pathlib import Path
from typing import TextIO

import numpy as np
import numpy.typing as npt
import structlog

from baromap.arrays import FloatArray
from baromap.errors import InputFormatError
from baromap.messages import NS_PER_S

log = structlog.get_logger(__name__)

#: Longest scan accepted (an LMS at 0.25 deg over 190 deg is 761 beams; leave headroom).
MAX_BEAMS = 4096
#: Ranges at or above this are "no return" markers (the Intel log uses 81.83 m).
NO_RETURN_M = 80.0
#: A reading at the top of a log's readings held by at least this share of all its beams, and
#: this many times as many beams as the 10 cm below it, is the laser's "no return" code, not a
#: wall: real walls spread over centimetres of noise, a code sits on one value. Logs of a laser
#: in a short-range mode print such a code far below ``NO_RETURN_M`` (and FLASER has no field
#: for it); mapped as a wall it would draw an arc that moves with the robot.
NO_RETURN_CODE_MIN_SHARE = 0.001
NO_RETURN_CODE_SPIKE = 5.0
#: Readings above a code: at most this share of the code's own count (glitches).
NO_RETURN_CODE_STRAY = 0.01
#: Scans a code must appear in.
NO_RETURN_CODE_MIN_SCANS = 10
#: Half the width of the bin a printed code falls in (logs print to the centimetre or finer).
NO_RETURN_CODE_BIN_M = 0.005
#: Stamps are Unix seconds; int64 nanoseconds hold about 292 years either side of 1970.
MAX_ABS_TIME_S = 9_200_000_000
#: A stamp at or past this (the year 2101) is a small negative time printed as an unsigned
#: 32-bit number: 4.29497e+09 is -1 s or so, wrapped.
WRAPPED_FROM_S = 2**32 - 2**27
#: A stamp under this (a millisecond after the log's clock began) is a zero, printed as a
#: denormal or left unset.
ZERO_BELOW_S = Decimal("0.001")
#: Where a log's stamps cannot order its scans (fewer than ORDERED_SHARE of the steps from one
#: scan to the next go forward: one value for the whole log, zeros, negative then wrapped),
#: every line is timed by its place in the file instead, a scan every ORDER_INTERVAL_S: the
#: corrected logs of the public collections keep about a scan per metre, driven at 0.5-1 m/s.
ORDERED_SHARE = 0.5
ORDER_INTERVAL_S = 1.0
#: A log timed by its scan order writes a pose with each scan when at least this share of
#: the steps from one scan to the next hold exactly one other line.
PAIRED_SHARE = 0.9


@dataclass(frozen=True, slots=True)
class CarmenScan:
    """One laser line: geometry, ranges, and the poses the log's producer attached."""

    t_ns: int
    angle_min_rad: float
    angle_increment_rad: float
    range_max_m: float
    ranges_m: FloatArray
    laser_pose: tuple[float, float, float]
    robot_pose: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class CarmenOdom:
    t_ns: int
    x_m: float
    y_m: float
    theta_rad: float
    v_mps: float
    omega_radps: float


@dataclass(slots=True)
class CarmenLog:
    """What a CARMEN log holds that baromap can use, in file order."""

    scans: list[CarmenScan] = field(default_factory=list)
    odometry: list[CarmenOdom] = field(default_factory=list)
    params: dict[str, str] = field(default_factory=dict)
    skipped: Counter[str] = field(default_factory=Counter)
    #: Set when a no-return code or ``robot_front_laser_max`` limits the ranges (see
    #: :func:`no_return_code`); ``None`` when the lines' own limits stand.
    range_limit_m: float | None = None
    #: What was done to stamps that could not time their lines (see :func:`line_times`).
    stamps: StampRepair | None = None
    #: The first malformed line of each kind: ``line N: what is wrong``.
    problems: dict[str, str] = field(default_factory=dict)

    def reference_poses(self) -> FloatArray:
        """(N, 3) robot poses attached to the scans."""
        return np.array([s.robot_pose for s in self.scans], dtype=np.float64).reshape(-1, 3)

    def scan_times_ns(self) -> npt.NDArray[np.int64]:
        return np.array([s.t_ns for s in self.scans], dtype=np.int64)

    def has_odometry(self) -> bool:
        """True when the ODOM lines actually move (corrected logs carry only zeros)."""
        return any(o.x_m != 0.0 or o.y_m != 0.0 or o.theta_rad != 0.0 for o in self.odometry)


def parse_time_ns(text: str) -> int:
    """Seconds as printed (decimal or exponent notation) to integer ns without float rounding
    (stamps must match relations); digits past the nanosecond are cut."""
    try:
        value = Decimal(text)
    except InvalidOperation:
        raise ValueError(f"bad time {text!r}") from None
    if not value.is_finite() or "_" in text:
        raise ValueError(f"bad time {text!r}")
    if abs(value) > MAX_ABS_TIME_S:
        raise ValueError(f"time {text!r} out of range")
    return int(value * NS_PER_S)


@dataclass(frozen=True, slots=True)
class StampRepair:
    """Stamps that could not time their lines, and what timed them instead.

    ``from_order``: the stamps could not order the scans at all, and every line was timed
    by its place in the file, a scan every ``interval_s``; otherwise each line whose stamp
    was broken took a time between its neighbours' in the file. ``faults`` counts the broken
    stamps by what was wrong with them; ``other_field`` the lines timed by the second stamp
    field of the line, their first being broken."""

    from_order: bool
    interval_s: float
    scans: int  # laser lines not timed by their own stamp
    odometry: int  # ODOM lines not timed by their own stamp
    faults: Counter[str]
    other_field: int

    def summary(self) -> dict[str, object]:
        """The counts, for one log line or a recording's metadata."""
        how = (
            f"scan order, a scan every {self.interval_s:g} s"
            if self.from_order
            else "their neighbours in the file"
        )
        return {
            "timed_by": how,
            "scans": self.scans,
            "odometry": self.odometry,
            **{k.replace(" ", "_"): v for k, v in sorted(self.faults.items())},
            "other_field": self.other_field,
        }


def _stamp_fault(text: str | None) -> tuple[int | None, str]:
    """A stamp's time, or None and what is wrong with it."""
    if text is None:
        return None, "missing"
    try:
        value = Decimal(text)
        t_ns = parse_time_ns(text)
    except (ValueError, InvalidOperation):
        return None, "unreadable"
    if value < 0:
        return None, "negative"
    if value < ZERO_BELOW_S:
        return None, "zero"
    if value >= WRAPPED_FROM_S:
        return None, "wrapped"
    return t_ns, ""


#: A stamp further than this behind the stamps before it in the file (their median, of
#: STRAY_WINDOW of them), or ahead of those after it, is out of order: a line written with
#: another line's field, not a clock's jitter.
STRAY_S = 5.0
STRAY_WINDOW = 10


def _strays(t_ns: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
    """Stamps (in file order) further than :data:`STRAY_S` behind the median of those before
    them, or ahead of the median of those after them."""
    n = len(t_ns)
    if n < 3:
        return np.zeros(n, dtype=bool)
    t = (t_ns - t_ns[0]).astype(np.float64)
    pad = np.full(STRAY_WINDOW, np.nan)
    windows = np.lib.stride_tricks.sliding_window_view(np.concatenate([pad, t, pad]), STRAY_WINDOW)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN window at the log's ends
        before = np.nanmedian(windows[:n], axis=1)
        after = np.nanmedian(windows[STRAY_WINDOW + 1 : STRAY_WINDOW + 1 + n], axis=1)
    # time goes forward: not far behind what came before it, nor far ahead of what follows
    return np.asarray((t < before - STRAY_S * NS_PER_S) | (t > after + STRAY_S * NS_PER_S))


def _order_positions(scan: npt.NDArray[np.bool_]) -> npt.NDArray[np.float64]:
    """Where each line falls in a log timed by its scan order: scan k at k. A log that writes
    one pose with each scan (one other line between most two scans, as many as scans) writes
    it beside its scan: each such line is timed with the scan on its side (the side the file's
    first line shows). Otherwise the lines between scans k and k + 1 spread evenly between."""
    scan_no = np.cumsum(scan) - 1  # the scan at or before each line, -1 before any
    position = scan_no.astype(np.float64)
    others = np.flatnonzero(~scan)
    if not len(others):
        return position
    group = scan_no[others]
    lead = np.searchsorted(group, group, side="left")
    size = np.searchsorted(group, group, side="right") - lead
    scans = int(scan.sum())
    between = np.diff(np.flatnonzero(scan)) - 1
    if (
        scans > 1
        and len(others) == scans
        and np.mean(between == 1) >= PAIRED_SHARE
        and not (scan[0] and scan[-1])
    ):
        # beside the next scan where the file opens with one, else beside the one before
        position[others] = group + (0.0 if scan[0] else 1.0)
        return position
    position[others] = group + (np.arange(len(others)) - lead + 1) / (size + 1)
    return position


def line_times(
    is_scan: list[bool], stamps: list[tuple[str | None, str | None]]
) -> tuple[npt.NDArray[np.int64], StampRepair | None]:
    """The time of every timed line (in file order), and what was repaired, if anything.

    Each line is timed by its first stamp field (CARMEN's ``ipc_timestamp``), or its last
    (``logger_timestamp``) where the first is broken: zero, negative, wrapped at 32 bits,
    unreadable. Where the stamps cannot order the scans (see :data:`ORDERED_SHARE`) every line
    is timed by its place in the file instead; otherwise the lines whose stamps are broken,
    or stray from the stamps around them (:data:`STRAY_S`), take a time between their
    neighbours' (by their place in the file), and a scan stamped like another comes a
    microsecond after it. A clock's jitter (an odometry line a little behind the one before
    it) is left alone: the lines are sorted by time afterwards."""
    n = len(stamps)
    times: list[int | None] = []
    faults: Counter[str] = Counter()
    other_field = 0
    fault_of: list[str] = []
    for first, last in stamps:
        t, fault = _stamp_fault(first)
        if t is None and last is not None:
            t2, _ = _stamp_fault(last)
            if t2 is not None:
                t, other_field = t2, other_field + 1
        times.append(t)
        fault_of.append(fault if t is None else "")
    scan_idx = [i for i in range(n) if is_scan[i]]
    scan_t = [times[i] for i in scan_idx]
    forward = sum(1 for a, b in pairwise(scan_t) if a is not None and b is not None and b > a)
    out = np.zeros(n, dtype=np.int64)
    if n == 0:
        return out, None
    if all(t is None for t in times) or (
        scan_idx
        and (forward < ORDERED_SHARE * (len(scan_idx) - 1) or all(t is None for t in scan_t))
    ):
        position = _order_positions(np.array(is_scan, dtype=bool))
        interval = round(ORDER_INTERVAL_S * NS_PER_S)
        out[:] = np.round((position + 1.0) * interval).astype(np.int64)
        for i in range(n):
            faults[fault_of[i] or "repeated"] += 1
        repaired_scans, repaired_odom = len(scan_idx), n - len(scan_idx)
        return out, StampRepair(
            True, ORDER_INTERVAL_S, repaired_scans, repaired_odom, faults, other_field
        )
    sane = np.array([i for i in range(n) if times[i] is not None], dtype=np.int64)
    sane_t = np.array([times[i] for i in sane], dtype=np.int64)
    stray = _strays(sane_t)
    good, exact = sane[~stray], sane_t[~stray]
    # interpolated about the first good stamp: float64 holds Unix nanoseconds to 128 ns only
    base = int(exact[0])
    good_t = (exact - base).astype(np.float64)
    bad = np.ones(n, dtype=bool)
    bad[good] = False
    for line in np.flatnonzero(bad).tolist():
        faults[fault_of[line] or "out of order"] += 1
    rel = np.interp(np.arange(n), good, good_t)
    if len(good) > 1:
        # before the first good stamp and after the last: the usual time per line
        step = float(np.median(np.diff(good_t) / np.diff(good)))
        head, tail = np.arange(n) < good[0], np.arange(n) > good[-1]
        rel[head] = good_t[0] - (good[0] - np.flatnonzero(head)) * step
        rel[tail] = good_t[-1] + (np.flatnonzero(tail) - good[-1]) * step
    out[:] = base + np.round(rel).astype(np.int64)
    out[good] = exact
    out[:] = np.maximum(out, 0)
    # two scans of one stamp: the later (in time, then in the file) a microsecond on
    scans = np.array(scan_idx, dtype=np.int64)
    order = scans[np.argsort(out[scans], kind="stable")]
    previous = -1
    for i in order.tolist():
        if out[i] <= previous:
            out[i] = previous + 1000
            if not bad[i]:
                bad[i] = True
                faults["repeated"] += 1
        previous = int(out[i])
    if not bad.any() and not other_field:
        return out, None
    scans_fixed = int(bad[scan_idx].sum())
    return out, StampRepair(
        False, ORDER_INTERVAL_S, scans_fixed, int(bad.sum()) - scans_fixed, faults, other_field
    )


#: Start angle and increment CARMEN's reader gives a SICK by an FLASER line's beam count
#: (``carmen_laser_guess_fov``); 400/401 beams are an LMS over 100 deg, centred, as it sweeps.
SICK_GEOMETRY: dict[int, tuple[float, float]] = {
    **dict.fromkeys((180, 181), (-math.pi / 2, math.radians(1.0))),
    **dict.fromkeys((360, 361), (-math.pi / 2, math.radians(0.5))),
    **dict.fromkeys((400, 401), (-math.radians(50.0), math.radians(0.25))),
    **dict.fromkeys((720, 721), (-math.pi / 2, math.radians(0.25))),
}


def flaser_geometry(n: int) -> tuple[float, float]:
    """Start angle and increment CARMEN assumes for an FLASER line of ``n`` beams."""
    return SICK_GEOMETRY.get(n, (-math.pi / 2, math.pi / max(n - 1, 1)))


def no_return_code(scans: list[CarmenScan]) -> float | None:
    """The log's "no return" reading, if it prints one below the range its lines declare.

    The highest reading (to the millimetre) that many beams hold, with next to nothing above it
    (a stray reading past a laser's code is a glitch, not a wall further out) and a spike
    against the 10 cm below it.
    """
    if not scans:
        return None
    ranges = np.concatenate([s.ranges_m for s in scans])
    limit = min(s.range_max_m for s in scans)
    ranges = ranges[np.isfinite(ranges) & (ranges > 0.0) & (ranges < limit)]
    if ranges.size == 0:
        return None
    values, counts = np.unique(np.round(ranges * 1000.0).astype(np.int64), return_counts=True)
    frequent = np.flatnonzero(counts >= max(NO_RETURN_CODE_MIN_SHARE * ranges.size, 2.0))
    if frequent.size == 0:
        return None
    top = int(frequent[-1])
    if counts[top + 1 :].sum() > NO_RETURN_CODE_STRAY * counts[top]:
        return None
    code_mm = int(values[top])
    bin_mm = round(NO_RETURN_CODE_BIN_M * 1000)
    at = counts[(values > code_mm - bin_mm) & (values <= code_mm)].sum()
    below = counts[(values > code_mm - 100) & (values <= code_mm - bin_mm)].sum()
    if at < NO_RETURN_CODE_SPIKE * max(int(below), 1):
        return None
    code = code_mm / 1000.0 - NO_RETURN_CODE_BIN_M
    # a code is printed wherever the robot is; one view held still repeats its own walls
    seen_in = sum(bool(np.any((s.ranges_m >= code) & (s.ranges_m < limit))) for s in scans)
    return code if seen_in >= NO_RETURN_CODE_MIN_SCANS else None


def _declared_max(params: dict[str, str]) -> float | None:
    """``robot_front_laser_max``, CARMEN's setting for the front laser's longest valid reading."""
    try:
        value = float(params.get("robot_front_laser_max", "nan"))
    except ValueError:
        return None
    return value if math.isfinite(value) and 0.0 < value < NO_RETURN_M else None


def _apply_declared_resolution(result: CarmenLog) -> None:
    """FLASER lines of a beam count CARMEN cannot place: the log's own
    ``laser_front_laser_resolution`` (degrees) gives the step, the sweep centred ahead (as a
    SICK's 100 deg modes are). Without it they stay spread over 180 deg, CARMEN's guess."""
    try:
        degrees = float(result.params.get("laser_front_laser_resolution", "nan"))
    except ValueError:
        return
    if not (math.isfinite(degrees) and 0.0 < degrees <= 5.0):
        return
    step = math.radians(degrees)
    result.scans = [
        replace(s, angle_min_rad=-(len(s.ranges_m) - 1) * step / 2, angle_increment_rad=step)
        if len(s.ranges_m) not in SICK_GEOMETRY and (len(s.ranges_m) - 1) * step <= math.tau
        else s
        for s in result.scans
    ]


def _apply_range_limit(result: CarmenLog) -> None:
    """Mark readings at the log's no-return code (or past its declared maximum) as no return."""
    found = (_declared_max(result.params), no_return_code(result.scans))
    limits = [v for v in found if v is not None]
    if not limits:
        return
    limit = min(limits)
    result.scans = [
        replace(s, range_max_m=limit) if s.range_max_m > limit else s for s in result.scans
    ]
    result.range_limit_m = limit


def _ranges(tokens: list[str], start: int, n: int) -> FloatArray:
    if not 0 < n <= MAX_BEAMS:
        raise ValueError(f"beam count {n} outside 1..{MAX_BEAMS}")
    if len(tokens) < start + n:
        raise ValueError("line shorter than its beam count")
    return np.array(tokens[start : start + n], dtype=np.float64)


def _pose(tokens: list[str], start: int) -> tuple[float, float, float]:
    pose = float(tokens[start]), float(tokens[start + 1]), float(tokens[start + 2])
    if not all(math.isfinite(v) for v in pose):
        # one NaN pose would poison every synthesised odometry pose after it
        raise ValueError("pose is not finite")
    return pose


#: A line's two stamp fields (``ipc_timestamp``, ``logger_timestamp``), None where absent.
Stamps = tuple[str | None, str | None]


def _stamps(tokens: list[str], at: int) -> Stamps:
    """The stamp fields from ``tokens[at]`` on: ``ipc_timestamp ipc_hostname
    logger_timestamp``."""
    return (
        tokens[at] if len(tokens) > at else None,
        tokens[at + 2] if len(tokens) > at + 2 else None,
    )


def _parse_flaser(tokens: list[str]) -> tuple[CarmenScan, Stamps]:
    n = int(tokens[1])
    ranges = _ranges(tokens, 2, n)
    rest = 2 + n
    if len(tokens) < rest + 6:
        raise ValueError(f"FLASER line too short for its {n} ranges and two poses")
    angle_min, increment = flaser_geometry(n)
    scan = CarmenScan(
        t_ns=0,
        angle_min_rad=angle_min,
        angle_increment_rad=increment,
        range_max_m=NO_RETURN_M,
        ranges_m=ranges,
        laser_pose=_pose(tokens, rest),
        robot_pose=_pose(tokens, rest + 3),
    )
    return scan, _stamps(tokens, rest + 6)


def _parse_robotlaser1(tokens: list[str]) -> tuple[CarmenScan, Stamps]:
    start_angle, _fov, resolution, max_range = (float(v) for v in tokens[2:6])
    if not (math.isfinite(start_angle) and 0.0 < resolution < math.pi):
        raise ValueError("ROBOTLASER1 geometry out of range")
    n = int(tokens[8])
    ranges = _ranges(tokens, 9, n)
    k = 9 + n
    m = int(tokens[k])
    if not 0 <= m <= MAX_BEAMS:
        raise ValueError(f"remission count {m} outside 0..{MAX_BEAMS}")
    k += 1 + m
    if len(tokens) < k + 11:
        raise ValueError("ROBOTLASER1 line too short for its poses and velocities")
    scan = CarmenScan(
        t_ns=0,
        angle_min_rad=start_angle,
        angle_increment_rad=resolution,
        range_max_m=min(max_range, NO_RETURN_M) if max_range > 0 else NO_RETURN_M,
        ranges_m=ranges,
        laser_pose=_pose(tokens, k),
        robot_pose=_pose(tokens, k + 3),
    )
    return scan, _stamps(tokens, k + 11)


def _parse_odom(tokens: list[str]) -> tuple[CarmenOdom, Stamps]:
    if len(tokens) < 7:
        raise ValueError("ODOM line too short for a pose and three velocities")
    x, y, theta = _pose(tokens, 1)
    tv, rv = float(tokens[4]), float(tokens[5])
    return CarmenOdom(0, x, y, theta, tv, rv), _stamps(tokens, 7)


def _open_text(path: Path) -> TextIO:
    if path.suffix == ".gz":
        return gzip.open(path, "rt", encoding="ascii", errors="replace")
    return path.open("r", encoding="ascii", errors="replace")


def parse_lines(lines: Iterator[str] | list[str]) -> CarmenLog:
    """Parse CARMEN text lines; unknown messages and malformed lines are counted, not fatal.

    Lines are timed by :func:`line_times`: a stamp that cannot time its line is replaced
    (what was done is in :attr:`CarmenLog.stamps`), never a reason to drop the line."""
    result = CarmenLog()
    # (kind, record, stamps) of every line that carries a time, in file order
    timed: list[tuple[str, CarmenScan | CarmenOdom, Stamps]] = []
    for number, line in enumerate(lines, 1):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        kind = tokens[0]
        try:
            if kind == "FLASER":
                timed.append((kind, *_parse_flaser(tokens)))
            elif kind == "ROBOTLASER1":
                timed.append((kind, *_parse_robotlaser1(tokens)))
            elif kind == "ODOM":
                timed.append((kind, *_parse_odom(tokens)))
            elif kind == "PARAM" and len(tokens) >= 3:
                result.params[tokens[1]] = tokens[2]
            else:
                result.skipped[f"unused {kind}"] += 1
        except (ValueError, IndexError) as exc:
            result.skipped[f"malformed {kind}"] += 1
            result.problems.setdefault(kind, f"line {number}: {exc or 'a field is missing'}")
    if any(kind == "ROBOTLASER1" for kind, _, _ in timed):
        # a logger that writes both prints every front-laser scan twice; ROBOTLASER1 says
        # its own geometry, FLASER leaves it to a guess from the beam count
        flaser = sum(kind == "FLASER" for kind, _, _ in timed)
        if flaser:
            result.skipped["FLASER beside ROBOTLASER1"] += flaser
        timed = [t for t in timed if t[0] != "FLASER"]
    times, result.stamps = line_times(
        [kind != "ODOM" for kind, _, _ in timed], [stamps for _, _, stamps in timed]
    )
    for (_, record, _), t_ns in zip(timed, times.tolist(), strict=True):
        if isinstance(record, CarmenScan):
            result.scans.append(replace(record, t_ns=t_ns))
        else:
            result.odometry.append(replace(record, t_ns=t_ns))
    if not any(kind == "ROBOTLASER1" for kind, _, _ in timed):
        _apply_declared_resolution(result)
    result.scans.sort(key=lambda s: s.t_ns)
    result.odometry.sort(key=lambda o: o.t_ns)
    _apply_range_limit(result)
    return result


def read_carmen(path: str | Path) -> CarmenLog:
    """Read a CARMEN log (plain or .gz)."""
    path = Path(path)
    try:
        with _open_text(path) as handle:
            result = parse_lines(handle)
    except (OSError, EOFError, zlib.error) as exc:  # a truncated or corrupt .gz too
        raise InputFormatError(f"cannot read CARMEN log {path}: {exc}") from exc
    if not result.scans:
        bad = {k: v for k, v in result.problems.items() if k in ("FLASER", "ROBOTLASER1")}
        if not bad:
            raise InputFormatError(f"{path}: no FLASER or ROBOTLASER1 line")
        raise InputFormatError(
            f"{path}: no usable laser line; "
            + "; ".join(
                f"{result.skipped[f'malformed {kind}']} {kind} lines malformed, the first at "
                f"{where}"
                for kind, where in bad.items()
            )
        )
    if result.stamps is not None:
        log.warning("stamps replaced", path=str(path), **result.stamps.summary())
    log.info(
        "carmen log read",
        path=str(path),
        scans=len(result.scans),
        odometry=len(result.odometry),
        skipped=dict(result.skipped),
        range_limit_m=result.range_limit_m,
    )
    return result
