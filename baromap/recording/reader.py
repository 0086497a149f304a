"""Read a baromap recording back into typed messages.

Reads what :mod:`baromap.recording.writer` writes, and survives what a power cut leaves: an
MCAP without its summary and footer, or cut in the middle of a record. Then it falls back to a
front-to-back scan, keeps every complete message and logs how it ended.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt
import structlog
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory

from baromap import jsonmsg, messages
from baromap.errors import InputFormatError, RecordingError
from baromap.recording import topics

log = structlog.get_logger(__name__)

MCAP_MAGIC = b"\x89MCAP0\r\n"

#: What the mcap library raises on a file that stops mid-record.
TRUNCATION_ERRORS = (McapError, EOFError, ValueError, struct.error)


@dataclass(frozen=True, slots=True)
class Record:
    """One message of a recording: where it was logged, when, and what it says."""

    topic: str
    log_time_ns: int
    message: Any


class _Decoders:
    """Turns raw MCAP messages into baromap messages, caching one decoder per schema."""

    def __init__(self) -> None:
        self._protobuf = ProtobufDecoderFactory()
        self._cache: dict[int, Any] = {}

    def decode(self, schema: Schema | None, channel: Channel, message: Message) -> Any:
        decoder = self._cache.get(channel.id)
        if decoder is None:
            decoder = self._make(schema, channel)
            self._cache[channel.id] = decoder
        return decoder(message.data)

    def _make(self, schema: Schema | None, channel: Channel) -> Any:
        name = schema.name if schema else ""
        if channel.message_encoding == "json":
            cls = jsonmsg.JSON_TYPES.get(name)
            if cls is None:
                return json.loads
            return lambda data: jsonmsg.loads(cls, data)
        if channel.message_encoding == "protobuf" and schema is not None:
            proto = self._protobuf.decoder_for("protobuf", schema)
            if proto is None:
                raise RecordingError(f"cannot decode protobuf schema {name!r}")
            if name == "foxglove.LaserScan":
                range_max = float(channel.metadata.get("range_max_m", "inf"))
                range_min = float(channel.metadata.get("range_min_m", "0"))
                return lambda data: _scan_from_foxglove(proto(data), range_min, range_max)
            return proto
        return lambda data: data


def _scan_from_foxglove(msg: Any, range_min: float, range_max: float) -> messages.LaserScan:
    ranges = np.asarray(msg.ranges, dtype=np.float32)
    n = ranges.shape[0]
    flags = (
        np.asarray(msg.intensities, dtype=np.uint16)
        if len(msg.intensities) == n
        else np.zeros(n, dtype=np.uint16)
    )
    increment = (msg.end_angle - msg.start_angle) / (n - 1) if n > 1 else 0.0
    return messages.LaserScan(
        t_ns=msg.timestamp.seconds * 1_000_000_000 + msg.timestamp.nanos,
        angle_min_rad=msg.start_angle,
        angle_increment_rad=increment,
        range_max_m=range_max,
        range_min_m=range_min,
        ranges_m=ranges,
        flags=flags,
    )


def _open(path: str | Path) -> IO[bytes]:
    try:
        stream = Path(path).open("rb")  # noqa: SIM115 - closed by the caller's finally
    except OSError as exc:
        raise RecordingError(f"cannot open recording {path}: {exc}") from exc
    if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
        stream.close()
        raise InputFormatError(f"{path} is not an MCAP file")
    stream.seek(0)
    return stream


def _has_summary(stream: IO[bytes]) -> bool:
    """True when the file ends with a footer and closing magic (it was closed cleanly)."""
    stream.seek(0, 2)
    size = stream.tell()
    if size < 2 * len(MCAP_MAGIC) + 21:
        return False
    stream.seek(size - len(MCAP_MAGIC))
    ok = stream.read(len(MCAP_MAGIC)) == MCAP_MAGIC
    stream.seek(0)
    return ok


def read_messages(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[Record]:
    """Messages of a recording in log-time order, decoded into baromap messages.

    Unknown JSON topics come back as dicts, unknown protobuf topics as protobuf objects.
    """
    wanted = set(topics) if topics is not None else None
    decoders = _Decoders()
    stream = _open(path)
    try:
        if _has_summary(stream):
            reader = make_reader(stream)
            for schema, channel, message in reader.iter_messages(
                topics=list(wanted) if wanted is not None else None, log_time_order=True
            ):
                yield Record(
                    channel.topic, message.log_time, decoders.decode(schema, channel, message)
                )
        else:
            yield from _recover(path, stream, wanted, decoders)
    finally:
        stream.close()


def _recover(
    path: str | Path, stream: IO[bytes], wanted: set[str] | None, decoders: _Decoders
) -> Iterator[Record]:
    """Front-to-back read of an unfinished file: everything up to the first broken record."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    count = 0
    try:
        for record in StreamReader(stream, skip_magic=False).records:
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None or (wanted is not None and channel.topic not in wanted):
                    continue
                count += 1
                yield Record(
                    channel.topic,
                    record.log_time,
                    decoders.decode(schemas.get(channel.schema_id), channel, record),
                )
    except TRUNCATION_ERRORS as exc:
        log.warning(
            "recording was not closed cleanly; recovered what was complete",
            path=str(path),
            messages=count,
            error=type(exc).__name__,
        )
    else:
        log.warning("recording has no summary (not closed cleanly)", path=str(path), messages=count)


def read_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """All metadata records by name (a later record of the same name wins)."""
    stream = _open(path)
    out: dict[str, dict[str, str]] = {}
    try:
        if _has_summary(stream):
            for item in make_reader(stream).iter_metadata():
                out[item.name] = dict(item.metadata)
            return out
        try:
            for record in StreamReader(stream, skip_magic=False).records:
                if isinstance(record, Metadata):
                    out[record.name] = dict(record.metadata)
        except TRUNCATION_ERRORS:
            pass
    finally:
        stream.close()
    return out


@dataclass(frozen=True, slots=True)
class PressureSeries:
    """A pressure topic as arrays, the shape floor detection and plots want."""

    t_ns: npt.NDArray[np.int64]
    pressure_pa: npt.NDArray[np.float64]
    temperature_c: npt.NDArray[np.float64]  # NaN where the sample had none


def pressure_series(samples: Iterable[messages.PressureSample]) -> PressureSeries:
    """Samples (in time order) as arrays."""
    t: list[int] = []
    p: list[float] = []
    temp: list[float] = []
    for sample in samples:
        t.append(sample.t_ns)
        p.append(sample.pressure_pa)
        temp.append(np.nan if sample.temperature_c is None else sample.temperature_c)
    return PressureSeries(
        np.asarray(t, dtype=np.int64), np.asarray(p, dtype=np.float64), np.asarray(temp)
    )


def load_pressure(path: str | Path, topic: str = topics.BARO) -> PressureSeries:
    samples = []
    for rec in read_messages(path, [topic]):
        if not isinstance(rec.message, messages.PressureSample):
            raise InputFormatError(f"{topic} in {path} does not hold pressure samples")
        samples.append(rec.message)
    return pressure_series(samples)
