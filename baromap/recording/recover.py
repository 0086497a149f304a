"""Rewrite a recording cut by SIGKILL or a power cut into a whole MCAP file.

A cut file has no summary, and the chunk that was being written when the process died is left
with a placeholder length (all ones, from the MCAP library that wrote it): the official readers'
usual calls (``make_reader(...).iter_messages()``) give up on it. Everything before that
chunk is whole and checked: the records are read in order with the ``mcap`` package's own
stream reader (chunk CRCs checked) until the first that is incomplete or does not parse, and
every message, schema, channel, metadata record and attachment found before it is written
into a new file with the ``mcap`` package's writer, which adds the summary (statistics, chunk,
metadata and attachment indexes). The original is never changed.

Messages keep their channel, log time, publish time, sequence number and bytes. Schema and
channel ids may be renumbered (the writer numbers what it is given from 1).
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from baromap.errors import InputFormatError, RecordingError

#: Largest record the reader takes: the writer's chunks are about 1 MiB, and a cut file's
#: unfinished chunk claims 2**64 - 1 bytes.
RECORD_LIMIT = 512 * 1024 * 1024
#: Suffix of the repaired copy the daemon makes of a cut file next to it.
RECOVERED_SUFFIX = ".recovered.mcap"
#: The MCAP magic (``walk.MCAP_MAGIC``): not imported from there, which loads the ``mcap``
#: package, for the daemon's start-up look at its directory needs only this.
MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass(slots=True)
class Recovery:
    """What a recovery kept, and where the source file was cut."""

    source: Path
    target: Path
    size: int  # bytes of the source
    cut_at: int | None  # byte offset of the first record not kept; None: the file was whole
    reason: str | None  # why the records stop there
    messages: int = 0
    metadata: int = 0
    attachments: int = 0
    topics: Counter[str] = field(default_factory=Counter)
    first_log_time: int | None = None
    last_log_time: int | None = None

    @property
    def was_cut(self) -> bool:
        return self.cut_at is not None


def is_cut(path: str | Path) -> bool:
    """Whether an MCAP file lacks its closing magic (cut; or still being written)."""
    with Path(path).open("rb") as stream:
        head = stream.read(len(MCAP_MAGIC))
        stream.seek(0, os.SEEK_END)
        size = stream.tell()
        if head != MCAP_MAGIC or size < 2 * len(MCAP_MAGIC):
            return head == MCAP_MAGIC[: len(head)]
        stream.seek(size - len(MCAP_MAGIC))
        return stream.read() != MCAP_MAGIC


class _Position:
    """The offset just past the last record the stream reader handed over."""

    def __init__(self, stream: BinaryIO) -> None:
        self.stream = stream
        self.good = len(MCAP_MAGIC)

    def mark(self) -> None:
        self.good = self.stream.tell()


def recover(source: str | Path, target: str | Path) -> Recovery:
    """Write every whole record of ``source`` into ``target`` with a summary; say what was kept.

    ``target`` is written under a temporary name and renamed when complete, so a recovery that
    is interrupted never leaves something that looks like a recording.
    """
    source, target = Path(source), Path(target)
    if source.resolve() == target.resolve():
        raise RecordingError(f"{target}: the recovered file must not replace the cut one")
    try:
        stream = source.open("rb")
    except OSError as exc:
        raise RecordingError(f"cannot open recording {source}: {exc}") from exc
    partial = target.with_name(target.name + ".part")
    with stream:
        if stream.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise InputFormatError(f"{source} is not an MCAP file")
        size = os.fstat(stream.fileno()).st_size
        stream.seek(0)
        result = Recovery(source, target, size, cut_at=None, reason=None)
        try:
            with partial.open("wb") as out:
                _copy(stream, out, result)
                out.flush()
                os.fsync(out.fileno())
            partial.replace(target)
        except OSError as exc:
            partial.unlink(missing_ok=True)
            raise RecordingError(f"cannot write {target}: {exc}") from exc
    return result


def _copy(stream: BinaryIO, out: BinaryIO, result: Recovery) -> None:
    from mcap.exceptions import McapError
    from mcap.records import Attachment, Channel, DataEnd, Footer, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import CompressionType, Writer

    from baromap.recording.walk import PARSE_ERRORS

    position = _Position(stream)
    reader = StreamReader(stream, validate_crcs=True, record_size_limit=RECORD_LIMIT)
    writer = Writer(out, compression=CompressionType.ZSTD)
    schemas: dict[int, int] = {0: 0}  # source id -> written id (0: no schema)
    channels: dict[int, int] = {}
    topics: dict[int, str] = {}
    started = False
    whole = False
    try:
        for record in reader.records:
            if isinstance(record, Header):
                writer.start(record.profile, record.library)
                started = True
            elif isinstance(record, Schema):
                if record.id not in schemas:
                    schemas[record.id] = writer.register_schema(
                        record.name, record.encoding, record.data
                    )
            elif isinstance(record, Channel):
                if record.id not in channels:
                    channels[record.id] = writer.register_channel(
                        record.topic,
                        record.message_encoding,
                        schemas[record.schema_id],
                        dict(record.metadata),
                    )
                    topics[record.id] = record.topic
            elif isinstance(record, Message):
                writer.add_message(
                    channels[record.channel_id],
                    record.log_time,
                    record.data,
                    record.publish_time,
                    record.sequence,
                )
                _count(result, topics[record.channel_id], record.log_time)
            elif isinstance(record, Metadata):
                writer.add_metadata(record.name, dict(record.metadata))
                result.metadata += 1
            elif isinstance(record, Attachment):
                writer.add_attachment(
                    record.create_time, record.log_time, record.name, record.media_type, record.data
                )
                result.attachments += 1
            elif isinstance(record, (DataEnd, Footer)):
                whole = True
                break
            position.mark()
    except (*PARSE_ERRORS, McapError, KeyError) as exc:
        result.reason = _reason(exc)
    if not whole:
        result.cut_at = position.good
        if result.reason is None:
            result.reason = "the file ends without its summary"
    if not started:
        raise InputFormatError(f"{result.source}: the file is cut inside its header")
    writer.finish()  # type: ignore[no-untyped-call]


def _count(result: Recovery, topic: str, log_time: int) -> None:
    result.messages += 1
    result.topics[topic] += 1
    if result.first_log_time is None:
        result.first_log_time = log_time
    result.last_log_time = log_time


def _reason(exc: BaseException) -> str:
    if isinstance(exc, KeyError):
        return f"a message refers to an undefined channel or schema {exc}"
    text = str(exc) or type(exc).__name__
    if "length" in text and "exceeds limit" in text:
        return "a record was being written when the file was cut (its length is unset)"
    if isinstance(exc, EOFError) or "EndOfFile" in type(exc).__name__:
        return "the file ends inside a record"
    return f"a record does not parse ({type(exc).__name__}: {text})"
