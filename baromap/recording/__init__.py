"""MCAP recordings of a run: topics, writer, reader, importers."""

from baromap.recording.reader import (
    PressureSeries,
    Record,
    load_pressure,
    pressure_series,
    read_messages,
    read_metadata,
)
from baromap.recording.writer import RecordingWriter

__all__ = [
    "PressureSeries",
    "Record",
    "RecordingWriter",
    "load_pressure",
    "pressure_series",
    "read_messages",
    "read_metadata",
]
