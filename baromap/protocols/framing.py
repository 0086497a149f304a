"""What every decoder shares: the record of discarded bytes and the counters behind it."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

#: Discarded bytes kept in a :class:`BadFrame` for diagnosis; the rest is only counted.
BAD_FRAME_SAMPLE_BYTES = 64


@dataclass(frozen=True, slots=True)
class BadFrame:
    """Bytes a decoder threw away, and why.

    ``reason`` is a short stable identifier (``"crc"``, ``"garbage"``, ``"length"``,
    ``"truncated"``, ...) that health counters are keyed by; ``size`` counts every discarded
    byte while ``sample`` keeps at most :data:`BAD_FRAME_SAMPLE_BYTES` of them.
    """

    reason: str
    size: int
    sample: bytes = b""

    @classmethod
    def of(cls, reason: str, data: bytes | bytearray | memoryview) -> BadFrame:
        return cls(reason, len(data), bytes(data[:BAD_FRAME_SAMPLE_BYTES]))


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
