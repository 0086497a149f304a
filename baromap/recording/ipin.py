"""Reader for IPIN competition logs (the ``GetSensorData`` Android app's text format).

These logs are the real, labelled barometer data we test floor detection against: a person
walks a building with a smartphone, the app logs every sensor as ``TYPE;AppTimestamp;...``
lines, and surveyed waypoints (``POSI``) say which floor they were on at which moment.

Two clocks are in the file. ``AppTimestamp`` is when the app read a value (the common clock of
all sensors and of the waypoints, seconds since the log started); ``SensorTimestamp`` is the
sensor's own clock, whose *differences* are the true sampling intervals. Pressure samples are
put on the app clock by the sensor clock plus the median offset between the two, so their
spacing is the sensor's and their epoch the waypoints'. Times are nanoseconds of that app clock
(not of the Unix epoch): the log gives only a local creation date to the second.

Lines that do not parse are skipped and counted; a file with no ``PRES`` line is an
:class:`~baromap.errors.InputFormatError`.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt
import structlog

from baromap.errors import InputFormatError
from baromap.messages import NS_PER_S
from baromap.recording.text_logs import parse_text_log

log = structlog.get_logger(__name__)

#: What the app writes in the first comment lines; used to recognise the format.
APP_SIGNATURE = "GetSensorData"
PA_PER_MBAR = 100.0
#: A sensor line is far shorter; a longer one is not this format (bounds memory per line).
MAX_LINE_CHARS = 4096
#: App and sensor clocks count seconds since the log (or the phone) started; beyond this a
#: stamp is garbage, and it would not fit int64 nanoseconds anyway.
MAX_ABS_TIME_S = 1e9


@dataclass(frozen=True, slots=True)
class Waypoint:
    """A surveyed ground-truth point: the walker was here, on ``floor``, at ``t_ns``."""

    t_ns: int
    index: int
    latitude_deg: float
    longitude_deg: float
    floor: int
    building: int


@dataclass(frozen=True, slots=True, eq=False)
class IpinLog:
    """Pressure and waypoints of one IPIN log; times in ns of the log's app clock."""

    t_ns: npt.NDArray[np.int64]
    pressure_pa: npt.NDArray[np.float64]
    waypoints: tuple[Waypoint, ...]
    phone: str = ""
    skipped: Counter[str] = field(default_factory=Counter)


def looks_like_ipin(head: str) -> bool:
    """Whether the first kilobytes of a text file are an IPIN/GetSensorData log."""
    if APP_SIGNATURE in head:
        return True
    return any(line.startswith(("PRES;", "POSI;", "ACCE;")) for line in head.splitlines()[:50])


def read_ipin(path: str | Path) -> IpinLog:
    """Read pressure samples and waypoints of an IPIN log."""
    return parse_text_log(path, parse_ipin)


def _time_s(text: str) -> float:
    value = float(text)
    if not abs(value) <= MAX_ABS_TIME_S:  # also NaN
        raise ValueError(f"time {text!r} out of range")
    return value


def parse_ipin(lines: Iterable[str], source: str = "<ipin>") -> IpinLog:
    app_s: list[float] = []
    sensor_s: list[float] = []
    pressure: list[float] = []
    waypoints: list[Waypoint] = []
    skipped: Counter[str] = Counter()
    phone = ""
    for raw in lines:
        if len(raw) > MAX_LINE_CHARS:
            skipped["long line"] += 1
            continue
        line = raw.strip()
        if not line:
            continue
        if line.startswith("%"):
            if "Model:" in line:
                phone = line.split("Model:", 1)[1].strip()
            continue
        kind, _, rest = line.partition(";")
        if kind == "PRES":
            fields = rest.split(";")
            try:
                t_app, t_sensor, mbar = _time_s(fields[0]), _time_s(fields[1]), float(fields[2])
            except (IndexError, ValueError):
                skipped["bad PRES"] += 1
                continue
            if not 300.0 < mbar < 1200.0:
                skipped["bad PRES"] += 1
                continue
            app_s.append(t_app)
            sensor_s.append(t_sensor)
            pressure.append(mbar * PA_PER_MBAR)
        elif kind == "POSI":
            fields = rest.split(";")
            try:
                waypoints.append(
                    Waypoint(
                        t_ns=round(_time_s(fields[0]) * NS_PER_S),
                        index=int(fields[1]),
                        latitude_deg=float(fields[2]),
                        longitude_deg=float(fields[3]),
                        floor=int(float(fields[4])),
                        building=int(float(fields[5])) if len(fields) > 5 and fields[5] else 0,
                    )
                )
            except (IndexError, ValueError, OverflowError):  # int(inf) overflows
                skipped["bad POSI"] += 1
    if not pressure:
        if skipped["bad PRES"]:
            raise InputFormatError(
                f"{source}: no usable PRES line: {skipped['bad PRES']} unreadable or outside "
                "300-1200 hPa"
            )
        raise InputFormatError(f"{source}: no PRES lines, not an IPIN pressure log")
    t_ns = _app_clock_ns(np.asarray(app_s), np.asarray(sensor_s))
    p = np.asarray(pressure, dtype=np.float64)
    order = np.argsort(t_ns, kind="stable")
    t_ns, p = t_ns[order], p[order]
    keep = np.concatenate(([True], np.diff(t_ns) > 0))
    if not keep.all():
        skipped["repeated time"] += int((~keep).sum())
        t_ns, p = t_ns[keep], p[keep]
    if skipped:
        log.debug("ipin lines skipped", source=source, **dict(skipped))
    waypoints.sort(key=lambda w: w.t_ns)
    return IpinLog(t_ns, p, tuple(waypoints), phone, skipped)


def _app_clock_ns(
    app_s: npt.NDArray[np.float64], sensor_s: npt.NDArray[np.float64]
) -> npt.NDArray[np.int64]:
    """Sensor-clock spacing on the app clock's epoch (see the module docstring).

    If the sensor clock is unusable (not increasing, or wandering more than a few seconds from
    the app clock over the log), the app clock is taken as it is.
    """
    offset = app_s - sensor_s
    median = float(np.median(offset))
    if np.all(np.diff(sensor_s) > 0) and np.max(np.abs(offset - median)) < 2.0:
        seconds = sensor_s + median
    else:
        seconds = app_s
    return np.round(seconds * NS_PER_S).astype(np.int64)
