"""The barometer board's frames (our own firmware), specified in ``firmware/PROTOCOL.md``.

One codec serves both ends of the wire: the daemon decodes device frames and encodes commands,
the simulated twin encodes device frames and decodes commands, and the firmware-in-the-loop tests
do both. So there is one :class:`Decoder` for every frame type and one :func:`encode` for every
frame type; each frame is a frozen dataclass.

Frames are COBS-encoded and end with 0x00, so a receiver resynchronises at the next 0x00 whatever
came before. The decoder buffers at most :data:`MAX_ENCODED` bytes: a longer run without a
delimiter cannot be a frame and is counted, never stored.
"""

from __future__ import annotations

import binascii
import enum
import struct
from collections.abc import Iterable
from dataclasses import dataclass, fields
from typing import ClassVar, Final

from baromap.errors import EncodeError
from baromap.messages import PressureSample
from baromap.protocols.framing import BadFrame, DecoderStats, DiscardRun, WireSized

PROTOCOL_VERSION: Final = 1
DELIMITER: Final = 0x00
HEADER = struct.Struct("<BBHI")
CRC = struct.Struct("<H")
MAX_PAYLOAD: Final = 48
MIN_FRAME: Final = HEADER.size + CRC.size
MAX_FRAME: Final = HEADER.size + MAX_PAYLOAD + CRC.size
#: COBS adds one code byte per started 254 bytes; 58 decoded bytes need one.
MAX_ENCODED: Final = MAX_FRAME + 1
CRC_INIT: Final = 0xFFFF
Q24_8: Final = 256.0
SEQ_MODULO: Final = 1 << 16
TIME_MODULO: Final = 1 << 32
MAX_RATE_HZ: Final = 50
OVERSAMPLING_VALUES: Final = (1, 2, 4, 8, 16)
IIR_FILTER_VALUES: Final = (0, 2, 4, 8, 16)


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/IBM-3740 (poly 0x1021, init 0xFFFF, not reflected); check value 0x29B1."""
    return binascii.crc_hqx(data, CRC_INIT)


def cobs_encode(data: bytes | bytearray | memoryview) -> bytes:
    """COBS-encode ``data`` (without the trailing delimiter)."""
    out = bytearray()
    blocks = bytes(data).split(b"\x00")
    last = len(blocks) - 1
    for index, block in enumerate(blocks):
        # A zero-free block is cut into runs of at most 254 bytes; a full run is coded 0xFF and
        # implies no zero, the shorter run after it implies the zero that ended the block. The
        # data's final block implies no zero, so when it ends with a full run nothing follows.
        rest = block
        while len(rest) >= 254:
            out.append(0xFF)
            out += rest[:254]
            rest = rest[254:]
            if not rest and index == last:
                return bytes(out)
        out.append(len(rest) + 1)
        out += rest
    return bytes(out)


def cobs_decode(data: bytes | bytearray | memoryview) -> bytes | None:
    """Undo :func:`cobs_encode`; None if the input is not valid COBS (a zero, or a short block).

    Every code byte but the first stands where a zero was, unless a full 254-byte run (code
    0xFF) came before it: the zeros are written over the codes in a copy, which costs a frame
    less than joining its blocks (the frames here are far shorter than a full run).
    """
    src = bytes(data)
    if 0 in src:  # a zero is neither a code nor a data byte
        return None
    n = len(src)
    out = bytearray(src)
    i = 0
    while i < n:
        end = i + src[i]
        if end > n:
            return None
        if end < n:
            if src[i] == 0xFF:
                return _cobs_decode_runs(src)
            out[end] = 0
        i = end
    return bytes(out[1:])


def _cobs_decode_runs(src: bytes) -> bytes | None:
    """:func:`cobs_decode` of zero-free input with a full run that is not the last block."""
    out = bytearray()
    i = 0
    n = len(src)
    while i < n:
        end = i + src[i]
        if end > n:
            return None
        out += src[i + 1 : end]
        if src[i] != 0xFF and end < n:
            out.append(0)
        i = end
    return bytes(out)


class FrameType(enum.IntEnum):
    HELLO = 0x01
    SAMPLE = 0x02
    STATUS = 0x03
    ERROR = 0x04
    ACK = 0x05
    SET_RATE = 0x81
    SET_OVERSAMPLING = 0x82
    IDENTIFY = 0x83


class SensorModel(enum.IntEnum):
    NONE = 0
    BMP280 = 1
    BME280 = 2
    MS5611 = 3


class SensorState(enum.IntEnum):
    SEARCHING = 0
    CONFIGURING = 1
    RUNNING = 2


class ErrorCode(enum.IntEnum):
    SENSOR_NOT_FOUND = 1
    WRONG_CHIP_ID = 2
    SENSOR_LOST = 3
    BAD_CALIBRATION = 4
    SENSOR_RESET = 5
    NO_DATA = 6
    BUS_TIMEOUT = 7


class AckResult(enum.IntEnum):
    OK = 0
    BAD_VALUE = 1
    UNKNOWN_COMMAND = 2
    BAD_LENGTH = 3


class ResetCause(enum.IntFlag):
    POWER_ON = 1 << 0
    EXTERNAL = 1 << 1
    BROWN_OUT = 1 << 2
    WATCHDOG = 1 << 3


@dataclass(frozen=True, slots=True)
class FrameHeader(WireSized):
    """What every frame's header carries besides its type: the sender's sequence number (one
    counter per frame type) and its clock in microseconds, both wrapping."""

    seq: int
    time_us: int


# Every frame class adds its payload fields, in wire order, to the header's and names the
# struct that packs them.


@dataclass(frozen=True, slots=True)
class HelloFrame(FrameHeader):
    """Who the board is and how it is set up (after start, sensor (re)found, IDENTIFY)."""

    TYPE: ClassVar[FrameType] = FrameType.HELLO
    PAYLOAD: ClassVar[struct.Struct] = struct.Struct("<12B")

    protocol_minor: int
    fw_major: int
    fw_minor: int
    fw_patch: int
    sensor: int
    chip_id: int
    i2c_address: int
    rate_hz: int
    osrs_p: int
    osrs_t: int
    iir_filter: int
    reset_cause: int

    @property
    def firmware_version(self) -> str:
        return f"{self.fw_major}.{self.fw_minor}.{self.fw_patch}"


@dataclass(frozen=True, slots=True)
class SampleFrame(FrameHeader):
    """One compensated reading: pressure in Q24.8 Pa, temperature in 0.01 degC."""

    TYPE: ClassVar[FrameType] = FrameType.SAMPLE
    PAYLOAD: ClassVar[struct.Struct] = struct.Struct("<Ih")

    pressure_q24_8: int
    temperature_centi_c: int

    @property
    def pressure_pa(self) -> float:
        return self.pressure_q24_8 / Q24_8

    @property
    def temperature_c(self) -> float:
        return self.temperature_centi_c / 100.0

    @classmethod
    def from_values(
        cls, seq: int, time_us: int, pressure_pa: float, temperature_c: float
    ) -> SampleFrame:
        """Round physical values to the wire's resolution (for the simulated twin)."""
        return cls(seq, time_us, round(pressure_pa * Q24_8), round(temperature_c * 100.0))


@dataclass(frozen=True, slots=True)
class StatusFrame(FrameHeader):
    """The board's counters since reset, once a second."""

    TYPE: ClassVar[FrameType] = FrameType.STATUS
    PAYLOAD: ClassVar[struct.Struct] = struct.Struct("<9IB")

    frames_sent: int
    frames_dropped: int
    i2c_errors: int
    samples_missed: int
    rx_bytes: int
    rx_frames: int
    rx_crc_errors: int
    rx_bad_frames: int
    rx_overflows: int
    sensor_state: int

    def counters(self) -> dict[str, int]:
        """The counters by name, for health messages."""
        return {name: getattr(self, name) for name in _STATUS_COUNTERS}


_STATUS_COUNTERS = (
    "frames_sent",
    "frames_dropped",
    "i2c_errors",
    "samples_missed",
    "rx_bytes",
    "rx_frames",
    "rx_crc_errors",
    "rx_bad_frames",
    "rx_overflows",
)


@dataclass(frozen=True, slots=True)
class ErrorFrame(FrameHeader):
    """A sensor problem the board is retrying through (:class:`ErrorCode`)."""

    TYPE: ClassVar[FrameType] = FrameType.ERROR
    PAYLOAD: ClassVar[struct.Struct] = struct.Struct("<BBH")

    code: int
    detail: int
    count: int


@dataclass(frozen=True, slots=True)
class AckFrame(FrameHeader):
    """The board's answer to one host frame (:class:`AckResult`)."""

    TYPE: ClassVar[FrameType] = FrameType.ACK
    PAYLOAD: ClassVar[struct.Struct] = struct.Struct("<BHB")

    command: int
    command_seq: int
    result: int


@dataclass(frozen=True, slots=True)
class SetRateCommand(FrameHeader):
    """Host asks for ``rate_hz`` samples per second (1..50)."""

    TYPE: ClassVar[FrameType] = FrameType.SET_RATE
    PAYLOAD: ClassVar[struct.Struct] = struct.Struct("<B")

    rate_hz: int


@dataclass(frozen=True, slots=True)
class SetOversamplingCommand(FrameHeader):
    """Host sets the sensor's oversampling (1..16) and IIR filter coefficient (0..16)."""

    TYPE: ClassVar[FrameType] = FrameType.SET_OVERSAMPLING
    PAYLOAD: ClassVar[struct.Struct] = struct.Struct("<BBB")

    osrs_p: int
    osrs_t: int
    iir_filter: int


@dataclass(frozen=True, slots=True)
class IdentifyCommand(FrameHeader):
    """Host asks for a HELLO (and a blinking LED)."""

    TYPE: ClassVar[FrameType] = FrameType.IDENTIFY
    PAYLOAD: ClassVar[struct.Struct] = struct.Struct("<")


Frame = (
    HelloFrame
    | SampleFrame
    | StatusFrame
    | ErrorFrame
    | AckFrame
    | SetRateCommand
    | SetOversamplingCommand
    | IdentifyCommand
)
DeviceFrame = HelloFrame | SampleFrame | StatusFrame | ErrorFrame | AckFrame
CommandFrame = SetRateCommand | SetOversamplingCommand | IdentifyCommand

FRAME_CLASSES: Final[tuple[type[Frame], ...]] = (
    HelloFrame,
    SampleFrame,
    StatusFrame,
    ErrorFrame,
    AckFrame,
    SetRateCommand,
    SetOversamplingCommand,
    IdentifyCommand,
)
_BY_TYPE: Final[dict[int, type[Frame]]] = {int(cls.TYPE): cls for cls in FRAME_CLASSES}
#: Payload field names of each frame class, in wire order (after the header's).
PAYLOAD_FIELDS: Final[dict[type[Frame], tuple[str, ...]]] = {
    cls: tuple(f.name for f in fields(cls))[len(fields(FrameHeader)) :] for cls in FRAME_CLASSES
}


def frame_payload(frame: Frame) -> bytes:
    """The payload bytes of ``frame`` (no header, no CRC)."""
    values = [getattr(frame, name) for name in PAYLOAD_FIELDS[type(frame)]]
    try:
        return frame.PAYLOAD.pack(*values)
    except struct.error as exc:
        raise EncodeError(f"{type(frame).__name__} field out of range: {exc}") from None


def encode_raw(frame: Frame) -> bytes:
    """Header + payload + CRC of ``frame``, before COBS (what the CRC protects)."""
    if type(frame) not in PAYLOAD_FIELDS:
        raise EncodeError(f"not a baro frame: {frame!r}")
    payload = frame_payload(frame)
    try:
        header = HEADER.pack(PROTOCOL_VERSION, frame.TYPE, frame.seq, frame.time_us)
    except struct.error as exc:
        raise EncodeError(f"{type(frame).__name__} header out of range: {exc}") from None
    body = header + payload
    return body + CRC.pack(crc16(body))


def encode(frame: Frame) -> bytes:
    """The wire bytes of ``frame``: COBS(header + payload + CRC) and the 0x00 delimiter."""
    return cobs_encode(encode_raw(frame)) + b"\x00"


def encode_all(frames: Iterable[Frame]) -> bytes:
    """The wire bytes of several frames, back to back."""
    return b"".join(encode(frame) for frame in frames)


def set_rate(rate_hz: int, seq: int = 0, time_us: int = 0) -> bytes:
    """Wire bytes of a SET_RATE command (a leading 0x00 flushes the board's receiver)."""
    return b"\x00" + encode(SetRateCommand(seq, time_us, rate_hz))


def set_oversampling(
    osrs_p: int, osrs_t: int, iir_filter: int, seq: int = 0, time_us: int = 0
) -> bytes:
    """Wire bytes of a SET_OVERSAMPLING command (with a leading 0x00)."""
    return b"\x00" + encode(SetOversamplingCommand(seq, time_us, osrs_p, osrs_t, iir_filter))


def identify(seq: int = 0, time_us: int = 0) -> bytes:
    """Wire bytes of an IDENTIFY command (with a leading 0x00)."""
    return b"\x00" + encode(IdentifyCommand(seq, time_us))


def decode_raw(raw: bytes, wire_size: int = 0) -> Frame | str:
    """Frame from COBS-decoded bytes (``wire_size`` bytes on the line), or the bad-frame
    reason."""
    if len(raw) < MIN_FRAME:
        return "short"
    body = raw[:-2]
    if crc16(body) != CRC.unpack_from(raw, len(raw) - 2)[0]:
        return "crc"
    version, frame_type, seq, time_us = HEADER.unpack_from(body)
    if version != PROTOCOL_VERSION:
        return "version"
    cls = _BY_TYPE.get(frame_type)
    if cls is None:
        return "type"
    payload_size = len(body) - HEADER.size
    if payload_size < cls.PAYLOAD.size:
        return "length"
    # Longer payloads are a newer revision of the same version: the extra bytes are ignored.
    return cls(seq, time_us, *cls.PAYLOAD.unpack_from(body, HEADER.size), wire_size=wire_size)


DecodedItem = Frame | BadFrame
#: Bad-frame reasons of frames whose CRC is good.
_CRC_GOOD_REASONS: Final = frozenset({"version", "type", "length"})


class Decoder:
    """Bytes in, frames and :class:`BadFrame` records out, in wire order; never raises on input.

    Holds at most :data:`MAX_ENCODED` bytes of a frame between calls, plus as many bytes of the
    tail of an over-long run (a valid frame glued behind line noise is still recovered).
    An item's wire size counts the 0x00 that ended it; a 0x00 that ends no frame (the
    firmware's lone one at start, an empty frame) counts toward the next item (:attr:`idle`).
    """

    def __init__(self) -> None:
        self.stats = DecoderStats()
        self._buf = bytearray()
        # An over-long run without a delimiter: discarded through the shared DiscardRun, less
        # its last MAX_ENCODED bytes (the tail), which may still end in a whole frame.
        self._run = DiscardRun(self.stats)
        self._tail = b""
        #: Delimiters read that ended no frame, not yet counted in an item's wire size.
        self.idle = 0

    @property
    def _skipping(self) -> bool:
        return self._run.reason is not None

    def feed(self, data: bytes | bytearray | memoryview) -> list[DecodedItem]:
        chunk = bytes(data)
        self.stats.bytes_in += len(chunk)
        out: list[DecodedItem] = []
        start = 0
        end = len(chunk)
        discard = self._run  # skipping while it has a reason (read directly: this runs per piece)
        while start < end:
            stop = chunk.find(b"\x00", start)
            piece = chunk[start:end] if stop < 0 else chunk[start:stop]
            if discard.reason is not None:
                self._skip(piece, out)
            elif len(self._buf) + len(piece) > MAX_ENCODED:
                run = bytes(self._buf) + piece
                self._buf.clear()
                self._run.start("oversized", out)
                self._tail = b""
                self._skip(run, out)
            elif stop >= 0:
                if self._buf:
                    self._buf += piece
                    raw_frame = bytes(self._buf)
                    self._buf.clear()
                else:
                    raw_frame = piece
                if raw_frame:
                    self._decode(raw_frame, out)
                else:
                    self.idle += 1
            else:
                self._buf += piece
            if stop < 0:
                break
            if discard.reason is not None:
                self._end_skip(out, at_delimiter=True)
            start = stop + 1
        return out

    def flush(self) -> list[DecodedItem]:
        """Report whatever is buffered as truncated (end of a recording or a closed port)."""
        out: list[DecodedItem] = []
        if self._skipping:
            self._end_skip(out, at_delimiter=False)
        if self._buf:
            truncated = BadFrame.of("truncated", self._buf, self._take_idle())
            out.append(self.stats.count_bad(truncated))
            self._buf.clear()
        return out

    def _take_idle(self) -> int:
        idle, self.idle = self.idle, 0
        return idle

    @property
    def buffered(self) -> int:
        """Bytes held while waiting for a delimiter (at most :data:`MAX_ENCODED` of a frame)."""
        return len(self._buf) + len(self._tail)

    def _skip(self, piece: bytes, out: list[DecodedItem]) -> None:
        # Bytes that leave the tail window are surely garbage; the run reports them in fixed
        # blocks (DiscardRun), so counters move on an endless run and chunking changes nothing.
        tail = self._tail + piece
        gone = len(tail) - MAX_ENCODED
        if gone > 0:
            self._run.absorb(tail, 0, gone, out)
            tail = tail[gone:]
        self._tail = tail

    def _end_skip(self, out: list[DecodedItem], *, at_delimiter: bool) -> None:
        found = _glued_frame_start(self._tail, 0) if at_delimiter else None
        garbage = len(self._tail) if found is None else found[0]
        self._run.absorb(self._tail, 0, garbage, out)
        closing = 1 if at_delimiter and found is None else 0  # the delimiter ends the run
        if not self._run.end(out, closing):
            self.idle += closing
        if found is not None:
            self.stats.frames += 1
            out.append(found[1])
        self._tail = b""

    def _decode(self, encoded: bytes, out: list[DecodedItem]) -> None:
        raw = cobs_decode(encoded)
        framing = 1 + self.idle  # the delimiter, and any before it that ended nothing
        if self.idle:
            self.idle = 0
        size = len(encoded) + framing
        result: Frame | str = "cobs" if raw is None else decode_raw(raw, size)
        if not isinstance(result, str):
            self.stats.frames += 1
            out.append(result)
            return
        # Line noise right before a frame glues onto it (the frame's own delimiter is at its
        # end). Look for the longest suffix that is a whole valid frame before giving up. A
        # frame whose CRC holds is one frame (of a newer version or type): nothing is glued.
        found = None if result in _CRC_GOOD_REASONS else _glued_frame_start(encoded, 1)
        if found is None:
            out.append(self.stats.count_bad(BadFrame.of(result, encoded, framing)))
            return
        offset, frame = found
        garbage = BadFrame.of("garbage", encoded[:offset], framing - 1)
        out.append(self.stats.count_bad(garbage))
        self.stats.frames += 1
        out.append(frame)


def _glued_frame_start(encoded: bytes, first: int) -> tuple[int, Frame] | None:
    """Offset (>= ``first``) and frame of the longest suffix of ``encoded`` that is a frame
    (its wire size counts the delimiter after ``encoded``).

    Only offsets from which the COBS code chain lands exactly on the end can start a frame;
    they are found in one backward pass, so the search costs little more than one decode.
    """
    n = len(encoded)
    chain_ok = [False] * (n + 1)
    chain_ok[n] = True
    for j in range(n - 1, first - 1, -1):
        code = encoded[j]
        chain_ok[j] = code != 0 and j + code <= n and chain_ok[j + code]
    for j in range(first, n - MIN_FRAME):
        if not chain_ok[j]:
            continue
        raw = cobs_decode(encoded[j:])
        if raw is None:
            continue
        result = decode_raw(raw, n - j + 1)
        if not isinstance(result, str):
            return j, result
    return None


def to_pressure_sample(frame: SampleFrame, t_ns: int) -> PressureSample:
    """The shared message for a SAMPLE received at host time ``t_ns``."""
    return PressureSample(
        t_ns=t_ns,
        pressure_pa=frame.pressure_pa,
        temperature_c=frame.temperature_c,
        seq=frame.seq,
        device_time_us=frame.time_us,
    )


def seq_gap(previous: int, current: int) -> int:
    """Frames missing between two consecutive sequence numbers of one type (wraps at 2^16)."""
    return (current - previous - 1) % SEQ_MODULO


def time_delta_us(previous: int, current: int) -> int:
    """Device microseconds from ``previous`` to ``current`` across the 2^32 wrap."""
    return (current - previous) % TIME_MODULO
