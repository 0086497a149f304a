"""CARMEN logs into baromap: scans and odometry as messages, written as a recording.

The log's reference poses become odometry only through the seeded error model of
:mod:`baromap.odometry` when the log has no raw odometry of its own (a "corrected" log).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import structlog

from baromap.errors import ConfigError
from baromap.messages import BeamFlag, LaserScan, Odometry
from baromap.odometry.synthesis import synthesize_odometry
from baromap.recording.carmen import CarmenLog, CarmenScan, read_carmen

log = structlog.get_logger(__name__)

#: CARMEN's parameters for the front laser's place on the robot (carmen.ini): ahead of the
#: centre, to its left (metres), and turned (radians).
MOUNT_PARAMS = (
    "robot_frontlaser_offset",
    "robot_frontlaser_side_offset",
    "robot_frontlaser_angular_offset",
)
#: A declared mount and the lines' own differ when apart by more than this (m, rad): the
#: lines print poses to a millimetre or so.
MOUNT_AGREE_M = 0.005
MOUNT_AGREE_RAD = 0.005


def to_laser_scan(scan: CarmenScan, index: int) -> LaserScan:
    """CARMEN ranges as a baromap scan: no-return markers become NaN flagged OVER_RANGE."""
    ranges = scan.ranges_m.astype(np.float32)
    bad = ~np.isfinite(ranges) | (ranges >= scan.range_max_m) | (ranges <= 0.0)
    flags = np.where(bad, np.uint16(BeamFlag.OVER_RANGE), np.uint16(0)).astype(np.uint16)
    ranges = np.where(bad, np.float32(np.nan), ranges)
    return LaserScan(
        t_ns=scan.t_ns,
        angle_min_rad=scan.angle_min_rad,
        angle_increment_rad=scan.angle_increment_rad,
        range_max_m=scan.range_max_m,
        ranges_m=ranges,
        flags=flags,
        scan_index=index,
    )


#: The recording's metadata record of what the importer did, and its key saying where the
#: times came from: the log's stamps, the stamps with broken ones replaced by their
#: neighbours', or the scan order (the stamps could not order the scans: the times are no
#: clock, and a speed worked out from them means nothing).
METADATA_NAME = "baromap.carmen"
STAMPS_KEY = "stamps"
STAMPS_LOGGED = "logged"
STAMPS_REPAIRED = "repaired"
STAMPS_FROM_ORDER = "scan order"

#: Where a log's odometry is read from: its ``ODOM`` lines, or the robot pose its laser lines
#: print (in a raw log that pose is the wheels' own; in a "corrected" one it is a SLAM solution).
#: The recording's metadata names each source by its label here.
_SOURCE_LABEL = {"odom": "recorded", "laser": "laser lines"}
ODOMETRY_SOURCES = tuple(_SOURCE_LABEL)


def odometry_messages(
    carmen: CarmenLog, synth_seed: int | None, source: str = "odom"
) -> list[Odometry]:
    """The log's own odometry (from ``source``), or odometry synthesised from its reference
    poses when ``synth_seed`` is given."""
    if source not in ODOMETRY_SOURCES:
        raise ConfigError(f"odometry source {source!r}: expected one of {ODOMETRY_SOURCES}")
    if synth_seed is not None or source == "laser":
        poses = carmen.reference_poses()
        if synth_seed is not None:
            poses = synthesize_odometry(poses, synth_seed)
        times = carmen.scan_times_ns()
        return [
            Odometry(t_ns=int(t), x_m=float(p[0]), y_m=float(p[1]), theta_rad=float(p[2]))
            for t, p in zip(times, poses, strict=True)
        ]
    if not carmen.has_odometry():
        raise ConfigError(
            "this log carries no raw odometry (its ODOM lines are missing or all zero); "
            "pass --odometry-from laser if the pose its laser lines print is the wheels' own "
            "(a raw log), or --synth-odometry SEED to synthesise odometry from those poses "
            "(a corrected log)"
        )
    return [
        Odometry(
            t_ns=o.t_ns,
            x_m=o.x_m,
            y_m=o.y_m,
            theta_rad=o.theta_rad,
            v_mps=o.v_mps,
            omega_radps=o.omega_radps,
        )
        for o in carmen.odometry
    ]


def laser_offset(carmen: CarmenLog) -> tuple[float, float, float]:
    """Mounting of the laser on the robot: the laser pose in the robot's frame.

    A ``FLASER`` or ``ROBOTLASER1`` line carries both poses; where they differ (a laser
    mounted ahead of the wheels' axle, as on most Pioneers) the scans are taken at the laser
    while the reference poses and the odometry are the robot's. The median over the scans,
    so one line printed with a rounded or stale pose cannot set it.
    """
    laser = np.array([s.laser_pose for s in carmen.scans], dtype=np.float64).reshape(-1, 3)
    robot = carmen.reference_poses()
    c, s = np.cos(robot[:, 2]), np.sin(robot[:, 2])
    dx, dy = laser[:, 0] - robot[:, 0], laser[:, 1] - robot[:, 1]
    dtheta = laser[:, 2] - robot[:, 2]
    # about the circular mean, so a laser facing backwards (near +-180 deg) is not split in two
    centre = math.atan2(float(np.mean(np.sin(dtheta))), float(np.mean(np.cos(dtheta))))
    around = np.remainder(dtheta - centre + math.pi, math.tau) - math.pi
    turn = math.remainder(centre + float(np.median(around)), math.tau)
    return (
        float(np.median(c * dx + s * dy)),
        float(np.median(-s * dx + c * dy)),
        turn,
    )


def declared_mount(carmen: CarmenLog) -> tuple[float, float, float] | None:
    """The laser's pose on the robot as the log's ``PARAM`` lines declare it, or None where
    they say nothing (or nothing that reads as a number)."""
    if not any(name in carmen.params for name in MOUNT_PARAMS):
        return None
    try:
        x, y, turn = (float(carmen.params.get(name, "0")) for name in MOUNT_PARAMS)
    except ValueError:
        return None
    if not all(math.isfinite(v) for v in (x, y, turn)):
        return None
    return (x, y, turn)


def check_mount(carmen: CarmenLog, offset: tuple[float, float, float], path: str) -> bool:
    """Warn where the log's ``PARAM`` lines put the laser elsewhere on the robot than its laser
    lines' two poses do; returns whether they disagree.

    The lines are followed: a raw log prints the laser's pose as the robot's moved by the
    mount, so the two agree; a "corrected" log (a SLAM's poses, written into both fields)
    shows no mount although its robot had one. Its poses, and so ``trajectory.tum``, are then
    the laser's, while ground truth of the robot's motion (Freiburg 079's relations) is the
    robot centre's: a trajectory turned back on itself differs from it by twice the mount."""
    declared = declared_mount(carmen)
    if declared is None:
        return False
    apart = math.hypot(declared[0] - offset[0], declared[1] - offset[1])
    turned = abs(math.remainder(declared[2] - offset[2], math.tau))
    if apart <= MOUNT_AGREE_M and turned <= MOUNT_AGREE_RAD:
        return False
    log.warning(
        "laser mount declared elsewhere than the lines put it; the lines' poses are followed",
        path=path,
        declared=" ".join(f"{v:.3f}" for v in declared),
        lines=" ".join(f"{v:.3f}" for v in offset),
    )
    return True


def import_carmen(
    log_path: str | Path,
    out_path: str | Path,
    synth_seed: int | None = None,
    odometry_from: str = "odom",
) -> dict[str, Any]:
    """Write a CARMEN log as a baromap recording; returns counts for the caller to print.
    ``odometry_from`` is one of :data:`ODOMETRY_SOURCES`; ``synth_seed`` degrades the laser
    lines' poses instead (a corrected log).

    The recording is written under a temporary name beside ``out_path`` and renamed when
    whole: a failed import leaves nothing behind that a second try would refuse to replace.
    An existing ``out_path`` is refused before the log is read."""
    from baromap.recording import RecordingWriter

    if synth_seed is not None and odometry_from != "odom":
        raise ConfigError("synthesised odometry replaces the log's own: give one or the other")
    out = Path(out_path)
    if out.exists():
        raise ConfigError(f"{out} exists: remove it or give another output")
    carmen = read_carmen(log_path)
    odometry = odometry_messages(carmen, synth_seed, odometry_from)
    offset = laser_offset(carmen)
    check_mount(carmen, offset, str(log_path))
    repair = carmen.stamps
    metadata = {
        "source": str(log_path),
        "odometry": "synthesised" if synth_seed is not None else _SOURCE_LABEL[odometry_from],
        "synth_seed": "" if synth_seed is None else str(synth_seed),
        "laser_offset": " ".join(f"{v:.6f}" for v in offset),
        "range_limit_m": "" if carmen.range_limit_m is None else f"{carmen.range_limit_m:.3f}",
        STAMPS_KEY: (
            STAMPS_LOGGED
            if repair is None
            else STAMPS_FROM_ORDER
            if repair.from_order
            else STAMPS_REPAIRED
        ),
        "stamps_replaced": "0" if repair is None else str(repair.scans + repair.odometry),
    }
    scans = [to_laser_scan(s, i) for i, s in enumerate(carmen.scans)]
    merged: list[LaserScan | Odometry] = [*scans, *odometry]
    merged.sort(key=lambda m: (m.t_ns, 0 if isinstance(m, Odometry) else 1))
    partial = out.with_name(f".{out.name}.{os.getpid()}.partial")
    try:
        with RecordingWriter(partial, robot="carmen", allow_overwrite=True) as writer:
            writer.write_metadata(METADATA_NAME, metadata)
            for message in merged:
                writer.write(message)
        partial.replace(out)
    finally:
        partial.unlink(missing_ok=True)
    return {
        "scans": len(scans),
        "odometry": len(odometry),
        "skipped": dict(carmen.skipped),
        "range_limit_m": carmen.range_limit_m,
        "stamps": None if repair is None else repair.summary(),
    }
