"""A recording as the arrays mapping works on: scans, odometry at the scan times, pressure.

Odometry and the laser run on their own clocks (10 Hz SIPs, 5-75 Hz scans), so the odometry
pose is interpolated at each scan's stamp; a scan outside the odometry's time span takes the
nearest odometry pose.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import structlog

from baromap import messages
from baromap.errors import InputFormatError
from baromap.mapping.scans import ScanBlock
from baromap.recording import read_messages, read_metadata, topics

log = structlog.get_logger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


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
    out[:, 2] = (out[:, 2] + np.pi) % (2 * np.pi) - np.pi
    return out


def laser_offset_from_metadata(metadata: dict[str, dict[str, str]]) -> FloatArray:
    """Laser mounting in the robot frame, from any metadata record that states it.

    Two spellings exist: ``laser_offset = "x y theta"`` (the CARMEN importer) and
    ``laser_mount = {"x_m", "y_m", "yaw_rad"}`` as JSON (the simulator, the daemon's config).
    """
    for record in metadata.values():
        text = record.get("laser_offset")
        if text:
            try:
                values = [float(v) for v in text.replace(",", " ").split()]
            except ValueError as exc:
                raise InputFormatError(f"laser_offset metadata {text!r}: {exc}") from exc
            if len(values) != 3 or not np.all(np.isfinite(values)):
                raise InputFormatError(f"laser_offset metadata {text!r} is not 'x y theta'")
            return np.array(values)
        mount = record.get("laser_mount")
        if mount:
            try:
                data = json.loads(mount)
                values = [
                    float(data.get("x_m", 0.0)),
                    float(data.get("y_m", 0.0)),
                    float(data.get("yaw_rad", 0.0)),
                ]
            except (ValueError, TypeError, AttributeError) as exc:
                raise InputFormatError(f"laser_mount metadata is not valid JSON: {exc}") from exc
            if not np.all(np.isfinite(values)):
                raise InputFormatError(f"laser_mount metadata {mount!r} is not finite")
            return np.array(values)
    return np.zeros(3)


def load_run(path: str | Path) -> RunData:
    """Read everything mapping needs from a recording in one pass."""
    scans: list[messages.LaserScan] = []
    odom_t: list[int] = []
    odom_p: list[tuple[float, float, float]] = []
    baro_t: list[int] = []
    baro_p: list[float] = []
    baro_temp: list[float] = []
    ref_t: list[int] = []
    ref_p: list[float] = []
    wanted = [topics.SCAN, topics.ODOM, topics.BARO, topics.REFERENCE_PRESSURE]
    for rec in read_messages(path, wanted):
        msg = rec.message
        if rec.topic == topics.REFERENCE_PRESSURE:
            if isinstance(msg, messages.PressureSample):
                ref_t.append(msg.t_ns)
                ref_p.append(msg.pressure_pa)
            continue
        if isinstance(msg, messages.LaserScan):
            scans.append(msg)
        elif isinstance(msg, messages.Odometry):
            odom_t.append(msg.t_ns)
            odom_p.append((msg.x_m, msg.y_m, msg.theta_rad))
        elif isinstance(msg, messages.PressureSample):
            baro_t.append(msg.t_ns)
            baro_p.append(msg.pressure_pa)
            baro_temp.append(np.nan if msg.temperature_c is None else msg.temperature_c)
    if not scans:
        raise InputFormatError(f"{path}: no laser scans on {topics.SCAN}")
    if not odom_t:
        raise InputFormatError(f"{path}: no odometry on {topics.ODOM}")
    metadata = read_metadata(path)
    block = ScanBlock.from_messages(scans, laser_offset_from_metadata(metadata))
    odom = interpolate_poses(
        np.array(odom_t, dtype=np.int64), np.array(odom_p, dtype=np.float64), block.t_ns
    )
    log.info("run loaded", scans=len(block), odometry=len(odom_t), pressure=len(baro_t))
    return RunData(
        scans=block,
        odom=odom,
        pressure_t_ns=np.array(baro_t, dtype=np.int64),
        pressure_pa=np.array(baro_p, dtype=np.float64),
        temperature_c=np.array(baro_temp, dtype=np.float64),
        metadata=metadata,
        reference_t_ns=np.array(ref_t, dtype=np.int64),
        reference_pa=np.array(ref_p, dtype=np.float64),
    )
