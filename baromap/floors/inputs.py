"""Pressure inputs for detection and evaluation, by sniffing the file: MCAP recording, IPIN log
or CSV. Each comes with the ground truth it carries, if any (simulator truth topics, IPIN
waypoints), and a reference station's pressure and the robot's odometry when a recording has
them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from baromap.errors import InputFormatError
from baromap.floors.evaluation import FloorTruth, truth_from_series, truth_from_waypoints
from baromap.messages import Odometry
from baromap.recording.reader import PressureSeries

MCAP_MAGIC = b"\x89MCAP"

#: ``(t_ns, x_m, y_m)`` of the robot's odometry.
OdometrySeries = tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64]]


@dataclass(frozen=True, slots=True, eq=False)
class FloorInput:
    kind: str
    series: PressureSeries
    truth: FloorTruth | None = None
    reference: PressureSeries | None = None
    odometry: OdometrySeries | None = None


def sniff(path: str | Path) -> str:
    """``"mcap"``, ``"ipin"`` or ``"csv"``."""
    from baromap.recording.ipin import looks_like_ipin

    try:
        with open(path, "rb") as handle:
            head = handle.read(8192)
    except OSError as exc:
        raise InputFormatError(f"cannot read {path}: {exc}") from exc
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if Path(path).suffix.lower() == ".mcap":
        # Read as CSV it would only say "no time_s,pressure_pa rows": say what it is not.
        raise InputFormatError(f"{path} is named .mcap but is not an MCAP recording")
    if looks_like_ipin(head.decode("utf-8", errors="replace")):
        return "ipin"
    return "csv"


def load_input(path: str | Path) -> FloorInput:
    kind = sniff(path)
    if kind == "ipin":
        from baromap.recording.ipin import read_ipin

        log = read_ipin(path)
        series = PressureSeries(log.t_ns, log.pressure_pa, np.full(log.t_ns.shape, np.nan))
        truth = (
            truth_from_waypoints([(w.t_ns, w.floor) for w in log.waypoints])
            if log.waypoints
            else None
        )
        return FloorInput(kind, series, truth)
    if kind == "csv":
        from baromap.recording.csv_pressure import read_csv_pressure

        return FloorInput(kind, read_csv_pressure(path))
    return _load_mcap(path)


def _load_mcap(path: str | Path) -> FloorInput:
    """Pressure, reference station, odometry and truth in one pass (each pass decompresses
    the whole file)."""
    from baromap.messages import PressureSample, TruthFloor
    from baromap.recording import pressure_series, read_messages, topics

    samples: dict[str, list[PressureSample]] = {topics.BARO: [], topics.REFERENCE_PRESSURE: []}
    t: list[int] = []
    floors: list[float] = []
    z: list[float] = []
    odometry: list[Odometry] = []
    wanted = [topics.BARO, topics.REFERENCE_PRESSURE, topics.TRUTH_FLOOR, topics.ODOM]
    for rec in read_messages(path, wanted):
        msg = rec.message
        if isinstance(msg, TruthFloor):
            t.append(msg.t_ns)
            floors.append(math.nan if msg.floor is None else float(msg.floor))
            z.append(msg.z_m)
        elif isinstance(msg, Odometry):
            odometry.append(msg)
        elif isinstance(msg, PressureSample) and rec.topic in samples:
            samples[rec.topic].append(msg)
        elif rec.topic not in (topics.TRUTH_FLOOR, topics.ODOM):
            raise InputFormatError(f"{rec.topic} in {path} does not hold pressure samples")
    series = pressure_series(samples[topics.BARO])
    if series.t_ns.size == 0:
        raise InputFormatError(f"{path}: no pressure samples on {topics.BARO}")
    reference = pressure_series(samples[topics.REFERENCE_PRESSURE])
    truth = truth_from_series(t, floors, z) if t else None
    return FloorInput(
        "mcap",
        series,
        truth,
        reference if reference.t_ns.size else None,
        _odometry_series(odometry) if odometry else None,
    )


def load_odometry(path: str | Path) -> OdometrySeries:
    """The robot's odometry from /odom of a recording."""
    from baromap.recording import read_messages, topics

    if sniff(path) != "mcap":
        raise InputFormatError(f"{path}: odometry is read from a recording (.mcap with /odom)")
    poses = []
    for rec in read_messages(path, [topics.ODOM]):
        if not isinstance(rec.message, Odometry):
            raise InputFormatError(f"{topics.ODOM} in {path} does not hold odometry")
        poses.append(rec.message)
    if not poses:
        raise InputFormatError(f"{path}: no {topics.ODOM} messages")
    return _odometry_series(poses)


def _odometry_series(poses: list[Odometry]) -> OdometrySeries:
    return (
        np.array([o.t_ns for o in poses], dtype=np.int64),
        np.array([o.x_m for o in poses], dtype=np.float64),
        np.array([o.y_m for o in poses], dtype=np.float64),
    )


def load_reference(path: str | Path) -> PressureSeries:
    """A reference station's pressure: a CSV, or /reference/pressure of a recording."""
    if sniff(path) == "mcap":
        from baromap.recording import load_pressure, topics

        series = load_pressure(path, topics.REFERENCE_PRESSURE)
        if series.t_ns.size == 0:
            raise InputFormatError(f"{path}: no {topics.REFERENCE_PRESSURE} samples")
        return series
    from baromap.recording.csv_pressure import read_csv_pressure

    return read_csv_pressure(path)
