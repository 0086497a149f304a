"""One front-to-back pass over an MCAP file that hands over the raw messages of chosen topics.

Why not the ``mcap`` package's readers: they turn every record of every chunk into a Python
object (a 46-minute run holds about 250,000) and merge chunks through a heap, even to read one
topic: loading ``/baro`` alone of such a run took about 5.7 s (measured, this machine). Here
the file is memory-mapped and each chunk decompressed once; message records are told apart by
their fixed 31-byte header (MCAP specification, "Message" record) and those of unwanted
channels are skipped by length without being built. Every other record (Chunk, Schema,
Channel, Metadata) is still parsed by the ``mcap`` package.

The walk is also the recovery path. A file cut by SIGKILL or a power cut ends inside a record,
or has no summary; the walk stops at the first record that is incomplete or does not parse,
keeps everything before it, and says how it ended (:attr:`Walk.complete`, :attr:`Walk.stop`).
A chunk is only used whole, so a message is never half-read.
"""

from __future__ import annotations

import mmap
import struct
import zlib
from collections.abc import Iterable, Iterator
from io import BytesIO
from pathlib import Path
from typing import BinaryIO, NamedTuple

import lz4.frame
import numpy as np
import numpy.typing as npt
import structlog
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Header, Metadata, Schema

from baromap.errors import InputFormatError, RecordingError

log = structlog.get_logger(__name__)

MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Largest chunk this reader decompresses (the writer's chunks are about 1 MiB): a corrupt
#: size field must not make it allocate gigabytes.
MAX_CHUNK_BYTES = 512 * 1024 * 1024

_RECORD = struct.Struct("<BQ")  # opcode, record length
_MESSAGE = struct.Struct("<BQHIQQ")  # + channel id, sequence, log time, publish time
_MESSAGE_DATA = _MESSAGE.size  # 31: where a message's payload starts
_INDEX = struct.Struct("<HI")  # MessageIndex: channel id, byte length of its entries

#: What the mcap package and the codecs raise on a record that does not parse.
PARSE_ERRORS = (
    McapError,
    EOFError,
    ValueError,
    struct.error,
    UnicodeDecodeError,
    zstandard.ZstdError,
    zlib.error,
)


class RawMessage(NamedTuple):
    log_time: int
    channel_id: int
    data: bytes


class Walk:
    """The records of one file, read as far as they are whole.

    Iterate :meth:`groups` once; afterwards :attr:`schemas`, :attr:`channels`,
    :attr:`metadata`, :attr:`complete` and :attr:`stop` describe what was found.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.metadata: list[Metadata] = []
        self.profile = ""
        #: True when the data section ended with a DataEnd record and the file with the magic.
        self.complete = False
        #: Why the walk stopped early (None when the file was whole).
        self.stop: str | None = None
        self.messages_seen = 0

    def groups(self, topics: Iterable[str] | None = None) -> Iterator[tuple[int, list[RawMessage]]]:
        """(file offset of a chunk, its messages on ``topics``, in file order), chunk by chunk.

        Messages written outside chunks come as groups of one at their own offset.
        """
        wanted = set(topics) if topics is not None else None
        try:
            handle = self.path.open("rb")
        except OSError as exc:
            raise RecordingError(f"cannot open recording {self.path}: {exc}") from exc
        with handle:
            if handle.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                raise InputFormatError(f"{self.path} is not an MCAP file")
            handle.seek(0, 2)
            size = handle.tell()
            if size <= len(MCAP_MAGIC):
                self.stop = "the file ends after its magic"
                return
            with mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) as buf:
                yield from self._walk(buf, size, wanted)

    def _walk(
        self, buf: mmap.mmap, size: int, wanted: set[str] | None
    ) -> Iterator[tuple[int, list[RawMessage]]]:
        pos = len(MCAP_MAGIC)
        view = memoryview(buf)
        # A chunk is held until the message index records that follow it have been read:
        # with them, only the wanted messages are touched (see _indexed).
        pending: tuple[int, bytes] | None = None
        indexes: dict[int, npt.NDArray[np.uint64]] = {}
        try:
            while True:
                if pos + _RECORD.size > size:
                    self.stop = f"the file ends inside a record header at byte {pos}"
                    break
                opcode, length = _RECORD.unpack_from(buf, pos)
                body, end = pos + _RECORD.size, pos + _RECORD.size + length
                if end > size:
                    self.stop = f"the file ends inside a record (opcode {opcode:#x}) at byte {pos}"
                    break
                if opcode == Opcode.MESSAGE_INDEX and pending is not None:
                    channel_id, entries = _message_index(view[body:end])
                    indexes[channel_id] = entries
                    pos = end
                    continue
                if pending is not None:
                    found = self._chunk_messages(pending[1], indexes, wanted)
                    if found:
                        yield pending[0], found
                    pending, indexes = None, {}
                if opcode == Opcode.CHUNK and wanted == set():
                    pass  # nothing wanted from chunks (metadata lives outside them)
                elif opcode == Opcode.CHUNK:
                    pending = pos, _decompress(Chunk.read(_stream(view[body:end])))
                elif opcode == Opcode.MESSAGE:
                    found = self._records(buf, pos, end, wanted)
                    if found:
                        yield pos, found
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                    self._definition(opcode, view[body:end])
                elif opcode == Opcode.HEADER:
                    self.profile = Header.read(_stream(view[body:end])).profile
                elif opcode == Opcode.METADATA:
                    self.metadata.append(Metadata.read(_stream(view[body:end])))
                elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
                    self.complete = buf[size - len(MCAP_MAGIC) : size] == MCAP_MAGIC
                    if not self.complete:
                        self.stop = "the summary section is cut"
                    break
                pos = end
            if pending is not None:
                # the file was cut after this chunk: its indexes may be partial, walk it
                found = self._records(pending[1], 0, len(pending[1]), wanted)
                if found:
                    yield pending[0], found
        except PARSE_ERRORS as exc:
            self.stop = f"a record at byte {pos} does not parse ({type(exc).__name__}: {exc})"
        finally:
            view.release()

    def _chunk_messages(
        self, data: bytes, indexes: dict[int, npt.NDArray[np.uint64]], wanted: set[str] | None
    ) -> list[RawMessage]:
        """The wanted messages of a whole chunk: through its indexes when they can be trusted."""
        if indexes and all(channel_id in self.channels for channel_id in indexes):
            found = self._indexed(data, indexes, wanted)
            if found is not None:
                return found
        return self._records(data, 0, len(data), wanted)

    def _indexed(
        self, data: bytes, indexes: dict[int, npt.NDArray[np.uint64]], wanted: set[str] | None
    ) -> list[RawMessage] | None:
        """Messages at the offsets the indexes give, checked against the records themselves.

        None when an index does not match its chunk (then the chunk is walked instead).
        """
        raw = np.frombuffer(data, dtype=np.uint8)
        out: list[RawMessage] = []
        for channel_id, entries in indexes.items():
            self.messages_seen += len(entries)
            if wanted is not None and self.channels[channel_id].topic not in wanted:
                continue
            offsets = entries[:, 1].astype(np.int64)
            if len(offsets) == 0:
                continue
            if offsets.min() < 0 or offsets.max() + _MESSAGE_DATA > len(data):
                return None
            header = raw[offsets[:, None] + np.arange(_MESSAGE_DATA)]
            if np.any(header[:, 0] != Opcode.MESSAGE):
                return None
            lengths = header[:, 1:9].copy().view("<u8").ravel()
            channels = header[:, 9:11].copy().view("<u2").ravel()
            log_times = header[:, 15:23].copy().view("<u8").ravel()
            ends = offsets + _RECORD.size + lengths.astype(np.int64)
            if np.any(channels != channel_id) or np.any(lengths < _MESSAGE_DATA - _RECORD.size):
                return None
            if ends.max() > len(data):
                return None
            out.extend(
                RawMessage(t, channel_id, data[start:end])
                for t, start, end in zip(
                    log_times.tolist(),
                    (offsets + _MESSAGE_DATA).tolist(),
                    ends.tolist(),
                    strict=True,
                )
            )
        return out

    def _definition(self, opcode: int, body: memoryview | bytes) -> None:
        if opcode == Opcode.SCHEMA:
            schema = Schema.read(_stream(body))
            self.schemas[schema.id] = schema
        else:
            channel = Channel.read(_stream(body))
            self.channels[channel.id] = channel

    def _records(
        self, data: bytes | mmap.mmap, pos: int, end: int, wanted: set[str] | None
    ) -> list[RawMessage]:
        """Message, Schema and Channel records between ``pos`` and ``end``."""
        out: list[RawMessage] = []
        keep: dict[int, bool] = {}
        unpack_record, unpack_message = _RECORD.unpack_from, _MESSAGE.unpack_from
        seen = 0
        while pos < end:
            opcode, length = unpack_record(data, pos)
            stop = pos + _RECORD.size + length
            if stop > end:
                raise McapError("a record runs past the end of its chunk")
            if opcode == Opcode.MESSAGE:
                seen += 1
                _, _, channel_id, _, log_time, _ = unpack_message(data, pos)
                take = keep.get(channel_id)
                if take is None:
                    channel = self.channels.get(channel_id)
                    if channel is None:
                        raise McapError(f"message on channel {channel_id} before its definition")
                    take = keep[channel_id] = wanted is None or channel.topic in wanted
                if take:
                    out.append(RawMessage(log_time, channel_id, data[pos + _MESSAGE_DATA : stop]))
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                self._definition(opcode, data[pos + _RECORD.size : stop])
            pos = stop
        self.messages_seen += seen
        return out


def _decompress(chunk: Chunk) -> bytes:
    if chunk.uncompressed_size > MAX_CHUNK_BYTES:
        raise McapError(f"chunk of {chunk.uncompressed_size} bytes (limit {MAX_CHUNK_BYTES})")
    if chunk.compression == "zstd":
        data: bytes = zstandard.ZstdDecompressor().decompress(
            chunk.data, max_output_size=chunk.uncompressed_size
        )
    elif chunk.compression == "lz4":
        data = lz4.frame.decompress(chunk.data)
    elif chunk.compression == "":
        data = bytes(chunk.data)
    else:
        raise McapError(f"unsupported chunk compression {chunk.compression!r}")
    if len(data) != chunk.uncompressed_size:
        raise McapError("chunk size differs from its header")
    return data


def _message_index(body: memoryview) -> tuple[int, npt.NDArray[np.uint64]]:
    """(channel id, (N, 2) log time and offset pairs) of a MessageIndex record."""
    channel_id, length = _INDEX.unpack_from(body, 0)
    if length % 16 or _INDEX.size + length > len(body):
        raise McapError("message index length does not fit its record")
    entries = np.frombuffer(body, dtype="<u8", count=length // 8, offset=_INDEX.size)
    return channel_id, entries.reshape(-1, 2).copy()  # no view may outlive the map


def message_index_at(stream: BinaryIO, offset: int) -> npt.NDArray[np.uint64]:
    """(N, 2) log time and offset pairs of the MessageIndex record at ``offset`` of a file."""
    stream.seek(offset)
    head = stream.read(_RECORD.size)
    if len(head) < _RECORD.size:
        raise McapError(f"no record at byte {offset}")
    opcode, length = _RECORD.unpack(head)
    if opcode != Opcode.MESSAGE_INDEX or length > MAX_CHUNK_BYTES:
        raise McapError(f"no message index at byte {offset}")
    body = stream.read(length)
    if len(body) < length:
        raise McapError(f"message index at byte {offset} is cut")
    return _message_index(memoryview(body))[1]


def _stream(body: memoryview | bytes) -> ReadDataStream:
    return ReadDataStream(BytesIO(body))


def warn_if_incomplete(walk: Walk, kept: int) -> None:
    """Say that a recording was cut, and what was kept of it (a reader's duty, not an error)."""
    if walk.complete:
        return
    log.warning(
        "recording was not closed cleanly; recovered what was complete",
        path=str(walk.path),
        messages=kept,
        stop=walk.stop or "no summary",
    )
