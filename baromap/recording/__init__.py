"""MCAP recordings of a run: topics, frames, writer, reader, importers."""

from baromap.recording.frames import LaserMount
from baromap.recording.reader import (
    OdometrySeries,
    PressureSeries,
    Record,
    load_odometry,
    load_pressure,
    load_pressure_and_odometry,
    load_pressures_and_odometry,
    odometry_series,
    pressure_series,
    read_messages,
    read_metadata,
)
from baromap.recording.writer import RecordingWriter

__all__ = [
    "LaserMount",
    "OdometrySeries",
    "PressureSeries",
    "Record",
    "RecordingWriter",
    "load_odometry",
    "load_pressure",
    "load_pressure_and_odometry",
    "load_pressures_and_odometry",
    "odometry_series",
    "pressure_series",
    "read_messages",
    "read_metadata",
]
