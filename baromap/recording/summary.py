"""What a recording holds, from its summary section: topics, schemas, counts, times, metadata.

A cleanly closed MCAP ends with a summary (statistics, channels and schemas, chunk and metadata
indexes), so a 46-minute run is described without decompressing a single chunk. A file that
was cut (power cut, SIGKILL) has none: then the data section is walked and the summary says
that it is incomplete and why, instead of passing a recovered prefix off as the whole run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import structlog
from mcap.reader import make_reader
from mcap.records import ChunkIndex

from baromap.errors import RecordingError
from baromap.recording.walk import MCAP_MAGIC, PARSE_ERRORS, Walk, message_index_at

log = structlog.get_logger(__name__)


@dataclass(frozen=True, slots=True)
class TopicSummary:
    topic: str
    schema: str
    encoding: str
    count: int
    first_ns: int | None
    last_ns: int | None

    @property
    def rate_hz(self) -> float:
        if self.first_ns is None or self.last_ns is None or self.last_ns <= self.first_ns:
            return 0.0
        return (self.count - 1) / ((self.last_ns - self.first_ns) / 1e9)


@dataclass(frozen=True, slots=True)
class RecordingSummary:
    path: Path
    profile: str
    complete: bool
    stop: str | None  # why a cut file ends where it does
    topics: list[TopicSummary]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics)

    @property
    def start_ns(self) -> int | None:
        starts = [t.first_ns for t in self.topics if t.first_ns is not None]
        return min(starts) if starts else None

    @property
    def end_ns(self) -> int | None:
        ends = [t.last_ns for t in self.topics if t.last_ns is not None]
        return max(ends) if ends else None


def summarize(path: str | Path) -> RecordingSummary:
    """The summary of a recording; a cut file is walked and reported incomplete."""
    path = Path(path)
    summary = _from_summary_section(path)
    return summary if summary is not None else _from_walk(path)


def _ends_with_magic(path: Path) -> bool:
    try:
        with path.open("rb") as stream:
            if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                return False
            stream.seek(0, 2)
            if stream.tell() < 2 * len(MCAP_MAGIC):
                return False
            stream.seek(-len(MCAP_MAGIC), 2)
            return stream.read(len(MCAP_MAGIC)) == MCAP_MAGIC
    except OSError as exc:
        raise RecordingError(f"cannot open recording {path}: {exc}") from exc


def _from_summary_section(path: Path) -> RecordingSummary | None:
    if not _ends_with_magic(path):
        return None
    try:
        with path.open("rb") as stream:
            reader = make_reader(stream)
            header = reader.get_header()
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                return None
            metadata = {item.name: dict(item.metadata) for item in reader.iter_metadata()}
            counts = summary.statistics.channel_message_counts
            span = _channel_spans(stream, summary.chunk_indexes, set(counts))
    except PARSE_ERRORS as exc:
        log.warning("summary section unreadable; walking the file", path=str(path), error=exc)
        return None
    topics: list[TopicSummary] = []
    for channel_id, channel in sorted(summary.channels.items()):
        schema = summary.schemas.get(channel.schema_id)
        first, last = span.get(channel_id, (None, None))
        topics.append(
            TopicSummary(
                topic=channel.topic,
                schema=schema.name if schema else "",
                encoding=channel.message_encoding,
                count=counts.get(channel_id, 0),
                first_ns=first,
                last_ns=last,
            )
        )
    return RecordingSummary(path, header.profile, True, None, _merge(topics), metadata)


def _channel_spans(
    stream: BinaryIO, chunk_indexes: list[ChunkIndex], channels: set[int]
) -> dict[int, tuple[int, int]]:
    """First and last log time per channel, from the message indexes of its first and last
    chunk (two small reads per channel, no decompression)."""
    first_chunk: dict[int, ChunkIndex] = {}
    last_chunk: dict[int, ChunkIndex] = {}
    for index in sorted(chunk_indexes, key=lambda c: c.message_start_time):
        for channel_id in index.message_index_offsets:
            first_chunk.setdefault(channel_id, index)
    for index in sorted(chunk_indexes, key=lambda c: c.message_end_time, reverse=True):
        for channel_id in index.message_index_offsets:
            last_chunk.setdefault(channel_id, index)
    spans: dict[int, tuple[int, int]] = {}
    for channel_id in channels & set(first_chunk):
        head = message_index_at(stream, first_chunk[channel_id].message_index_offsets[channel_id])
        tail = message_index_at(stream, last_chunk[channel_id].message_index_offsets[channel_id])
        if len(head) and len(tail):
            spans[channel_id] = (int(head[:, 0].min()), int(tail[:, 0].max()))
    return spans


def _merge(topics: list[TopicSummary]) -> list[TopicSummary]:
    """One line per (topic, schema): a topic may span channels (scans of two range limits)."""
    merged: dict[tuple[str, str, str], TopicSummary] = {}
    for t in topics:
        key = (t.topic, t.schema, t.encoding)
        old = merged.get(key)
        if old is None:
            merged[key] = t
            continue
        firsts = [v for v in (old.first_ns, t.first_ns) if v is not None]
        lasts = [v for v in (old.last_ns, t.last_ns) if v is not None]
        merged[key] = TopicSummary(
            t.topic,
            t.schema,
            t.encoding,
            old.count + t.count,
            min(firsts) if firsts else None,
            max(lasts) if lasts else None,
        )
    return sorted(merged.values(), key=lambda t: t.topic)


def _from_walk(path: Path) -> RecordingSummary:
    walk = Walk(path)
    counts: dict[int, int] = {}
    first: dict[int, int] = {}
    last: dict[int, int] = {}
    for _, group in walk.groups(None):
        for raw in group:
            counts[raw.channel_id] = counts.get(raw.channel_id, 0) + 1
            if raw.log_time < first.get(raw.channel_id, raw.log_time + 1):
                first[raw.channel_id] = raw.log_time
            if raw.log_time > last.get(raw.channel_id, raw.log_time - 1):
                last[raw.channel_id] = raw.log_time
    topics = []
    for channel_id, channel in sorted(walk.channels.items()):
        schema = walk.schemas.get(channel.schema_id)
        topics.append(
            TopicSummary(
                channel.topic,
                schema.name if schema else "",
                channel.message_encoding,
                counts.get(channel_id, 0),
                first.get(channel_id),
                last.get(channel_id),
            )
        )
    metadata = {item.name: dict(item.metadata) for item in walk.metadata}
    stop = walk.stop or ("no summary section" if not walk.complete else None)
    return RecordingSummary(path, walk.profile, walk.complete, stop, _merge(topics), metadata)
