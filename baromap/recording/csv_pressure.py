"""Pressure logs as CSV: ``time_s,pressure_pa[,temperature_c]``, and ``baromap import csv``.

The lowest common denominator of barometer loggers (a phone app, a bench logger, a
spreadsheet). A header line is optional; ``#`` starts a comment. Lines that do not parse are
skipped and counted; pressures outside 300-1200 hPa mean the file is in another unit (hPa,
kPa) and are refused with a message saying so, rather than silently treated as pascals, and so
are temperatures no air has (a kelvin column would make every height 2 % wrong, and below
absolute zero the hypsometric equation has no answer).

A reference station's log has the same shape; ``--reference`` puts it on
``/reference/pressure`` of the recording.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import structlog

from baromap.errors import InputFormatError
from baromap.messages import NS_PER_S, PressureSample
from baromap.recording.reader import PressureSeries
from baromap.recording.text_logs import parse_text_log

log = structlog.get_logger(__name__)

MIN_PA = 30_000.0
MAX_PA = 120_000.0
#: Air temperatures a barometer can report (the BMP280's own operating range).
MIN_C = -40.0
MAX_C = 85.0
#: Times must fit int64 nanoseconds: about 292 years either side of 1970.
MAX_ABS_TIME_S = 9.2e9
#: Longer lines are not this format (bounds the memory a bad file can take per line).
MAX_LINE_CHARS = 1024


def read_csv_pressure(path: str | Path) -> PressureSeries:
    return parse_text_log(path, parse_csv_pressure)


def parse_csv_pressure(lines: Iterable[str], source: str = "<csv>") -> PressureSeries:
    times: list[int] = []
    pressures: list[float] = []
    temperatures: list[float] = []
    skipped: Counter[str] = Counter()
    seen_data = False
    for raw in lines:
        if len(raw) > MAX_LINE_CHARS:
            skipped["long line"] += 1
            continue
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        fields = [f.strip() for f in line.replace(";", ",").split(",")]
        try:
            t_s = float(fields[0])
            p = float(fields[1])
            temp = float(fields[2]) if len(fields) > 2 and fields[2] else math.nan
        except (IndexError, ValueError):
            if not seen_data and not times:
                seen_data = True  # a header line
                continue
            skipped["unparsable"] += 1
            continue
        seen_data = True
        if not (math.isfinite(t_s) and math.isfinite(p)):
            skipped["not finite"] += 1
            continue
        if abs(t_s) > MAX_ABS_TIME_S:
            raise InputFormatError(f"{source}: time {t_s} is not in seconds")
        if not MIN_PA <= p <= MAX_PA:
            raise InputFormatError(
                f"{source}: pressure {p} is not in pascals (expected {MIN_PA:.0f}-{MAX_PA:.0f});"
                " convert hPa/mbar by multiplying by 100"
            )
        if not (math.isnan(temp) or MIN_C <= temp <= MAX_C):
            raise InputFormatError(
                f"{source}: temperature {temp} is not in degrees Celsius "
                f"(expected {MIN_C:.0f} to {MAX_C:.0f})"
            )
        times.append(round(t_s * NS_PER_S))
        pressures.append(p)
        temperatures.append(temp)
    if not times:
        raise InputFormatError(f"{source}: no time_s,pressure_pa rows")
    if skipped:
        log.debug("csv lines skipped", source=source, **dict(skipped))
    t = np.asarray(times, dtype=np.int64)
    order = np.argsort(t, kind="stable")
    t = t[order]
    keep = np.concatenate(([True], np.diff(t) > 0))
    return PressureSeries(
        t[keep],
        np.asarray(pressures, dtype=np.float64)[order][keep],
        np.asarray(temperatures, dtype=np.float64)[order][keep],
    )


def samples(series: PressureSeries) -> list[PressureSample]:
    """The series as messages (temperature None where the file had none)."""
    return [
        PressureSample(int(t), float(p), None if math.isnan(c) else float(c))
        for t, p, c in zip(series.t_ns, series.pressure_pa, series.temperature_c, strict=True)
    ]


def import_csv(path: str | Path, output: str | Path, reference: str | Path | None = None) -> int:
    """Write a CSV pressure log (and optionally a reference station's) as a recording."""
    from baromap.recording import RecordingWriter, topics

    series = read_csv_pressure(path)
    ref = read_csv_pressure(reference) if reference is not None else None
    with RecordingWriter(output, robot="csv", metadata={"source": str(path)}) as writer:
        for sample in samples(series):
            writer.write(sample)
        if ref is not None:
            for sample in samples(ref):
                writer.write(sample, topic=topics.REFERENCE_PRESSURE)
    return int(series.t_ns.size)
