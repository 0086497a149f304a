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
import zlib
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
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

    def reference_poses(self) -> FloatArray:
        """(N, 3) robot poses attached to the scans."""
        return np.array([s.robot_pose for s in self.scans], dtype=np.float64).reshape(-1, 3)

    def scan_times_ns(self) -> npt.NDArray[np.int64]:
        return np.array([s.t_ns for s in self.scans], dtype=np.int64)

    def has_odometry(self) -> bool:
        """True when the ODOM lines actually move (corrected logs carry only zeros)."""
        return any(o.x_m != 0.0 or o.y_m != 0.0 or o.theta_rad != 0.0 for o in self.odometry)


def parse_time_ns(text: str) -> int:
    """Decimal seconds to integer ns without float rounding (stamps must match relations)."""
    sign = -1 if text.startswith("-") else 1
    whole, _, frac = text.lstrip("+-").partition(".")
    if not whole.isdigit() and whole != "":
        raise ValueError(f"bad time {text!r}")
    if frac and not frac.isdigit():
        raise ValueError(f"bad time {text!r}")
    frac_ns = int((frac + "000000000")[:9]) if frac else 0
    if len(whole) > 10 or int(whole or "0") > MAX_ABS_TIME_S:
        raise ValueError(f"time {text!r} out of range")
    return sign * (int(whole or "0") * NS_PER_S + frac_ns)


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


def _parse_flaser(tokens: list[str]) -> CarmenScan:
    n = int(tokens[1])
    ranges = _ranges(tokens, 2, n)
    rest = 2 + n
    if len(tokens) < rest + 7:
        raise ValueError("FLASER line too short")
    angle_min, increment = flaser_geometry(n)
    return CarmenScan(
        t_ns=parse_time_ns(tokens[rest + 6]),
        angle_min_rad=angle_min,
        angle_increment_rad=increment,
        range_max_m=NO_RETURN_M,
        ranges_m=ranges,
        laser_pose=_pose(tokens, rest),
        robot_pose=_pose(tokens, rest + 3),
    )


def _parse_robotlaser1(tokens: list[str]) -> CarmenScan:
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
    if len(tokens) < k + 12:
        raise ValueError("ROBOTLASER1 line too short")
    return CarmenScan(
        t_ns=parse_time_ns(tokens[k + 11]),
        angle_min_rad=start_angle,
        angle_increment_rad=resolution,
        range_max_m=min(max_range, NO_RETURN_M) if max_range > 0 else NO_RETURN_M,
        ranges_m=ranges,
        laser_pose=_pose(tokens, k),
        robot_pose=_pose(tokens, k + 3),
    )


def _parse_odom(tokens: list[str]) -> CarmenOdom:
    if len(tokens) < 8:
        raise ValueError("ODOM line too short")
    x, y, theta = _pose(tokens, 1)
    tv, rv = float(tokens[4]), float(tokens[5])
    return CarmenOdom(parse_time_ns(tokens[7]), x, y, theta, tv, rv)


def _open_text(path: Path) -> TextIO:
    if path.suffix == ".gz":
        return gzip.open(path, "rt", encoding="ascii", errors="replace")
    return path.open("r", encoding="ascii", errors="replace")


def parse_lines(lines: Iterator[str] | list[str]) -> CarmenLog:
    """Parse CARMEN text lines; unknown messages and malformed lines are counted, not fatal."""
    result = CarmenLog()
    robot_lasers: list[CarmenScan] = []
    for line in lines:
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        kind = tokens[0]
        try:
            if kind == "FLASER":
                result.scans.append(_parse_flaser(tokens))
            elif kind == "ROBOTLASER1":
                robot_lasers.append(_parse_robotlaser1(tokens))
            elif kind == "ODOM":
                result.odometry.append(_parse_odom(tokens))
            elif kind == "PARAM" and len(tokens) >= 3:
                result.params[tokens[1]] = tokens[2]
            else:
                result.skipped[f"unused {kind}"] += 1
        except (ValueError, IndexError):
            result.skipped[f"malformed {kind}"] += 1
    if robot_lasers:
        # a logger that writes both prints every front-laser scan twice; ROBOTLASER1 says
        # its own geometry, FLASER leaves it to a guess from the beam count
        if result.scans:
            result.skipped["FLASER beside ROBOTLASER1"] += len(result.scans)
        result.scans = robot_lasers
    else:
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
        raise InputFormatError(f"{path}: no FLASER or ROBOTLASER1 line")
    log.info(
        "carmen log read",
        path=str(path),
        scans=len(result.scans),
        odometry=len(result.odometry),
        skipped=dict(result.skipped),
        range_limit_m=result.range_limit_m,
    )
    return result
