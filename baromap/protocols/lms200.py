"""SICK LMS200 telegrams: the CRC, encoders for both directions, and a resynchronising decoder.

Both directions live here because two parts of baromap speak this protocol: the daemon's driver
(host to sensor commands out, sensor replies and B0 scans in) and the simulated twin in
``baromap.sim`` (the reverse). Each field layout is written once, in this module, so the two
sides cannot drift apart.

Telegram: ``STX | ADR | LEN (u16 LE) | CMD | data | [status] | CRC (u16 LE)``. LEN counts CMD,
data and, in sensor replies (ADR 0x80), the trailing status byte. The sensor also sends a single
ACK (0x06) or NAK (0x15) byte before it answers a command; the decoder returns those as
:class:`Ack` / :class:`Nak` messages, but only at a telegram boundary: after garbage it waits
for the next good telegram before trusting a lone 0x06 or 0x15 again.
"""

from __future__ import annotations

import enum
import functools
import math
import struct
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from baromap.errors import ConfigError, EncodeError
from baromap.messages import BeamFlag, LaserScan
from baromap.protocols.framing import BadFrame, BufferedDecoder, WireSized

STX: Final = 0x02
ACK: Final = 0x06
NAK: Final = 0x15
HOST_ADDRESS: Final = 0x00  # telegrams host -> sensor
SENSOR_ADDRESS: Final = 0x80  # telegrams sensor -> host
ADDRESSES: Final = frozenset({HOST_ADDRESS, SENSOR_ADDRESS})
HEADER_BYTES: Final = 4
CRC_BYTES: Final = 2

#: Largest LEN an LMS2xx telegram carries (sicktoolbox's maximum payload, 812 bytes); the
#: biggest B0 scan, 401 values with a real-time index, has LEN 807. A larger LEN is a
#: corrupted header, never a real telegram.
MAX_LEN: Final = 812
MAX_TELEGRAM_BYTES: Final = HEADER_BYTES + MAX_LEN + CRC_BYTES

#: Status byte healthy sensors send in every reply.
STATUS_OK: Final = 0x10
INSTALLATION_PASSWORD: Final = b"SICK_LMS"


class Command(enum.IntEnum):
    """Host -> sensor command bytes; the reply carries the command + 0x80."""

    RESET = 0x10
    SET_MODE = 0x20
    STATUS = 0x31
    TYPE = 0x3A
    VARIANT = 0x3B
    READ_CONFIG = 0x74
    WRITE_CONFIG = 0x77


class Reply(enum.IntEnum):
    """Sensor -> host reply command bytes."""

    POWER_ON = 0x90
    RESET = 0x91
    MODE = 0xA0
    SCAN = 0xB0
    STATUS = 0xB1
    MEAN_SCAN = 0xB6
    SUBRANGE_SCAN = 0xB7
    MEAN_SUBRANGE_SCAN = 0xBF
    TYPE = 0xBA
    VARIANT = 0xBB
    READ_CONFIG = 0xF4
    WRITE_CONFIG = 0xF7
    INVALID_COMMAND = 0x92


class Mode(enum.IntEnum):
    """Argument of ``SET_MODE`` (0x20): operating modes and baud switches."""

    INSTALLATION = 0x00
    CONTINUOUS = 0x24  # stream every scan (B0)
    REQUEST = 0x25  # send values on request only: "stop continuous output"
    MEAN = 0x26  # + n: stream the mean of n scans (B6)
    SUBRANGE = 0x27  # + first, last (u16, 1-based): stream those values (B7)
    MEAN_SUBRANGE = 0x28  # + n, first, last: the mean of n scans over the subrange (BF)
    BAUD_38400 = 0x40
    BAUD_19200 = 0x41
    BAUD_9600 = 0x42
    BAUD_500000 = 0x48


#: Host baud rate -> mode byte that switches the sensor to it.
BAUD_MODES: Final[dict[int, Mode]] = {
    9600: Mode.BAUD_9600,
    19200: Mode.BAUD_19200,
    38400: Mode.BAUD_38400,
    500000: Mode.BAUD_500000,
}
#: Mode byte -> baud rate, for the sensor side of a baud switch.
MODE_BAUDS: Final[dict[int, int]] = {int(mode): baud for baud, mode in BAUD_MODES.items()}
#: Scans a mean-value mode averages (sicktoolbox's bounds).
MEAN_SAMPLES: Final = range(2, 251)


class MeasuringMode(enum.IntEnum):
    """Byte 5 of the configuration block: range of the values and the flag bits above them."""

    RANGE_8_FIELDS_DAZZLE = 0x00  # 8 m (mm) / 80 m (cm); fields A, B and dazzle: the default
    RANGE_8_REFLECTOR = 0x01  # 8 / 80 m; reflector bits in 8 levels
    RANGE_8_FIELDS_ABC = 0x02  # 8 / 80 m; fields A, B and C
    RANGE_16_REFLECTOR = 0x03  # 16 m; reflector bits in 4 levels
    RANGE_16_FIELDS_AB = 0x04  # 16 m; fields A and B
    RANGE_32_REFLECTOR = 0x05  # 32 m; reflector bit in 2 levels
    RANGE_32_FIELD_A = 0x06  # 32 m; field A
    RANGE_32_IMMEDIATE = 0x0F  # 32 m; immediate transmission, no flag bits


#: Bits of a value word that carry the range in each measuring mode (sicktoolbox's masks).
RANGE_BITS: Final[dict[int, int]] = {
    MeasuringMode.RANGE_8_FIELDS_DAZZLE: 13,
    MeasuringMode.RANGE_8_REFLECTOR: 13,
    MeasuringMode.RANGE_8_FIELDS_ABC: 13,
    MeasuringMode.RANGE_16_REFLECTOR: 14,
    MeasuringMode.RANGE_16_FIELDS_AB: 14,
    MeasuringMode.RANGE_32_REFLECTOR: 15,
    MeasuringMode.RANGE_32_FIELD_A: 15,
    MeasuringMode.RANGE_32_IMMEDIATE: 16,
}
DEFAULT_RANGE_BITS: Final = 13


def range_bits(measuring_mode: int) -> int:
    """Range bits of a value word in ``measuring_mode``; ConfigError for a mode not modelled."""
    try:
        return RANGE_BITS[measuring_mode]
    except KeyError:
        raise ConfigError(f"no range measuring mode 0x{measuring_mode:02X}") from None


# ---------------------------------------------------------------------------------------------
# CRC
# ---------------------------------------------------------------------------------------------

_CRC_POLY: Final = 0x8005


def crc16_bitwise(data: bytes | bytearray | memoryview) -> int:
    """The LMS CRC exactly as SICK specifies it, one byte per step.

    Kept as the readable definition and the check for :func:`crc16`; it costs about a
    microsecond per byte, too slow for a 500 kbaud stream.
    """
    crc = 0
    prev = 0
    for byte in bytes(data):
        crc = ((crc << 1) ^ _CRC_POLY) if crc & 0x8000 else (crc << 1)
        crc = (crc & 0xFFFF) ^ ((prev << 8) | byte)
        prev = byte
    return crc


def _crc_table(rows: int) -> npt.NDArray[np.uint16]:
    """Contribution of byte value b at distance k from the end: ``b * (x^k + x^(k+7)) mod P``.

    The CRC is linear over GF(2): each step multiplies by x modulo P = x^16 + 0x8005 and adds
    ``prev << 8 | byte``. Unrolled, byte j of an n-byte telegram contributes
    ``b_j * x^k`` (its own step) plus ``b_j * x^(k+7)`` (as the high byte of the next step),
    k = n-1-j; the last byte has no next step. XOR of the table entries is the CRC.
    """
    powers = np.empty(rows + 8, dtype=np.uint32)
    value = 1
    for k in range(rows + 8):
        powers[k] = value
        value = ((value << 1) ^ _CRC_POLY) & 0xFFFF if value & 0x8000 else value << 1
    multiplier = powers[:rows].copy()
    multiplier[1:] ^= powers[8 : rows + 7]
    basis = np.empty((rows, 8), dtype=np.uint32)
    shifted = multiplier
    for bit in range(8):
        basis[:, bit] = shifted
        top = (shifted & 0x8000) != 0
        doubled = (shifted << 1) & 0xFFFF
        shifted = np.where(top, doubled ^ _CRC_POLY, doubled).astype(np.uint32)
    table = np.zeros((rows, 256), dtype=np.uint32)
    byte_values = np.arange(256)
    for bit in range(8):
        has_bit = ((byte_values >> bit) & 1).astype(bool)
        table ^= np.where(has_bit[None, :], basis[:, bit][:, None], 0).astype(np.uint32)
    return table.astype(np.uint16)


_CRC_ROWS: Final = MAX_TELEGRAM_BYTES
_CRC_FLAT: Final = _crc_table(_CRC_ROWS).reshape(-1)
#: Row offsets for k = ROWS-1 .. 0, so the last n entries index an n-byte input.
_CRC_ROW_BASE: Final = (np.arange(_CRC_ROWS - 1, -1, -1, dtype=np.int64)) * 256
#: Below this length the plain loop beats numpy's call overhead.
_CRC_TABLE_MIN: Final = 24


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16 of an LMS telegram (STX up to the last data/status byte), same as SICK's loop."""
    n = len(data)
    if n < _CRC_TABLE_MIN or n > _CRC_ROWS:
        return crc16_bitwise(data)
    index = _CRC_ROW_BASE[_CRC_ROWS - n :] + np.frombuffer(data, dtype=np.uint8)
    return int(np.bitwise_xor.reduce(_CRC_FLAT[index]))


# ---------------------------------------------------------------------------------------------
# Messages
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Ack(WireSized):
    """The sensor accepted the last command (a reply telegram follows)."""


@dataclass(frozen=True, slots=True)
class Nak(WireSized):
    """The sensor rejected the last command's framing or CRC (no reply follows)."""


ACK_MESSAGE: Final = Ack(wire_size=1)
NAK_MESSAGE: Final = Nak(wire_size=1)


class Severity(enum.IntEnum):
    """Bits 0-2 of a reply's status byte."""

    OK = 0
    INFO = 1
    WARNING = 2
    ERROR = 3
    FATAL = 4


@dataclass(frozen=True, slots=True)
class SensorStatus:
    """A reply's status byte, decoded. ``code`` is None for the reserved values 5-7."""

    raw: int
    code: Severity | None
    implausible: bool
    pollution: bool

    @property
    def healthy(self) -> bool:
        return self.code is Severity.OK and not (self.implausible or self.pollution)


def decode_status(status: int) -> SensorStatus:
    """Status byte -> severity, "implausible values" (bit 6) and "pollution" (bit 7)."""
    code = status & 0x07
    return SensorStatus(
        raw=status,
        code=Severity(code) if code <= Severity.FATAL else None,
        implausible=bool(status & 0x40),
        pollution=bool(status & 0x80),
    )


@dataclass(frozen=True, slots=True)
class Telegram(WireSized):
    """Any telegram other than a B0 scan, either direction.

    ``status`` is the trailing status byte of sensor replies (ADR 0x80) and None for host
    commands (ADR 0x00), which carry none.
    """

    address: int
    command: int
    data: bytes = b""
    status: int | None = None

    @property
    def from_sensor(self) -> bool:
        return bool(self.address & 0x80)

    def encode(self) -> bytes:
        if self.from_sensor:
            if self.status is None:
                raise EncodeError("a sensor reply needs a status byte")
            return encode_reply(self.command, self.data, self.status)
        if self.status is not None:
            raise EncodeError("host telegrams carry no status byte")
        return encode_telegram(self.command, self.data)


Units = Literal["cm", "mm"]
_UNIT_CODES: Final[dict[int, Units]] = {0: "cm", 1: "mm"}
_UNIT_BITS: Final[dict[Units, int]] = {"cm": 0, "mm": 1}
_METRES_PER_UNIT: Final[dict[Units, float]] = {"cm": 0.01, "mm": 0.001}
#: Longest range the default 8 m / 80 m mode reports, per unit.
RANGE_MAX_M: Final[dict[Units, float]] = {"cm": 81.9, "mm": 8.19}


def range_max_m(units: Units, bits: int = DEFAULT_RANGE_BITS) -> float:
    """Longest range a value word with ``bits`` range bits reports (8.19 m, 16.38 m, ... in mm)."""
    return RANGE_MAX_M[units] * (1 << (bits - DEFAULT_RANGE_BITS))


#: Angular offset of each successive partial scan of an interlaced mode, degrees.
PARTIAL_STEP_DEG: Final = 0.25
#: Documented beam counts -> (angular field, resolution) in degrees.
SCAN_GEOMETRY: Final[dict[int, tuple[float, float]]] = {
    181: (180.0, 1.0),
    361: (180.0, 0.5),
    101: (100.0, 1.0),
    201: (100.0, 0.5),
    401: (100.0, 0.25),
}

_COUNT_MASK: Final = 0x03FF
_RANGE_MASK: Final = 0x1FFF
#: Reserved 13-bit range values (default mode) and what they mean. Values from
#: FIRST_ERROR_CODE up that are not listed are treated as invalid too.
ERROR_CODES: Final[dict[int, BeamFlag]] = {
    0x1FFF: BeamFlag.INVALID,
    0x1FFE: BeamFlag.DAZZLE,
    0x1FFD: BeamFlag.OVERFLOW,
    0x1FFB: BeamFlag.LOW_SNR,
    0x1FFA: BeamFlag.CHANNEL_ERROR,
    0x1FF7: BeamFlag.OVER_RANGE,
}
FIRST_ERROR_CODE: Final = min(ERROR_CODES)
_ERROR_FLAG_LUT: Final = np.array(
    [
        int(ERROR_CODES.get(code, BeamFlag.INVALID))
        for code in range(FIRST_ERROR_CODE, _RANGE_MASK + 1)
    ],
    dtype=np.uint16,
)
#: Flag -> code for the encoder, in the order a beam with several flags is reported.
_FLAG_TO_CODE: Final = [(flag, code) for code, flag in ERROR_CODES.items()]


def _frozen_words(values: npt.ArrayLike) -> npt.NDArray[np.uint16]:
    if (
        isinstance(values, np.ndarray)
        and values.dtype == np.uint16
        and values.ndim == 1
        and not values.flags.writeable
    ):
        return values
    array = np.asarray(values)
    if array.ndim != 1:
        raise EncodeError("scan values must be a 1-D sequence")
    if array.size and (array.min() < 0 or array.max() > 0xFFFF):
        raise EncodeError("scan values must fit in 16 bits")
    words = array.astype(np.uint16, copy=True)
    words.setflags(write=False)
    return words


def _words_to_ranges_and_flags(
    words: npt.NDArray[np.uint16], units: Units, bits: int
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint16]]:
    """What :meth:`ScanTelegram.ranges_and_flags` says of each word (the definition)."""
    wide = words.astype(np.uint32)
    mask = (1 << bits) - 1
    first_error = mask - (_RANGE_MASK - FIRST_ERROR_CODE)
    ranges_raw = wide & mask
    flags = wide >> bits
    errors = ranges_raw >= first_error
    ranges = ranges_raw.astype(np.float32) * np.float32(_METRES_PER_UNIT[units])
    if errors.any():
        codes = np.where(errors, ranges_raw, first_error) - first_error
        flags = flags | np.where(errors, _ERROR_FLAG_LUT[codes], 0)
        ranges[errors] = np.nan
    return ranges, flags.astype(np.uint16)


@functools.cache
def _word_tables(units: Units, bits: int) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint16]]:
    """Range and flags of every 16-bit word, for one unit and range width (384 kB).

    A scan then costs two table look-ups instead of a dozen numpy operations: at 75 scans a
    second each operation's call overhead, not its arithmetic, is what the laser thread spent.
    """
    ranges, flags = _words_to_ranges_and_flags(np.arange(1 << 16, dtype=np.uint16), units, bits)
    ranges.setflags(write=False)
    flags.setflags(write=False)
    return ranges, flags


#: Scan replies -> (has a sample size, has a subrange) before the count word.
_SCAN_HEADERS: Final[dict[int, tuple[bool, bool]]] = {
    Reply.SCAN: (False, False),
    Reply.MEAN_SCAN: (True, False),
    Reply.SUBRANGE_SCAN: (False, True),
    Reply.MEAN_SUBRANGE_SCAN: (True, True),
}


@dataclass(frozen=True, slots=True, eq=False)
class ScanTelegram(WireSized):
    """A scan telegram: raw 16-bit range words, as the sensor sent them.

    ``reply`` is B0 (every value), B6 (mean of ``sample_size`` scans), B7 (the values of
    ``subrange``, first and last 1-based index) or BF (the mean over a subrange); the header
    fields of B6/B7/BF come before the count word as the telegram listing orders them.
    ``count_word`` is the telegram's count field: bits 0-9 the number of values, 11-12 the
    partial-scan index, 13 "partial scan", 14-15 the units (0 cm, 1 mm). ``extra`` holds the
    bytes some modes put between the values and the status byte (the real-time scan index).
    """

    count_word: int
    values: npt.NDArray[np.uint16]
    status: int = STATUS_OK
    extra: bytes = b""
    address: int = SENSOR_ADDRESS
    reply: int = Reply.SCAN
    sample_size: int | None = None
    subrange: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if self.reply not in _SCAN_HEADERS:
            raise EncodeError(f"0x{self.reply:02X} is not a scan telegram")
        mean, sub = _SCAN_HEADERS[self.reply]
        if mean != (self.sample_size is not None) or sub != (self.subrange is not None):
            raise EncodeError(f"scan telegram 0x{self.reply:02X} needs other header fields")
        words = _frozen_words(self.values)
        object.__setattr__(self, "values", words)
        if not 0 <= self.count_word <= 0xFFFF:
            raise EncodeError("count word must fit in 16 bits")
        if words.shape[0] != self.count_word & _COUNT_MASK:
            raise EncodeError(
                f"count word says {self.count_word & _COUNT_MASK} values, got {words.shape[0]}"
            )
        if (self.count_word >> 14) not in _UNIT_CODES:
            raise EncodeError("count word bits 14-15 must be 0 (cm) or 1 (mm)")

    @property
    def beam_count(self) -> int:
        return self.count_word & _COUNT_MASK

    @property
    def units(self) -> Units:
        return _UNIT_CODES[self.count_word >> 14]

    @property
    def partial(self) -> bool:
        return bool(self.count_word & 0x2000)

    @property
    def partial_index(self) -> int:
        return (self.count_word >> 11) & 0x03

    @property
    def scan_index(self) -> int | None:
        return int.from_bytes(self.extra, "little") if self.extra else None

    def sensor_status(self) -> SensorStatus:
        return decode_status(self.status)

    def ranges_and_flags(
        self, bits: int = DEFAULT_RANGE_BITS
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint16]]:
        """Ranges in metres (NaN for error codes) and BeamFlag bits, one per value.

        ``bits`` is the range width of the sensor's measuring mode (:func:`range_bits`): 13 in
        the default 8 m / 80 m mode, 15 in the 32 m modes. The reserved error values sit at the
        top of the range field in every mode; the bits above the range are raw flag bits.
        """
        range_of, flags_of = _word_tables(self.units, bits)
        ranges = range_of.take(self.values)
        flags = flags_of.take(self.values)
        # Read-only, and nobody else holds them: a LaserScan keeps them without a copy.
        ranges.setflags(write=False)
        flags.setflags(write=False)
        return ranges, flags

    def to_laser_scan(
        self, t_ns: int, field_deg: float | None = None, bits: int = DEFAULT_RANGE_BITS
    ) -> LaserScan:
        """The scan as a :class:`baromap.messages.LaserScan` (x forward, counter-clockwise).

        The angular field comes from the beam count (181/361: 180 deg, 101/201/401: 100 deg);
        for any other count the configured field must be given, else :class:`ConfigError`.
        A partial scan of an interlaced mode starts 0.25 deg x its partial index further
        counter-clockwise (as SICK's telegram listing and the reference drivers read it).
        ``bits`` is the measuring mode's range width (see :meth:`ranges_and_flags`).
        """
        n = self.beam_count
        if field_deg is None:
            if n not in SCAN_GEOMETRY:
                raise ConfigError(f"{n} beams has no documented field; pass field_deg")
            field_deg, resolution_deg = SCAN_GEOMETRY[n]
        else:
            resolution_deg = field_deg / max(n - 1, 1)
        ranges, flags = self.ranges_and_flags(bits)
        return LaserScan(
            t_ns=t_ns,
            angle_min_rad=math.radians(PARTIAL_STEP_DEG * self.partial_index - field_deg / 2.0),
            angle_increment_rad=math.radians(resolution_deg),
            range_max_m=range_max_m(self.units, bits),
            ranges_m=ranges,
            flags=flags,
            status=self.status,
            scan_index=self.scan_index,
        )

    def encode(self) -> bytes:
        head = b""
        try:
            if self.sample_size is not None:
                head += bytes((self.sample_size,))
            if self.subrange is not None:
                head += _SUBRANGE.pack(*self.subrange)
        except (ValueError, struct.error) as exc:
            raise EncodeError(f"scan header out of range: {exc}") from exc
        payload = head + _SCAN_COUNT.pack(self.count_word) + self.values.astype("<u2").tobytes()
        return encode_reply(self.reply, payload + self.extra, self.status)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ScanTelegram):
            return NotImplemented
        return (
            self.count_word == other.count_word
            and self.status == other.status
            and self.extra == other.extra
            and self.address == other.address
            and self.reply == other.reply
            and self.sample_size == other.sample_size
            and self.subrange == other.subrange
            and np.array_equal(self.values, other.values)
        )

    __hash__ = None  # type: ignore[assignment]


LmsMessage = Ack | Nak | Telegram | ScanTelegram | BadFrame

# ---------------------------------------------------------------------------------------------
# Encoders
# ---------------------------------------------------------------------------------------------

_LEN: Final = struct.Struct("<H")
_SCAN_COUNT: Final = struct.Struct("<H")
_SUBRANGE: Final = struct.Struct("<HH")
_VARIANT: Final = struct.Struct("<HH")
_CRC: Final = struct.Struct("<H")


def _byte(value: int, what: str) -> int:
    if not 0 <= value <= 0xFF:
        raise EncodeError(f"{what} {value} does not fit in a byte")
    return value


def _frame(address: int, payload: bytes) -> bytes:
    if len(payload) > MAX_LEN:
        raise EncodeError(f"telegram payload of {len(payload)} bytes exceeds LEN {MAX_LEN}")
    body = bytes((STX, address)) + _LEN.pack(len(payload)) + payload
    return body + _CRC.pack(crc16(body))


def encode_telegram(command: int, data: bytes = b"") -> bytes:
    """A host -> sensor telegram (ADR 0x00) with its CRC."""
    return _frame(HOST_ADDRESS, bytes((_byte(command, "command"),)) + bytes(data))


def encode_reply(command: int, data: bytes = b"", status: int = STATUS_OK) -> bytes:
    """A sensor -> host telegram (ADR 0x80): the reply command, data and status byte."""
    payload = bytes((_byte(command, "command"),)) + bytes(data) + bytes((_byte(status, "status"),))
    return _frame(SENSOR_ADDRESS, payload)


def scan_count_word(
    beam_count: int, units: Units = "mm", *, partial: bool = False, partial_index: int = 0
) -> int:
    """The B0 count field for ``beam_count`` values."""
    if not 0 <= beam_count <= _COUNT_MASK:
        raise EncodeError(f"{beam_count} values do not fit the 10-bit count")
    if not 0 <= partial_index <= 3:
        raise EncodeError("partial scan index is 0..3")
    if units not in _UNIT_BITS:
        raise EncodeError(f"units must be 'cm' or 'mm', not {units!r}")
    return beam_count | partial_index << 11 | int(partial) << 13 | _UNIT_BITS[units] << 14


def encode_scan(
    values: npt.ArrayLike,
    *,
    units: Units = "mm",
    status: int = STATUS_OK,
    partial: bool = False,
    partial_index: int = 0,
    extra: bytes = b"",
    sample_size: int | None = None,
    subrange: tuple[int, int] | None = None,
) -> bytes:
    """A complete scan telegram from raw 16-bit range words (see :func:`range_words`).

    B0 by default; a ``sample_size`` makes it a mean-value B6, a ``subrange`` a B7, both a BF.
    """
    words = _frozen_words(values)
    count = scan_count_word(words.shape[0], units, partial=partial, partial_index=partial_index)
    reply = {
        (False, False): Reply.SCAN,
        (True, False): Reply.MEAN_SCAN,
        (False, True): Reply.SUBRANGE_SCAN,
        (True, True): Reply.MEAN_SUBRANGE_SCAN,
    }[(sample_size is not None, subrange is not None)]
    return ScanTelegram(
        count,
        words,
        status,
        bytes(extra),
        reply=reply,
        sample_size=sample_size,
        subrange=subrange,
    ).encode()


def range_words(
    ranges_m: npt.ArrayLike,
    flags: npt.ArrayLike | None = None,
    *,
    units: Units = "mm",
    bits: int = DEFAULT_RANGE_BITS,
) -> npt.NDArray[np.uint16]:
    """Ranges in metres (and optional BeamFlag bits) -> the words a B0 telegram carries.

    The inverse of :meth:`ScanTelegram.ranges_and_flags`, up to the unit's resolution: NaN
    becomes "invalid", a range the ``bits``-wide field cannot hold becomes "over range", a beam
    flagged with an error keeps that error's code, and raw flag bits go above the range field
    (as many as fit: three in the default mode, one in the 32 m modes, none at 16 bits).
    """
    if bits not in RANGE_BITS.values():
        raise EncodeError(f"value words have 13 to 16 range bits, not {bits}")
    ranges = np.asarray(ranges_m, dtype=np.float64)
    if ranges.ndim != 1:
        raise EncodeError("ranges must be a 1-D sequence")
    offset = ((1 << bits) - 1) - _RANGE_MASK  # error codes move to the top of a wider field
    with np.errstate(invalid="ignore"):
        counts = np.rint(ranges / _METRES_PER_UNIT[units])
        invalid = np.isnan(ranges) | (ranges < 0)
        over = ~invalid & (counts >= FIRST_ERROR_CODE + offset)
    counts = np.nan_to_num(counts, nan=0.0, posinf=0.0, neginf=0.0)
    words = np.where(invalid, 0x1FFF + offset, np.where(over, 0x1FF7 + offset, counts)).astype(
        np.uint32
    )
    if flags is not None:
        beam_flags = np.asarray(flags, dtype=np.uint32)
        if beam_flags.shape != ranges.shape:
            raise EncodeError("flags must have one entry per range")
        for flag, code in _FLAG_TO_CODE:
            words = np.where((beam_flags & int(flag)) != 0, code + offset, words)
        words |= (beam_flags & ((1 << (16 - bits)) - 1) & 0x7) << bits
    out = words.astype(np.uint16)
    out.setflags(write=False)
    return out


# Command builders: every telegram of the init sequence, host -> sensor.


def status_request() -> bytes:
    return encode_telegram(Command.STATUS)


def type_request() -> bytes:
    return encode_telegram(Command.TYPE)


def set_mode(mode: int, data: bytes = b"") -> bytes:
    return encode_telegram(Command.SET_MODE, bytes((_byte(mode, "mode"),)) + data)


def switch_baud(baud: int) -> bytes:
    """Ask the sensor to change to ``baud``; the host follows after the A0 reply."""
    if baud not in BAUD_MODES:
        raise EncodeError(f"LMS200 speaks {sorted(BAUD_MODES)} baud, not {baud}")
    return set_mode(BAUD_MODES[baud])


def start_continuous() -> bytes:
    return set_mode(Mode.CONTINUOUS)


def start_mean(sample_size: int) -> bytes:
    """Stream the mean of ``sample_size`` scans (2..250): B6 telegrams."""
    if sample_size not in MEAN_SAMPLES:
        raise EncodeError(f"mean values take 2..250 scans, not {sample_size}")
    return set_mode(Mode.MEAN, bytes((sample_size,)))


def start_subrange(first: int, last: int) -> bytes:
    """Stream values ``first``..``last`` (1-based, inclusive): B7 telegrams."""
    return set_mode(Mode.SUBRANGE, _subrange(first, last))


def start_mean_subrange(sample_size: int, first: int, last: int) -> bytes:
    """Stream the mean of ``sample_size`` scans over values ``first``..``last``: BF."""
    if sample_size not in MEAN_SAMPLES:
        raise EncodeError(f"mean values take 2..250 scans, not {sample_size}")
    return set_mode(Mode.MEAN_SUBRANGE, bytes((sample_size,)) + _subrange(first, last))


def _subrange(first: int, last: int) -> bytes:
    if not 1 <= first <= last <= _COUNT_MASK:
        raise EncodeError(f"subrange {first}..{last} is not 1 <= first <= last")
    return _SUBRANGE.pack(first, last)


def reset() -> bytes:
    """Software reset: the sensor answers 91, restarts at 9600 baud and later sends 90."""
    return encode_telegram(Command.RESET)


def reset_reply(status: int = STATUS_OK) -> bytes:
    return encode_reply(Reply.RESET, b"", status)


def power_on_telegram(text: str, status: int = STATUS_OK) -> bytes:
    """The 90 telegram a sensor sends when it is up (after power-on or a reset).

    Drivers only look at the command byte; the text (software version, "LMS ready") is
    informative.
    """
    return encode_reply(Reply.POWER_ON, text.encode("ascii"), status)


def stop_continuous() -> bytes:
    return set_mode(Mode.REQUEST)


def installation_mode(password: bytes = INSTALLATION_PASSWORD) -> bytes:
    if len(password) != len(INSTALLATION_PASSWORD):
        raise EncodeError("the installation password is 8 bytes")
    return set_mode(Mode.INSTALLATION, password)


VARIANTS: Final = frozenset({(180, 100), (180, 50), (100, 100), (100, 50), (100, 25)})


def set_variant(angle_deg: int, resolution_cdeg: int) -> bytes:
    """Angular field (100 or 180 deg) and resolution in 0.01 deg (25, 50, 100)."""
    if (angle_deg, resolution_cdeg) not in VARIANTS:
        raise EncodeError(f"no LMS200 variant {angle_deg} deg at {resolution_cdeg / 100} deg")
    return encode_telegram(Command.VARIANT, _VARIANT.pack(angle_deg, resolution_cdeg))


def config_request() -> bytes:
    return encode_telegram(Command.READ_CONFIG)


# ---------------------------------------------------------------------------------------------
# Configuration block (0x77 write / 0xF4 read / 0xF7 write reply)
# ---------------------------------------------------------------------------------------------

_CONFIG: Final = struct.Struct("<H11B15B2B2H")  # 34 bytes, the LMS200 configuration block
#: The shortest 77 block a driver in use sends (ARIA's): 32 bytes.
MIN_CONFIG_BLOCK: Final = 32
#: The configuration's availability byte: bit 1 asks for the real-time scan index in scans.
AVAILABILITY_SCAN_INDEX: Final = 0x02


@dataclass(frozen=True, slots=True)
class LmsConfig:
    """The 34-byte configuration block; ``units`` selects cm (0) or mm (1) range words.

    Field order follows the LMS2xx telegram listing (as sicktoolbox writes it): blanking,
    stop threshold, peak threshold, availability, measuring mode, units, temporary field,
    subtractive fields, multiple evaluation, restart, restart time, multiple evaluation for
    suppressed objects, contours A-C (5 bytes each), pixel-oriented evaluation, single value
    evaluation mode, restart times of fields B/C, multiple evaluation for dazzling.
    """

    blanking: int = 0
    stop_threshold: int = 0
    peak_threshold: int = 0
    availability: int = 0
    measuring_mode: int = 0
    units: int = 1
    temporary_field: int = 0
    subtractive_fields: int = 0
    multiple_evaluation: int = 2
    restart: int = 0
    restart_time: int = 0
    suppressed_evaluation: int = 0
    contours: tuple[int, ...] = (0,) * 15
    pixel_oriented_evaluation: int = 0
    single_value_evaluation: int = 0
    fields_bc_restart_times: int = 0
    dazzle_evaluation: int = 0

    def pack(self) -> bytes:
        if len(self.contours) != _CONTOUR_BYTES:
            raise EncodeError("contours hold 3 x 5 bytes")
        head = [getattr(self, name) for name in _CONFIG_HEAD]
        tail = [getattr(self, name) for name in _CONFIG_TAIL]
        try:
            return _CONFIG.pack(*head, *self.contours, *tail)
        except struct.error as exc:
            raise EncodeError(f"configuration field out of range: {exc}") from exc

    def updated(self, block: bytes) -> LmsConfig | None:
        """This configuration with the leading fields a 77 telegram's ``block`` carries.

        Firmware generations differ in how long the block is: sicktoolbox, MRPT and Player
        send all 34 bytes, ARIA sends 32 (its layout ends early). Both work on real sensors,
        so the sensor takes the fields present by position and keeps the rest. None for a
        block shorter than :data:`MIN_CONFIG_BLOCK` or longer than the full one.
        """
        if not MIN_CONFIG_BLOCK <= len(block) <= _CONFIG.size:
            return None
        merged = bytes(block) + self.pack()[len(block) :]
        return LmsConfig.unpack(merged)

    @classmethod
    def unpack(cls, block: bytes) -> LmsConfig | None:
        """The block, or None if ``block`` is not exactly 34 bytes."""
        if len(block) != _CONFIG.size:
            return None
        values: tuple[int, ...] = _CONFIG.unpack(block)
        head = dict(zip(_CONFIG_HEAD, values, strict=False))
        contours = values[len(_CONFIG_HEAD) : len(_CONFIG_HEAD) + _CONTOUR_BYTES]
        tail = dict(zip(_CONFIG_TAIL, values[len(_CONFIG_HEAD) + _CONTOUR_BYTES :], strict=True))
        return cls(**head, contours=contours, **tail)


#: Field order of the block around the 15 contour bytes (one list for pack and unpack).
_CONFIG_HEAD: Final = (
    "blanking",
    "stop_threshold",
    "peak_threshold",
    "availability",
    "measuring_mode",
    "units",
    "temporary_field",
    "subtractive_fields",
    "multiple_evaluation",
    "restart",
    "restart_time",
    "suppressed_evaluation",
)
_CONTOUR_BYTES: Final = 15
_CONFIG_TAIL: Final = (
    "pixel_oriented_evaluation",
    "single_value_evaluation",
    "fields_bc_restart_times",
    "dazzle_evaluation",
)


def set_config(config: LmsConfig) -> bytes:
    return encode_telegram(Command.WRITE_CONFIG, config.pack())


def config_reply(config: LmsConfig, status: int = STATUS_OK) -> bytes:
    """Sensor's F4 answer to :func:`config_request`."""
    return encode_reply(Reply.READ_CONFIG, config.pack(), status)


def config_write_reply(accepted: bool, config: LmsConfig, status: int = STATUS_OK) -> bytes:
    """Sensor's F7 answer to :func:`set_config`: 01 accepted, then the block now in force."""
    return encode_reply(Reply.WRITE_CONFIG, bytes((int(accepted),)) + config.pack(), status)


def parse_config_write_reply(telegram: Telegram) -> tuple[bool, LmsConfig | None] | None:
    if telegram.command != Reply.WRITE_CONFIG or not telegram.data:
        return None
    return telegram.data[0] == 1, LmsConfig.unpack(telegram.data[1:])


# ---------------------------------------------------------------------------------------------
# Other replies the init sequence reads
# ---------------------------------------------------------------------------------------------


class ModeResult(enum.IntEnum):
    """First data byte of an A0 reply."""

    OK = 0
    WRONG_PASSWORD = 1


def mode_reply(result: int = ModeResult.OK, status: int = STATUS_OK) -> bytes:
    return encode_reply(Reply.MODE, bytes((_byte(result, "result"),)), status)


def mode_result(telegram: Telegram) -> int | None:
    """The A0 result byte (0 = mode changed), or None if this is not an A0 reply."""
    if telegram.command != Reply.MODE or not telegram.data:
        return None
    return telegram.data[0]


@dataclass(frozen=True, slots=True)
class VariantReply:
    """BB reply: whether the variant was taken, and the field/resolution now in force."""

    accepted: bool
    angle_deg: int
    resolution_cdeg: int


def variant_reply(reply: VariantReply, status: int = STATUS_OK) -> bytes:
    data = bytes((int(reply.accepted),)) + _VARIANT.pack(reply.angle_deg, reply.resolution_cdeg)
    return encode_reply(Reply.VARIANT, data, status)


def parse_variant_reply(telegram: Telegram) -> VariantReply | None:
    data = telegram.data
    if telegram.command != Reply.VARIANT or len(data) != 1 + _VARIANT.size:
        return None
    angle, resolution = _VARIANT.unpack_from(data, 1)
    return VariantReply(data[0] == 1, angle, resolution)


def type_reply(type_string: str, status: int = STATUS_OK) -> bytes:
    return encode_reply(Reply.TYPE, type_string.encode("ascii"), status)


def parse_type_reply(telegram: Telegram) -> str | None:
    if telegram.command != Reply.TYPE:
        return None
    return telegram.data.decode("ascii", errors="replace").rstrip("\x00 ")


@dataclass(frozen=True, slots=True)
class StatusReport:
    """The fields of a B1 status reply baromap uses, at the offsets sicktoolbox reads them.

    Offsets are into the reply's data (after the B1 byte): software version 0-6, operating
    mode 7, device status 8 (0 ok), variant 17, measuring mode 101, field u16 106, resolution
    u16 108, address 119, units 121, laser on 122, boot PROM version 123-129.
    """

    software_version: str = "V02.10 "
    operating_mode: int = Mode.REQUEST
    device_status: int = 0
    variant: int = 0
    measuring_mode: int = 0
    angle_deg: int = 180
    resolution_cdeg: int = 100
    address: int = 0
    units: int = 1
    laser_on: int = 1
    prom_version: str = "V01.01 "


STATUS_DATA_BYTES: Final = 130  # enough to hold every field above; real replies are longer
#: A real B1 reply's data: sicktoolbox reads up to the calibration interval, a u16 at data
#: bytes 150-151 (its payload index 151 counts the B1 byte).
STATUS_FULL_BYTES: Final = 152
_STATUS_FIELDS: Final = struct.Struct("<HH")


def status_reply(
    report: StatusReport, status: int = STATUS_OK, size: int = STATUS_FULL_BYTES
) -> bytes:
    if size < STATUS_DATA_BYTES:
        raise EncodeError(f"a B1 reply needs at least {STATUS_DATA_BYTES} data bytes")
    data = bytearray(size)
    data[0:7] = report.software_version.encode("ascii")[:7].ljust(7)
    data[7] = _byte(report.operating_mode, "operating mode")
    data[8] = _byte(report.device_status, "device status")
    data[17] = _byte(report.variant, "variant")
    data[101] = _byte(report.measuring_mode, "measuring mode")
    _STATUS_FIELDS.pack_into(data, 106, report.angle_deg, report.resolution_cdeg)
    data[119] = _byte(report.address, "address")
    data[121] = _byte(report.units, "units")
    data[122] = _byte(report.laser_on, "laser on")
    data[123:130] = report.prom_version.encode("ascii")[:7].ljust(7)
    return encode_reply(Reply.STATUS, bytes(data), status)


def parse_status_reply(telegram: Telegram) -> StatusReport | None:
    data = telegram.data
    if telegram.command != Reply.STATUS or len(data) < STATUS_DATA_BYTES:
        return None
    angle, resolution = _STATUS_FIELDS.unpack_from(data, 106)
    return StatusReport(
        software_version=data[0:7].decode("ascii", errors="replace"),
        operating_mode=data[7],
        device_status=data[8],
        variant=data[17],
        measuring_mode=data[101],
        angle_deg=angle,
        resolution_cdeg=resolution,
        address=data[119],
        units=data[121],
        laser_on=data[122],
        prom_version=data[123:130].decode("ascii", errors="replace"),
    )


# ---------------------------------------------------------------------------------------------
# Decoder
# ---------------------------------------------------------------------------------------------

_STX_BYTE: Final = bytes((STX,))


class Decoder(BufferedDecoder[LmsMessage]):
    """Bytes in, LMS messages out; usable on either side of the line.

    It accepts host (ADR 0x00) and sensor (ADR 0x80) telegrams, bounds LEN by
    :data:`MAX_LEN` before waiting for a body, checks the CRC, and on any rejection resumes
    the search at the byte after the rejected STX, so a real telegram that starts inside the
    rejected bytes is still found. Discarded bytes are reported as one :class:`BadFrame` per
    run (reason of what started the run: ``garbage``, ``length``, ``crc``), emitted when the
    run ends, so the output never depends on how the stream was chunked. A CRC-valid telegram
    whose content contradicts itself (a B0 count that does not match LEN) is ``format``.

    A header whose LEN is plausible holds up telegrams behind it until LEN bytes arrived; on a
    live stream that is at most one telegram time. Call :meth:`flush` at the end of a stream
    or when the line changes (baud switch) to report what is pending and start afresh.

    ``at_boundary=False`` is for joining a line mid-stream (a port opened onto a sensor that
    may be streaming): nothing before the first good telegram is read as an ACK or NAK.
    """

    def __init__(self, *, at_boundary: bool = True) -> None:
        # No run (None): at a telegram boundary, where a lone 0x06 / 0x15 is an ACK / NAK.
        super().__init__(None if at_boundary else "garbage")

    def _process(self) -> list[LmsMessage]:
        buf = self._buf
        out: list[LmsMessage] = []
        pos = 0
        end = len(buf)
        while pos < end:
            if self._run.reason is None:
                byte = buf[pos]
                if byte in (ACK, NAK):
                    out.append(ACK_MESSAGE if byte == ACK else NAK_MESSAGE)
                    self.stats.frames += 1
                    pos += 1
                    continue
                if byte != STX:
                    self._run.start("garbage", out)
                    continue
            else:
                found = buf.find(_STX_BYTE, pos)
                stop = end if found < 0 else found
                if stop > pos:
                    self._run.absorb(buf, pos, stop, out)
                    pos = stop
                    continue
            next_pos = self._candidate(buf, pos, end, out)
            if next_pos < 0:
                break
            pos = next_pos
        del buf[:pos]
        return out

    # -- telegrams -------------------------------------------------------------------------

    def _candidate(self, buf: bytearray, pos: int, end: int, out: list[LmsMessage]) -> int:
        """Decode the telegram starting at ``pos`` (an STX): new position, or -1 for more."""
        if end - pos < 2:
            return -1
        address = buf[pos + 1]
        if address not in ADDRESSES:
            self._run.absorb(buf, pos, pos + 1, out)
            return pos + 1
        if end - pos < HEADER_BYTES:
            return -1
        length = buf[pos + 2] | buf[pos + 3] << 8
        if not (2 if address & 0x80 else 1) <= length <= MAX_LEN:
            return self._run.reject("length", buf, pos, out)
        stop = pos + HEADER_BYTES + length + CRC_BYTES
        if stop > end:
            return -1
        frame = bytes(buf[pos:stop])
        if crc16(frame[:-CRC_BYTES]) != frame[-2] | frame[-1] << 8:
            return self._run.reject("crc", buf, pos, out)
        self._run.end(out)
        message = _decode_frame(frame, address)
        if isinstance(message, BadFrame):
            out.append(self.stats.count_bad(message))
        else:
            self.stats.frames += 1
            out.append(message)
        return stop


def _decode_frame(frame: bytes, address: int) -> Telegram | ScanTelegram | BadFrame:
    command = frame[HEADER_BYTES]
    size = len(frame)
    if not address & 0x80:
        return Telegram(address, command, frame[HEADER_BYTES + 1 : -CRC_BYTES], wire_size=size)
    status = frame[-CRC_BYTES - 1]
    data = frame[HEADER_BYTES + 1 : -CRC_BYTES - 1]
    if command not in _SCAN_HEADERS:
        return Telegram(address, command, data, status, wire_size=size)
    return _decode_scan(frame, command, data, status)


def _decode_scan(frame: bytes, reply: int, data: bytes, status: int) -> ScanTelegram | BadFrame:
    mean, sub = _SCAN_HEADERS[reply]
    pos = int(mean) + (_SUBRANGE.size if sub else 0)
    if len(data) < pos + _SCAN_COUNT.size:
        return BadFrame.of("format", frame)
    sample_size = data[0] if mean else None
    subrange = _SUBRANGE.unpack_from(data, int(mean)) if sub else None
    (count_word,) = _SCAN_COUNT.unpack_from(data, pos)
    n = count_word & _COUNT_MASK
    values_start = pos + _SCAN_COUNT.size
    values_end = values_start + 2 * n
    if values_end > len(data) or (count_word >> 14) not in _UNIT_CODES:
        return BadFrame.of("format", frame)
    # A read-only view of the telegram's own (immutable) bytes: no copy on a little-endian
    # host, where the line's word order is the native one.
    words = np.frombuffer(data, dtype="<u2", count=n, offset=values_start)
    if words.dtype != np.uint16:  # a big-endian host
        words = words.astype(np.uint16)
        words.setflags(write=False)
    return ScanTelegram(
        count_word,
        words,
        status,
        data[values_end:],
        reply=reply,
        sample_size=sample_size,
        subrange=subrange,
        wire_size=len(frame),
    )
