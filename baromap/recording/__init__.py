"""MCAP recordings of a run: topics, frames, writer, reader, importers.

The reader's names are imported on first use (PEP 562 ``__getattr__``): the daemon writes and
never reads, and the reader brings the mcap package and protobuf's runtime, some 40 ms of CPU
at every start of the daemon (``python -X importtime -c "import baromapd.main"``).
"""

from typing import TYPE_CHECKING, Any

from baromap.recording.frames import LaserMount
from baromap.recording.writer import RecordingWriter

if TYPE_CHECKING:
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


def __getattr__(name: str) -> Any:
    if name in _FROM_READER:
        from baromap.recording import reader

        return getattr(reader, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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

#: What the reader module provides (the rest of ``__all__`` is imported above).
_FROM_READER = frozenset(__all__) - {"LaserMount", "RecordingWriter"}
