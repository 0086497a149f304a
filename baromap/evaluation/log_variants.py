"""CARMEN logs rewritten the way real logs differ from the ones at hand, for the mapping gate.

The public logs carry GMapping's corrected poses and no usable odometry, so the gate makes raw
logs of them: odometry made from the corrected poses by a seeded error model, written both as
``ODOM`` lines and as the robot pose of every ``FLASER`` line, as a raw CARMEN log has it.
Everything then goes through ``baromap import carmen`` and ``baromap build-maps`` as a user's
log would, and the result is scored against the corrected poses.

What real logs do that the published ones may not:

- odometry only at the scan times (a logger throttled to the laser), or at 10 Hz between them;
- pauses of 2-40 s between two scans with nothing logged (the robot waiting at a door or an
  elevator, a throttled logger);
- a base that counts from zero again after a pause (power-cycled), in a frame of its own;
- a robot standing for half a minute while the laser goes on and the odometry says nothing
  (a base that publishes only when it moves);
- broken stamps: one value for the whole log, zeros, or negative and then wrapped at 32 bits;
- every k-th scan only, and odometry worse than the synthesis default in ways it never is:
  distance and turn scale errors of several percent, a creep that wanders, slip bursts, noise
  several times the default's.

Each variant is deterministic from its seed. The gate keeps nothing of the library's odometry
synthesis (:mod:`baromap.odometry.synthesis`): its inputs stay the same while that changes.
"""

from __future__ import annotations

import gzip
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from baromap.arrays import FloatArray, IntArray
from baromap.errors import ConfigError, InputFormatError
from baromap.mapping import se2
from baromap.recording.carmen import parse_time_ns

NS_PER_S = 1_000_000_000
#: Scan times of a log whose stamps are broken, for making odometry times between its scans
#: (what the published stamps are instead is written unchanged).
ORDER_INTERVAL_NS = NS_PER_S
#: Mixed into every seed so each part of a variant draws from its own stream.
_ODOMETRY_STREAM, _PAUSE_STREAM, _SLIP_STREAM = 45, 46, 47


@dataclass(frozen=True, slots=True)
class SourceLog:
    """The ``FLASER`` lines of a published log: what a variant is made of."""

    name: str
    #: per scan, the beam count and ranges as printed (written back unchanged)
    beams: list[str]
    laser: FloatArray  # (S, 3) laser pose printed on the line
    reference: FloatArray  # (S, 3) robot pose printed on the line: GMapping's
    stamps: list[str]  # the line's last field, as printed
    #: the stamps as times, None where they do not order the scans (broken as published)
    times_ns: IntArray | None

    def __len__(self) -> int:
        return len(self.beams)


def read_source(path: str | Path, name: str | None = None) -> SourceLog:
    """The ``FLASER`` lines of a CARMEN log (plain or .gz), its stamps kept as text."""
    path = Path(path)
    opener = gzip.open if path.suffix == ".gz" else open
    beams: list[str] = []
    laser: list[list[float]] = []
    robot: list[list[float]] = []
    stamps: list[str] = []
    with opener(path, "rt", encoding="ascii", errors="replace") as handle:
        for line in handle:
            tokens = line.split()
            if not tokens or tokens[0] != "FLASER":
                continue
            n = int(tokens[1])
            rest = 2 + n
            beams.append(" ".join(tokens[1:rest]))
            laser.append([float(v) for v in tokens[rest : rest + 3]])
            robot.append([float(v) for v in tokens[rest + 3 : rest + 6]])
            stamps.append(tokens[-1])
    if not beams:
        raise InputFormatError(f"{path}: no FLASER line")
    return SourceLog(
        name or path.name,
        beams,
        np.array(laser),
        np.array(robot),
        stamps,
        _times(stamps),
    )


def _times(stamps: list[str]) -> IntArray | None:
    """The stamps as times if they order the scans (positive, increasing), else None."""
    try:
        t = np.array([parse_time_ns(s) for s in stamps], dtype=np.int64)
    except ValueError:
        return None
    if len(t) and (t[0] <= 0 or np.any(np.diff(t) <= 0)):
        return None
    return t


@dataclass(frozen=True, slots=True)
class OdometryErrors:
    """How the gate's odometry goes wrong, step by step in the robot's frame.

    ``noise`` scales the synthesis default's random part (2 % of the step along and across,
    0.5 deg per metre and 2 % of the turn). ``wander``: the creep and the scale walk along
    the path (deg/m and per cent per square root of 100 m: slow drift, a tyre warming up, a
    load shifting). ``slips_per_100m``: bursts where the wheels spin or skid, each adding
    0.1-0.4 m of forward reading and a turn error of 4 degrees (one sigma) to one step.
    """

    scale: float = 0.05
    turn_scale: float = 0.0
    creep_deg_per_m: float = 2.0
    noise: float = 1.0
    wander: float = 0.0
    slips_per_100m: float = 0.0


#: The error models the gate names. ``default`` is the synthesis default's size and shape.
ODOMETRY = {
    "default": OdometryErrors(),
    "scale": OdometryErrors(scale=-0.06, turn_scale=0.05, creep_deg_per_m=0.5),
    "drift": OdometryErrors(scale=0.02, creep_deg_per_m=1.0, wander=1.5),
    "slip": OdometryErrors(slips_per_100m=5.0),
    "noisy": OdometryErrors(noise=3.0),
    # diagnoses, in no gate case: the reference itself (how far the scans alone move a SLAM
    # off the reference, apart from what odometry's errors leave in it); the default's scale
    # and creep without its noise; its noise without scale or creep
    "exact": OdometryErrors(scale=0.0, creep_deg_per_m=0.0, noise=0.0),
    "noiseless": OdometryErrors(noise=0.0),
    "unbiased": OdometryErrors(scale=0.0, creep_deg_per_m=0.0),
}


def degrade(reference: FloatArray, seed: int, errors: OdometryErrors) -> FloatArray:
    """Odometry poses (S, 3) from reference poses (S, 3), starting at the first of them."""
    ref = np.asarray(reference, dtype=np.float64)
    out = np.empty_like(ref)
    if len(ref) == 0:
        return out
    step = se2.between(ref[:-1], ref[1:])
    fwd, side, turn = step[:, 0], step[:, 1], step[:, 2]
    dist = np.hypot(fwd, side)
    rng = np.random.default_rng([_ODOMETRY_STREAM, seed])
    n = len(dist)
    walk = np.zeros((n, 2))
    if errors.wander > 0 and n:
        # a Brownian path over the distance driven, one unit per square root of 100 m
        dw = rng.standard_normal((n, 2)) * np.sqrt(np.maximum(dist, 0.0) / 100.0)[:, None]
        walk = np.cumsum(dw, axis=0) * errors.wander
    scale = 1.0 + errors.scale + walk[:, 1] / 100.0
    creep = np.radians(errors.creep_deg_per_m + walk[:, 0])
    k = errors.noise
    fwd_o = fwd * scale + rng.standard_normal(n) * 0.02 * k * dist
    side_o = side * scale + rng.standard_normal(n) * 0.02 * k * dist
    rot_sigma = k * (math.radians(0.5) * dist + 0.02 * np.abs(turn))
    turn_o = turn * (1.0 + errors.turn_scale) + creep * dist + rng.standard_normal(n) * rot_sigma
    if errors.slips_per_100m > 0 and n:
        slip_rng = np.random.default_rng([_SLIP_STREAM, seed])
        starts = slip_rng.random(n) < 1.0 - np.exp(-errors.slips_per_100m * dist / 100.0)
        fwd_o = fwd_o + starts * slip_rng.uniform(0.1, 0.4, n) * np.sign(fwd + 1e-12)
        turn_o = turn_o + starts * slip_rng.standard_normal(n) * math.radians(4.0)
    out[0] = ref[0]
    pose = ref[0].copy()
    for i in range(n):
        pose = se2.compose(pose, np.array([fwd_o[i], side_o[i], turn_o[i]]))
        out[i + 1] = pose
    return out


#: How a variant times its lines (see the module docstring).
TIMINGS = ("scan", "10hz", "pauses", "reset", "quiet")
#: Stamps written instead of the times: as the timing made them, or broken like a published log.
STAMPS = ("asis", "constant", "zero", "wrap")
ODOMETRY_HZ = 10.0
PAUSES = 10
PAUSE_S = (2.0, 40.0)
#: The reset: a pause this long, after which the base counts from zero in a frame of its own.
RESET_PAUSE_S = 20.0
#: The robot standing with the laser on and the odometry silent: so many times, this long,
#: scanning this often.
QUIET_STANDS = 4
QUIET_S = (20.0, 40.0)
QUIET_SCAN_HZ = 2.0


@dataclass(frozen=True, slots=True)
class Variant:
    odometry: str = "default"
    timing: str = "scan"
    stamps: str = "asis"
    stride: int = 1
    part: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if self.odometry not in ODOMETRY:
            raise ConfigError(f"odometry model {self.odometry!r}: one of {', '.join(ODOMETRY)}")
        if self.timing not in TIMINGS:
            raise ConfigError(f"timing {self.timing!r}: one of {', '.join(TIMINGS)}")
        if self.stamps not in STAMPS:
            raise ConfigError(f"stamps {self.stamps!r}: one of {', '.join(STAMPS)}")
        if self.stride < 1:
            raise ConfigError(f"stride must be at least 1, got {self.stride}")


@dataclass(slots=True)
class VariantLog:
    """A variant's CARMEN text and what scoring it needs."""

    lines: list[str]
    #: the kept scans' indices in the source log, in the variant's order
    source_index: IntArray
    reference: FloatArray  # (S, 3) corrected poses of the kept scans
    #: the stamps written on the kept scans' lines, None where they are broken on purpose
    #: (or as published): the imported run's times are then the importer's own
    scan_ns: IntArray | None
    #: scans the variant adds (the robot standing with the laser on), not scored
    extra_scans: int = 0
    events: list[str] = field(default_factory=list)

    def write(self, path: Path) -> None:
        path.write_text("\n".join(self.lines) + "\n", encoding="ascii")


def _stamp(t_ns: int) -> str:
    return f"{t_ns // NS_PER_S}.{(t_ns % NS_PER_S) // 1000:06d}"


def _micro(t_ns: IntArray) -> IntArray:
    """Times as printed to the microsecond (what a reader of the text gets back)."""
    return np.asarray((t_ns // 1000) * 1000, dtype=np.int64)


def _interpolate(t_src: IntArray, poses: FloatArray, t: IntArray) -> FloatArray:
    theta = np.unwrap(poses[:, 2])
    q = t.astype(np.float64)
    s = t_src.astype(np.float64)
    out = np.stack(
        [np.interp(q, s, poses[:, 0]), np.interp(q, s, poses[:, 1]), np.interp(q, s, theta)],
        axis=1,
    )
    out[:, 2] = se2.wrap(out[:, 2])
    return out


def make_variant(source: SourceLog, variant: Variant, seed: int) -> VariantLog:
    """The variant of ``source`` for ``seed``."""
    index = np.arange(len(source))
    if variant.part is not None:
        index = index[variant.part[0] : variant.part[1]]
    index = index[:: variant.stride]
    if len(index) < 2:
        raise ConfigError("a variant needs at least two scans")
    broken = source.times_ns is None
    if broken and (variant.timing != "scan" or variant.stamps != "asis"):
        raise ConfigError(f"{source.name}: its stamps are broken; only scan timing, as published")
    reference = source.reference[index]
    odom = degrade(reference, seed, ODOMETRY[variant.odometry])
    # the laser's pose on each line: the odometry's, moved as the corrected poses have it
    mount = se2.between(reference, source.laser[index])
    laser = se2.compose(odom, mount)
    if source.times_ns is None:
        t = np.arange(1, len(index) + 1, dtype=np.int64) * ORDER_INTERVAL_NS
    else:
        t = source.times_ns[index].copy()
    rng = np.random.default_rng([_PAUSE_STREAM, seed])
    events: list[str] = []
    # (time, order, line) rows; order puts ODOM before FLASER at one time, as importers do
    odom_rows: list[tuple[int, FloatArray]] = []
    extra: list[tuple[int, int]] = []  # (time, scan repeated) while the robot stands
    reset_at = -1
    if variant.timing == "pauses":
        at = np.sort(
            rng.choice(np.arange(1, len(index)), size=min(PAUSES, len(index) - 1), replace=False)
        )
        for k in at:
            seconds = float(rng.uniform(*PAUSE_S))
            t[k:] += round(seconds * NS_PER_S)
        events.append(f"{len(at)} pauses of {PAUSE_S[0]:g}-{PAUSE_S[1]:g} s, nothing logged")
    elif variant.timing == "reset":
        reset_at = len(index) // 2
        t[reset_at:] += round(RESET_PAUSE_S * NS_PER_S)
        events.append(f"base counts from zero after a {RESET_PAUSE_S:g} s pause at scan {reset_at}")
    elif variant.timing == "quiet":
        at = np.sort(
            rng.choice(
                np.arange(1, len(index)), size=min(QUIET_STANDS, len(index) - 1), replace=False
            )
        )
        for k in at:
            seconds = float(rng.uniform(*QUIET_S))
            shift = round(seconds * NS_PER_S)
            step = round(NS_PER_S / QUIET_SCAN_HZ)
            extra += [(int(t[k - 1]) + j * step, int(k - 1)) for j in range(1, int(shift // step))]
            t[k:] += shift
        events.append(
            f"{len(at)} stands of {QUIET_S[0]:g}-{QUIET_S[1]:g} s, the laser on, odometry silent"
        )
    t = _micro(t)
    if variant.timing in ("scan", "pauses"):
        odom_rows = [(int(ti), odom[i]) for i, ti in enumerate(t)]
    else:
        # 10 Hz between the scans and at every scan, but none while the robot stands
        grid = np.arange(t[0], t[-1], round(NS_PER_S / ODOMETRY_HZ), dtype=np.int64)
        times = _micro(np.union1d(grid, t))
        if variant.timing in ("reset", "quiet"):
            # nothing logged within the pauses: only the scans' own samples at their ends
            nxt = np.searchsorted(t, times, side="left")
            prv = np.clip(nxt - 1, 0, len(t) - 1)
            nxt = np.clip(nxt, 0, len(t) - 1)
            long_step = (t[nxt] - t[prv]) > 5 * NS_PER_S
            times = times[~long_step | np.isin(times, t)]
        poses = _interpolate(t, odom, times)
        odom_rows = [(int(ti), p) for ti, p in zip(times, poses, strict=True)]
    if reset_at > 0:
        origin = odom[reset_at]
        odom_rows = [
            (ti, se2.between(origin, p) if ti >= t[reset_at] else p) for ti, p in odom_rows
        ]
        laser[reset_at:] = se2.between(origin, laser[reset_at:])
        odom = odom.copy()
        odom[reset_at:] = se2.between(origin, odom[reset_at:])
    # (time, kind, text); kind 0 (ODOM) sorts before 1 (FLASER) at one time, as importers do
    rows: list[tuple[int, int, str]] = [
        (ti, 0, f"ODOM {p[0]:.6f} {p[1]:.6f} {p[2]:.6f} 0 0 0") for ti, p in odom_rows
    ]
    rows += [
        (int(ti), 1, _flaser(source.beams[index[i]], laser[i], odom[i])) for i, ti in enumerate(t)
    ]
    rows += [(ti, 1, _flaser(source.beams[index[k]], laser[k], odom[k])) for ti, k in extra]
    rows.sort(key=lambda r: (r[0], r[1]))
    published = [source.stamps[i] for i in index]
    lines = []
    for number, (ti, _, text) in enumerate(rows):
        if variant.stamps != "asis":
            stamp = _broken_stamp(variant.stamps, number, len(rows))
        elif broken:
            # as published: each line the text of its scan (odometry is at the scan times)
            stamp = published[min(int(np.searchsorted(t, ti, side="right")) - 1, len(t) - 1)]
        else:
            stamp = _stamp(ti)
        lines.append(f"{text} {stamp} gate {stamp}")
    keep_times = variant.stamps == "asis" and not broken
    return VariantLog(
        lines=lines,
        source_index=index,
        reference=reference,
        scan_ns=t if keep_times else None,
        extra_scans=len(extra),
        events=events,
    )


def _flaser(beams: str, laser: FloatArray, odom: FloatArray) -> str:
    return (
        f"FLASER {beams} {laser[0]:.6f} {laser[1]:.6f} {laser[2]:.6f} "
        f"{odom[0]:.6f} {odom[1]:.6f} {odom[2]:.6f}"
    )


def _broken_stamp(kind: str, number: int, lines: int) -> str:
    """Line ``number``'s stamp broken as published logs break them: one value for the whole
    log, zeros, or negative and falling for the first tenth of the lines, then wrapped at
    32 bits."""
    if kind == "constant":
        return "1.01893e+09"
    if kind == "zero":
        return "0"
    if number < lines // 10:
        return f"{-0.042 * (number + 1):.6g}"
    return "4.29497e+09"
