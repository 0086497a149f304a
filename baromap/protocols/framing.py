"""What every decoder shares: the record of discarded bytes and the counters behind it."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

#: Discarded bytes kept in a :class:`BadFrame` for diagnosis; the rest is only counted.
BAD_FRAME_SAMPLE_BYTES = 64


@dataclass(frozen=True, slots=True)
class WireSized:
    """What every decoded item says besides its content: how many bytes it took on the line,
    its framing included, so a reader can place the item's end in the byte stream (the daemon
    stamps frames from when their last byte arrived). Items a decoder returns account for
    every byte fed, in order; an item built in code rather than decoded took none (0)."""

    wire_size: int = field(default=0, kw_only=True, compare=False)


@dataclass(frozen=True, slots=True)
class BadFrame(WireSized):
    """Bytes a decoder threw away, and why.

    ``reason`` is a short stable identifier (``"crc"``, ``"garbage"``, ``"length"``,
    ``"truncated"``, ...) that health counters are keyed by; ``size`` counts every discarded
    byte while ``sample`` keeps at most :data:`BAD_FRAME_SAMPLE_BYTES` of them. Its wire size
    is ``size`` plus any framing byte that ended it (the baro codec's 0x00 delimiter).
    """

    reason: str
    size: int
    sample: bytes = b""

    @classmethod
    def of(cls, reason: str, data: bytes | bytearray | memoryview, framing: int = 0) -> BadFrame:
        """``data`` discarded for ``reason``; ``framing`` bytes on the line ended it."""
        size = len(data)
        return cls(reason, size, bytes(data[:BAD_FRAME_SAMPLE_BYTES]), wire_size=size + framing)


@dataclass(slots=True)
class DecoderStats:
    """Running totals of one decoder: good frames, discarded bytes, bad frames by reason."""

    frames: int = 0
    bytes_in: int = 0
    bytes_discarded: int = 0
    bad: Counter[str] = field(default_factory=Counter)

    def count_bad(self, bad: BadFrame) -> BadFrame:
        self.bad[bad.reason] += 1
        self.bytes_discarded += bad.size
        return bad

    def as_dict(self) -> dict[str, int]:
        """Flat counters for health messages and logs."""
        out = {
            "frames": self.frames,
            "bytes_in": self.bytes_in,
            "bytes_discarded": self.bytes_discarded,
        }
        out.update({f"bad_{reason}": n for reason, n in sorted(self.bad.items())})
        return out


#: A pending run of discarded bytes is reported once it reaches this many bytes, so a line
#: that never syncs still shows up in the counters.
MAX_DISCARD_RUN = 4096


class DiscardRun:
    """Consecutive discarded bytes, reported as one :class:`BadFrame` when the run ends.

    A run ends at the next good frame, when the reason changes, or every
    :data:`MAX_DISCARD_RUN` bytes. Reporting runs rather than single bytes keeps a decoder's
    output independent of how the stream was chunked: the same bytes give the same records.
    ``reason`` is ``None`` while the decoder is in sync.
    """

    __slots__ = ("_stats", "reason", "sample", "size")

    def __init__(self, stats: DecoderStats, reason: str | None = None) -> None:
        self._stats = stats
        self.reason = reason
        self.size = 0
        self.sample = bytearray()

    def start(self, reason: str, out: list[Any]) -> None:
        """End the current run (if any) and open one for ``reason``."""
        self.end(out)
        self.reason = reason

    def absorb(self, buf: bytes | bytearray, start: int, stop: int, out: list[Any]) -> None:
        """Discard ``buf[start:stop]``; a decoder in sync starts a ``garbage`` run."""
        if self.reason is None:
            self.reason = "garbage"
        while start < stop:
            take = min(stop - start, MAX_DISCARD_RUN - self.size)
            room = BAD_FRAME_SAMPLE_BYTES - len(self.sample)
            if room > 0:
                self.sample += buf[start : start + min(room, take)]
            self.size += take
            start += take
            if self.size >= MAX_DISCARD_RUN:
                self._emit(out)  # report it, but stay out of sync: the run goes on

    def reject(self, reason: str, buf: bytearray, pos: int, out: list[Any]) -> int:
        """Discard the frame start at ``pos`` for ``reason``; the search resumes after it."""
        self.start(reason, out)
        self.absorb(buf, pos, pos + 1, out)
        return pos + 1

    def end(self, out: list[Any], framing: int = 0) -> bool:
        """Back in sync: report what was discarded, ended by ``framing`` bytes on the line
        (a delimiter); False if there was nothing to report."""
        emitted = self._emit(out, framing)
        self.reason = None
        return emitted

    def _emit(self, out: list[Any], framing: int = 0) -> bool:
        reason, size, sample = self.reason, self.size, self.sample
        self.size = 0
        self.sample = bytearray()
        if reason is None or not size:
            return False
        bad = BadFrame(reason, size, bytes(sample), wire_size=size + framing)
        out.append(self._stats.count_bad(bad))
        return True


def flush_truncated(buf: bytearray, run: DiscardRun, process: Callable[[], list[Any]]) -> list[Any]:
    """End of stream for a length-prefixed decoder: settle what is still pending.

    An unfinished frame can no longer complete, so its first byte is discarded as
    ``truncated`` and the bytes after it are searched again (``process``): a complete frame
    that a bogus length was holding up still decodes. Then the pending run is reported.
    """
    out: list[Any] = []
    while buf:
        if run.reason != "truncated":
            run.start("truncated", out)
        run.absorb(buf, 0, 1, out)
        del buf[0]
        out += process()
    run.end(out)
    return out


MessageT = TypeVar("MessageT")


class BufferedDecoder(Generic[MessageT]):
    """A length-prefixed decoder's bookkeeping: bytes in, a bounded buffer, a discard run.

    Subclasses implement :meth:`_process`, which decodes what it can from ``_buf`` and
    removes it; ``initial_reason`` starts the run out of sync (joining a line mid-stream).
    """

    def __init__(self, initial_reason: str | None = None) -> None:
        self.stats = DecoderStats()
        self._buf = bytearray()
        self._run = DiscardRun(self.stats, initial_reason)

    def feed(self, data: bytes | bytearray | memoryview) -> list[MessageT]:
        self.stats.bytes_in += len(data)
        self._buf += data
        return self._process()

    def flush(self) -> list[MessageT]:
        """End of stream or of a line setting (baud switch): settle what is pending.

        See :func:`flush_truncated`.
        """
        return flush_truncated(self._buf, self._run, self._process)

    def _process(self) -> list[MessageT]:
        raise NotImplementedError
