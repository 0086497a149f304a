"""Read a baromap recording back into typed messages.

Reads what :mod:`baromap.recording.writer` writes (and format 1 recordings, whose ``/odom``
was JSON), and survives what a power cut leaves: an MCAP without its summary and footer, or cut
in the middle of a record. Then it keeps every complete chunk and logs how the file ended.

All reads go through one front-to-back pass (:mod:`baromap.recording.walk`); the series
loaders (:func:`load_pressure`, :func:`load_odometry`) decode a whole topic at once into
arrays, the shape floor detection and mapping use.
"""

from __future__ import annotations

import heapq
import itertools
import json
import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import structlog
from mcap.reader import make_reader
from mcap.records import Channel, Schema
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory

from baromap import jsonmsg, messages
from baromap.errors import InputFormatError, RecordingError
from baromap.recording import topics
from baromap.recording.frames import quaternion_to_yaw
from baromap.recording.walk import (
    MCAP_MAGIC,
    PARSE_ERRORS,
    RawMessage,
    Walk,
    warn_if_incomplete,
)
from baromap.recording.writer import RAW_ODOMETRY_KEYS

log = structlog.get_logger(__name__)

ODOMETRY_SCHEMA = "foxglove.Odometry"


@dataclass(frozen=True, slots=True)
class Record:
    """One message of a recording: where it was logged, when, and what it says."""

    topic: str
    log_time_ns: int
    message: Any


Decoder = Callable[[bytes], Any]


class _Decoders:
    """Turns raw MCAP payloads into baromap messages, one decoder per channel."""

    def __init__(self, walk: Walk) -> None:
        self._walk = walk
        self._protobuf = ProtobufDecoderFactory()
        self._cache: dict[int, Decoder] = {}

    def decode(self, channel_id: int, data: bytes) -> Any:
        decoder = self._cache.get(channel_id)
        if decoder is None:
            decoder = self._cache[channel_id] = self.make(channel_id)
        return decoder(data)

    def channel(self, channel_id: int) -> tuple[Channel, Schema | None]:
        channel = self._walk.channels[channel_id]
        return channel, self._walk.schemas.get(channel.schema_id)

    def protobuf(self, channel_id: int) -> Decoder:
        channel, schema = self.channel(channel_id)
        name = schema.name if schema else ""
        if channel.message_encoding != "protobuf" or schema is None:
            raise InputFormatError(f"{channel.topic}: {name!r} is not a protobuf schema")
        try:
            proto = self._protobuf.decoder_for("protobuf", schema)
        except Exception as exc:  # the factory raises whatever protobuf raises
            raise InputFormatError(f"{channel.topic}: bad protobuf schema {name!r}") from exc
        if proto is None:
            raise RecordingError(f"cannot decode protobuf schema {name!r}")
        return _guarded(channel.topic, proto)

    def make(self, channel_id: int) -> Decoder:
        channel, schema = self.channel(channel_id)
        name = schema.name if schema else ""
        if channel.message_encoding == "json":
            cls = jsonmsg.JSON_TYPES.get(name)
            if cls is None:
                return json.loads
            return lambda data: jsonmsg.loads(cls, data)
        if channel.message_encoding == "protobuf" and schema is not None:
            proto = self.protobuf(channel_id)
            if name == "foxglove.LaserScan":
                range_max = float(channel.metadata.get("range_max_m", "inf"))
                range_min = float(channel.metadata.get("range_min_m", "0"))
                return lambda data: _scan_from_foxglove(proto(data), range_min, range_max)
            if name == ODOMETRY_SCHEMA:
                return lambda data: _odometry_from_foxglove(proto(data), channel.topic)
            return proto
        return lambda data: data


def _guarded(topic: str, proto: Decoder) -> Decoder:
    def decode(data: bytes) -> Any:
        try:
            return proto(data)
        except Exception as exc:  # protobuf's DecodeError and friends
            raise InputFormatError(f"{topic}: a message does not decode: {exc}") from exc

    return decode


def _stamp_ns(stamp: Any) -> int:
    return int(stamp.seconds) * 1_000_000_000 + int(stamp.nanos)


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
        t_ns=_stamp_ns(msg.timestamp),
        angle_min_rad=msg.start_angle,
        angle_increment_rad=increment,
        range_max_m=range_max,
        range_min_m=range_min,
        ranges_m=ranges,
        flags=flags,
    )


def _raw_counters(msg: Any, topic: str) -> tuple[int, int, int]:
    raw = {kv.key: kv.value for kv in msg.metadata}
    try:
        return (
            int(raw.get("raw_x", 0)),
            int(raw.get("raw_y", 0)),
            int(raw.get("raw_theta", 0)),
        )
    except ValueError as exc:
        raise InputFormatError(f"{topic}: odometry counters {raw!r} are not integers") from exc


def _odometry_from_foxglove(msg: Any, topic: str) -> messages.Odometry:
    q = msg.pose.orientation
    raw_x, raw_y, raw_theta = _raw_counters(msg, topic)
    return messages.Odometry(
        t_ns=_stamp_ns(msg.timestamp),
        x_m=msg.pose.position.x,
        y_m=msg.pose.position.y,
        theta_rad=quaternion_to_yaw(q.x, q.y, q.z, q.w),
        v_mps=msg.linear_velocity.x,
        omega_radps=msg.angular_velocity.z,
        raw_x=raw_x,
        raw_y=raw_y,
        raw_theta=raw_theta,
    )


def _chunk_horizons(path: str | Path) -> dict[int, int] | None:
    """For each chunk (by file offset), the earliest log time of any chunk after it.

    Messages up to that time can be handed out in order once the chunk is read. None when the
    file has no summary (then chunks come out in file order, each sorted).
    """
    try:
        with Path(path).open("rb") as stream:
            stream.seek(-len(MCAP_MAGIC), 2)
            if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                return None
            stream.seek(0)
            summary = make_reader(stream).get_summary()
    except (OSError, *PARSE_ERRORS):
        return None
    if summary is None or not summary.chunk_indexes:
        return None
    indexes = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    horizons: dict[int, int] = {}
    later = math.inf
    for index in reversed(indexes):
        horizons[index.chunk_start_offset] = int(min(later, 2**64))
        later = min(later, index.message_start_time)
    return horizons


def read_messages(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[Record]:
    """Messages of a recording in log-time order, decoded into baromap messages.

    Unknown JSON topics come back as dicts, unknown protobuf topics as protobuf objects. A file
    that was not closed cleanly comes back as far as its chunks are whole, chunk by chunk in
    file order (each chunk in time order), with a warning.
    """
    walk = Walk(path)
    decoders = _Decoders(walk)
    horizons = _chunk_horizons(path)
    pending: list[tuple[int, int, RawMessage]] = []
    counter = itertools.count()
    kept = 0
    for offset, group in walk.groups(topics):
        for raw in group:
            heapq.heappush(pending, (raw.log_time, next(counter), raw))
        horizon = horizons.get(offset) if horizons is not None else None
        while pending and (horizon is None or pending[0][0] <= horizon):
            _, _, raw = heapq.heappop(pending)
            kept += 1
            channel = walk.channels[raw.channel_id]
            yield Record(channel.topic, raw.log_time, decoders.decode(raw.channel_id, raw.data))
    while pending:
        _, _, raw = heapq.heappop(pending)
        kept += 1
        channel = walk.channels[raw.channel_id]
        yield Record(channel.topic, raw.log_time, decoders.decode(raw.channel_id, raw.data))
    warn_if_incomplete(walk, kept)


def read_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """All metadata records by name (a later record of the same name wins)."""
    if _has_summary(path):
        try:
            with Path(path).open("rb") as stream:
                return {
                    item.name: dict(item.metadata) for item in make_reader(stream).iter_metadata()
                }
        except PARSE_ERRORS:
            pass  # a summary that does not parse: read the data section instead
        except OSError as exc:
            raise RecordingError(f"cannot open recording {path}: {exc}") from exc
    walk = Walk(path)
    for _ in walk.groups(()):
        pass
    return {item.name: dict(item.metadata) for item in walk.metadata}


def _has_summary(path: str | Path) -> bool:
    """True when the file ends with the closing magic (it was closed cleanly)."""
    try:
        with Path(path).open("rb") as stream:
            stream.seek(0, 2)
            if stream.tell() < 2 * len(MCAP_MAGIC) + 21:
                return False
            stream.seek(-len(MCAP_MAGIC), 2)
            return stream.read(len(MCAP_MAGIC)) == MCAP_MAGIC
    except OSError as exc:
        raise RecordingError(f"cannot open recording {path}: {exc}") from exc


@dataclass(frozen=True, slots=True)
class PressureSeries:
    """A pressure topic as arrays, the shape floor detection and plots want."""

    t_ns: npt.NDArray[np.int64]
    pressure_pa: npt.NDArray[np.float64]
    temperature_c: npt.NDArray[np.float64]  # NaN where the sample had none


@dataclass(frozen=True, slots=True)
class OdometrySeries:
    """An odometry topic as arrays: the integrated pose, velocities and the raw counters."""

    t_ns: npt.NDArray[np.int64]
    x_m: npt.NDArray[np.float64]
    y_m: npt.NDArray[np.float64]
    theta_rad: npt.NDArray[np.float64]
    v_mps: npt.NDArray[np.float64]
    omega_radps: npt.NDArray[np.float64]
    raw_x: npt.NDArray[np.int64]
    raw_y: npt.NDArray[np.int64]
    raw_theta: npt.NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    def poses(self) -> npt.NDArray[np.float64]:
        """(N, 3) x, y, theta."""
        return np.column_stack([self.x_m, self.y_m, self.theta_rad])


def pressure_series(samples: Iterable[messages.PressureSample]) -> PressureSeries:
    """Samples (in time order) as arrays."""
    samples = list(samples)
    n = len(samples)
    return PressureSeries(
        np.fromiter((s.t_ns for s in samples), dtype=np.int64, count=n),
        np.fromiter((s.pressure_pa for s in samples), dtype=np.float64, count=n),
        np.fromiter(
            (math.nan if s.temperature_c is None else s.temperature_c for s in samples),
            dtype=np.float64,
            count=n,
        ),
    )


def odometry_series(odometry: Iterable[messages.Odometry]) -> OdometrySeries:
    """Odometry messages (in time order) as arrays."""
    items = list(odometry)
    n = len(items)

    def column(name: str, dtype: type[np.generic]) -> Any:
        return np.fromiter((getattr(o, name) for o in items), dtype=dtype, count=n)

    return OdometrySeries(
        column("t_ns", np.int64),
        column("x_m", np.float64),
        column("y_m", np.float64),
        column("theta_rad", np.float64),
        column("v_mps", np.float64),
        column("omega_radps", np.float64),
        column("raw_x", np.int64),
        column("raw_y", np.int64),
        column("raw_theta", np.int64),
    )


def _collect(walk: Walk, wanted: Sequence[str]) -> dict[str, list[RawMessage]]:
    """Raw messages of each wanted topic, in log-time order (stable for equal times)."""
    out: dict[str, list[RawMessage]] = {topic: [] for topic in wanted}
    for _, group in walk.groups(wanted):
        for raw in group:
            out[walk.channels[raw.channel_id].topic].append(raw)
    kept = 0
    for topic, raws in out.items():
        kept += len(raws)
        if any(a.log_time > b.log_time for a, b in itertools.pairwise(raws)):
            out[topic] = sorted(raws, key=lambda r: r.log_time)
    warn_if_incomplete(walk, kept)
    return out


def _decode_pressure(
    walk: Walk, raws: list[RawMessage], topic: str
) -> list[messages.PressureSample]:
    schema_name = jsonmsg.schema_name(messages.PressureSample)
    for channel_id in {raw.channel_id for raw in raws}:
        channel = walk.channels[channel_id]
        schema = walk.schemas.get(channel.schema_id)
        if channel.message_encoding != "json" or schema is None or schema.name != schema_name:
            raise InputFormatError(f"{topic} in {walk.path} does not hold pressure samples")
    return jsonmsg.loads_many(messages.PressureSample, [raw.data for raw in raws])


def _decode_odometry(walk: Walk, raws: list[RawMessage], topic: str) -> OdometrySeries:
    decoders = _Decoders(walk)
    by_channel: dict[int, Decoder] = {}
    protobuf: dict[int, Decoder] = {}
    json_name = jsonmsg.schema_name(messages.Odometry)
    for channel_id in {raw.channel_id for raw in raws}:
        channel = walk.channels[channel_id]
        schema = walk.schemas.get(channel.schema_id)
        name = schema.name if schema else ""
        if channel.message_encoding == "protobuf" and name == ODOMETRY_SCHEMA:
            by_channel[channel_id] = decoders.make(channel_id)
            protobuf[channel_id] = decoders.protobuf(channel_id)
        elif channel.message_encoding == "json" and name == json_name:
            by_channel[channel_id] = lambda data: jsonmsg.loads(messages.Odometry, data)
        else:
            raise InputFormatError(f"{topic} in {walk.path} does not hold odometry ({name!r})")
    if len(protobuf) == len(by_channel):
        return _foxglove_odometry_columns(raws, protobuf, topic)
    return odometry_series(by_channel[raw.channel_id](raw.data) for raw in raws)


def _foxglove_odometry_columns(
    raws: list[RawMessage], decoders: dict[int, Decoder], topic: str
) -> OdometrySeries:
    """foxglove.Odometry payloads straight into columns (no message object per sample)."""
    stamps: list[int] = []
    rows: list[tuple[float, ...]] = []
    counts: list[tuple[int, int, int]] = []
    for raw in raws:
        msg = decoders[raw.channel_id](raw.data)
        pose = msg.pose
        position, q = pose.position, pose.orientation
        stamp = msg.timestamp
        stamps.append(stamp.seconds * 1_000_000_000 + stamp.nanos)
        rows.append(
            (
                position.x,
                position.y,
                q.x,
                q.y,
                q.z,
                q.w,
                msg.linear_velocity.x,
                msg.angular_velocity.z,
            )
        )
        meta = msg.metadata
        if len(meta) == 3 and (meta[0].key, meta[1].key, meta[2].key) == RAW_ODOMETRY_KEYS:
            try:
                counts.append((int(meta[0].value), int(meta[1].value), int(meta[2].value)))
            except ValueError as exc:
                raise InputFormatError(f"{topic}: odometry counters are not integers") from exc
        else:
            counts.append(_raw_counters(msg, topic) if len(meta) else (0, 0, 0))
    n = len(raws)
    t = np.array(stamps, dtype=np.int64).reshape(n)
    f = np.array(rows, dtype=np.float64).reshape(n, 8)  # x, y, qx, qy, qz, qw, v, omega
    counters = np.array(counts, dtype=np.int64).reshape(n, 3)
    qx, qy, qz, qw = f[:, 2], f[:, 3], f[:, 4], f[:, 5]
    yaw = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return OdometrySeries(
        t_ns=t,
        x_m=f[:, 0].copy(),
        y_m=f[:, 1].copy(),
        theta_rad=yaw,
        v_mps=f[:, 6].copy(),
        omega_radps=f[:, 7].copy(),
        raw_x=counters[:, 0].copy(),
        raw_y=counters[:, 1].copy(),
        raw_theta=counters[:, 2].copy(),
    )


def load_pressure(path: str | Path, topic: str = topics.BARO) -> PressureSeries:
    """A pressure topic as arrays, in one pass and one parse of the whole topic."""
    walk = Walk(path)
    raws = _collect(walk, [topic])[topic]
    return pressure_series(_decode_pressure(walk, raws, topic))


def load_odometry(path: str | Path, topic: str = topics.ODOM) -> OdometrySeries:
    """An odometry topic as arrays (format 2's foxglove.Odometry or format 1's JSON)."""
    walk = Walk(path)
    raws = _collect(walk, [topic])[topic]
    return _decode_odometry(walk, raws, topic)


def load_pressure_and_odometry(
    path: str | Path, pressure_topic: str = topics.BARO, odometry_topic: str = topics.ODOM
) -> tuple[PressureSeries, OdometrySeries]:
    """Both series of a run in one pass over the file (each pass decompresses all of it)."""
    pressures, odometry = load_pressures_and_odometry(path, [pressure_topic], odometry_topic)
    return pressures[pressure_topic], odometry


def load_pressures_and_odometry(
    path: str | Path, pressure_topics: Sequence[str], odometry_topic: str = topics.ODOM
) -> tuple[dict[str, PressureSeries], OdometrySeries]:
    """Several pressure topics (the robot's barometer, a reference station's) and odometry in
    one pass over the file; a pressure topic the file does not hold comes back empty."""
    walk = Walk(path)
    raws = _collect(walk, [*pressure_topics, odometry_topic])
    pressures = {
        topic: pressure_series(_decode_pressure(walk, raws[topic], topic))
        for topic in pressure_topics
    }
    return pressures, _decode_odometry(walk, raws[odometry_topic], odometry_topic)
