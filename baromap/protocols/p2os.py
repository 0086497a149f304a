"""Pioneer P2OS / ARCOS packets: checksum, encoders both ways, decoder.

Both directions live here: the daemon's driver sends commands and decodes SYNC echoes, SIPs and
CONFIG packets; the simulated robot in ``baromap.sim`` decodes the commands and encodes the
replies. Every field layout is written once (the SIP and CONFIG tables below) and used by both.

Packet: ``FA FB | COUNT | data | CHK_hi CHK_lo`` with COUNT = len(data) + 2. The first data
byte is the command (host -> robot) or the packet type (robot -> host). Telling a SYNC echo from
other robot packets needs no handshake state: ARCOS types are 0x20 (CONFIG), 0x3X (SIPs),
0x90, 0xF0, ... so a packet whose type is 0, 1 or 2 can only be a SYNC echo.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass
from typing import Any, Final, Literal

from baromap.errors import ConfigError, EncodeError
from baromap.protocols.framing import BadFrame, BufferedDecoder, WireSized

SYNC: Final = b"\xfa\xfb"
HEADER_BYTES: Final = 3
CHECKSUM_BYTES: Final = 2
#: Every packet has at least its command/type byte.
MIN_COUNT: Final = 1 + CHECKSUM_BYTES
#: ARIA's receiver: "spec says packet max size is 200".
MAX_COUNT: Final = 200
MAX_DATA: Final = MAX_COUNT - CHECKSUM_BYTES


class Command(enum.IntEnum):
    """Host -> robot command numbers (the handshake reuses 0-2 as SYNC0-2)."""

    PULSE = 0
    OPEN = 1
    CLOSE = 2
    ENABLE = 4
    SETA = 5
    SETV = 6
    SETO = 7
    VEL = 11
    CONFIG = 18
    RVEL = 21
    SONAR = 28
    STOP = 29
    HOSTBAUD = 50
    ESTOP = 55
    SYNC0 = 0
    SYNC1 = 1
    SYNC2 = 2


class ArgType(enum.IntEnum):
    """Argument type byte after the command."""

    INT = 0x3B  # non-negative integer, u16 LE
    NEG_INT = 0x1B  # negative integer, magnitude as u16 LE
    STRING = 0x2B  # length byte, then the characters


class PacketType(enum.IntEnum):
    """Robot -> host packet types baromap decodes."""

    SYNC0 = 0x00
    SYNC1 = 0x01
    SYNC2 = 0x02
    CONFIG = 0x20
    SIP_STOPPED = 0x32
    SIP_MOVING = 0x33


# ---------------------------------------------------------------------------------------------
# Checksum and framing
# ---------------------------------------------------------------------------------------------

_WORDS: Final = [struct.Struct(f">{n}H") for n in range(MAX_COUNT // 2 + 1)]


def checksum(data: bytes | bytearray | memoryview) -> int:
    """Sum of big-endian 16-bit words mod 65536, an odd trailing byte XORed in."""
    n = len(data)
    words = _WORDS[n >> 1] if n >> 1 < len(_WORDS) else struct.Struct(f">{n >> 1}H")
    total = int(sum(words.unpack_from(data))) & 0xFFFF
    if n & 1:
        total ^= data[n - 1]
    return total


def encode_packet(data: bytes) -> bytes:
    """Header, COUNT and checksum around ``data`` (command or type byte first)."""
    if not 1 <= len(data) <= MAX_DATA:
        raise EncodeError(f"P2OS packets carry 1..{MAX_DATA} data bytes, not {len(data)}")
    chk = checksum(data)
    return SYNC + bytes((len(data) + CHECKSUM_BYTES,)) + bytes(data) + bytes((chk >> 8, chk & 0xFF))


# ---------------------------------------------------------------------------------------------
# Host -> robot commands
# ---------------------------------------------------------------------------------------------

_U16: Final = struct.Struct("<H")
INT_ARG_MIN: Final = -0x8000  # ARCOS integers are 2-byte shorts
INT_ARG_MAX: Final = 0x7FFF


@dataclass(frozen=True, slots=True)
class CommandPacket(WireSized):
    """A command as the robot receives it: no argument, an integer, or a string."""

    command: int
    argument: int | bytes | None = None

    def encode(self) -> bytes:
        return encode_command(self.command, self.argument)


def encode_command(command: int, argument: int | bytes | None = None) -> bytes:
    """A complete command packet; integers go out as 0x3B/0x1B + u16, bytes as 0x2B strings."""
    if not 0 <= command <= 0xFF:
        raise EncodeError(f"command {command} does not fit in a byte")
    data = bytes((command,))
    if isinstance(argument, int):
        if not INT_ARG_MIN <= argument <= INT_ARG_MAX:
            raise EncodeError(f"integer argument {argument} is not a 2-byte short")
        kind = ArgType.INT if argument >= 0 else ArgType.NEG_INT
        data += bytes((kind,)) + _U16.pack(abs(argument))
    elif argument is not None:
        if len(argument) > min(0xFF, MAX_DATA - 3):
            raise EncodeError(f"string argument of {len(argument)} bytes is too long")
        data += bytes((ArgType.STRING, len(argument))) + bytes(argument)
    return encode_packet(data)


def sync(step: int) -> bytes:
    """SYNC0, SYNC1 or SYNC2: the handshake's three packets."""
    if step not in (0, 1, 2):
        raise EncodeError(f"there is no SYNC{step}")
    return encode_command(step)


def pulse() -> bytes:
    """Keepalive: resets the robot's communication watchdog."""
    return encode_command(Command.PULSE)


def open_controller() -> bytes:
    """OPEN: start the servers (SIPs every cycle) after the handshake."""
    return encode_command(Command.OPEN)


def close_controller() -> bytes:
    return encode_command(Command.CLOSE)


def enable_motors(enabled: bool = True) -> bytes:
    return encode_command(Command.ENABLE, int(enabled))


def vel(mm_per_s: int) -> bytes:
    """Translational velocity setpoint, mm/s."""
    return encode_command(Command.VEL, mm_per_s)


def rvel(deg_per_s: int) -> bytes:
    """Rotational velocity setpoint, deg/s."""
    return encode_command(Command.RVEL, deg_per_s)


def stop() -> bytes:
    return encode_command(Command.STOP)


def reset_odometry() -> bytes:
    """SETO: the robot's position counters and heading go back to 0."""
    return encode_command(Command.SETO)


#: HOSTBAUD argument for each host baud rate (ARIA's SwitchToBaudRate handling).
HOST_BAUD_CODES: Final[dict[int, int]] = {9600: 0, 19200: 1, 38400: 2, 57600: 3, 115200: 4}


def host_baud(baud: int) -> bytes:
    """HOSTBAUD: the robot answers at ``baud`` from the next packet on; the host follows."""
    if baud not in HOST_BAUD_CODES:
        raise EncodeError(f"P2OS speaks {sorted(HOST_BAUD_CODES)} baud, not {baud}")
    return encode_command(Command.HOSTBAUD, HOST_BAUD_CODES[baud])


def config_request() -> bytes:
    """CONFIG: ask for one CONFIG packet (ARIA sends the argument 1)."""
    return encode_command(Command.CONFIG, 1)


# ---------------------------------------------------------------------------------------------
# Robot -> host packets
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SyncEcho(WireSized):
    """The robot echoed SYNC0 or SYNC1 (step 0 or 1; 2 only if it sent no strings)."""

    step: int

    def encode(self) -> bytes:
        if self.step not in (0, 1, 2):
            raise EncodeError(f"there is no SYNC{self.step} echo")
        return encode_packet(bytes((self.step,)))


@dataclass(frozen=True, slots=True)
class Sync2Info(WireSized):
    """The SYNC2 echo: robot name, class and subclass (NUL-terminated on the wire)."""

    name: str
    robot_class: str
    subclass: str

    def encode(self) -> bytes:
        parts = (self.name, self.robot_class, self.subclass)
        if any("\x00" in part for part in parts):
            raise EncodeError("SYNC2 strings cannot contain NUL")
        body = b"".join(part.encode("latin-1") + b"\x00" for part in parts)
        return encode_packet(bytes((PacketType.SYNC2,)) + body)


_SIP_HEAD: Final = struct.Struct("<BHHhhhBHhHBB")  # type ... compass, sonar count: 20 bytes
#: Fields of _SIP_HEAD after type, x and y, in wire order.
_SIP_HEAD_FIELDS: Final = (
    "theta",
    "left_vel",
    "right_vel",
    "battery_dv",
    "stall_bumpers",
    "control",
    "flags",
    "compass",
)
_SONAR: Final = struct.Struct("<BH")
POSITION_MASK: Final = 0x7FFF

#: Optional SIP fields newer firmware appends, in wire order; each group is read only if all
#: its bytes remain (ARIA reads them one after another while bytes remain).
SIP_TAIL: Final[tuple[tuple[tuple[str, ...], struct.Struct], ...]] = (
    (("timer", "analog", "digital_in", "digital_out"), struct.Struct("<HBBB")),
    (("battery_x10",), struct.Struct("<H")),
    (("charge_state",), struct.Struct("<B")),
    (("rot_vel",), struct.Struct("<h")),
    (("fault_flags",), struct.Struct("<H")),
    (("lat_vel",), struct.Struct("<h")),
    (("temperature",), struct.Struct("<b")),
    (("state_of_charge",), struct.Struct("<b")),
    (("uc_time_us",), struct.Struct("<I")),
    (("flags3",), struct.Struct("<I")),
)


@dataclass(frozen=True, slots=True)
class StandardSip(WireSized):
    """A standard Server Information Packet (type 0x32 stopped / 0x33 moving), raw units.

    ``x``/``y`` are the robot's 15-bit position counters (wrap at 0x8000), ``theta`` its
    heading in 1/4096 turn; velocities are raw units (x VelConvFactor -> mm/s). ``sonars`` are
    (index, raw range) pairs of the readings in this cycle. Tail fields are None when the
    firmware did not send them; ``rot_vel`` is in 0.1 deg/s, ``battery_x10`` in 0.1 V.
    ``extra`` keeps trailing bytes no known field accounts for.
    """

    moving: bool
    x: int
    y: int
    theta: int
    left_vel: int
    right_vel: int
    battery_dv: int
    stall_bumpers: int
    control: int
    flags: int
    compass: int
    sonars: tuple[tuple[int, int], ...] = ()
    timer: int | None = None
    analog: int | None = None
    digital_in: int | None = None
    digital_out: int | None = None
    battery_x10: int | None = None
    charge_state: int | None = None
    rot_vel: int | None = None
    fault_flags: int | None = None
    lat_vel: int | None = None
    temperature: int | None = None
    state_of_charge: int | None = None
    uc_time_us: int | None = None
    flags3: int | None = None
    extra: bytes = b""

    @property
    def motors_enabled(self) -> bool:
        return bool(self.flags & 0x01)

    @property
    def battery_v(self) -> float:
        return (self.battery_x10 if self.battery_x10 is not None else self.battery_dv) / 10.0

    def encode(self) -> bytes:
        if not (0 <= self.x <= POSITION_MASK and 0 <= self.y <= POSITION_MASK):
            raise EncodeError("SIP positions are 15-bit counters (0..0x7FFF)")
        if len(self.sonars) > 0xFF:
            raise EncodeError("at most 255 sonar readings per SIP")
        kind = PacketType.SIP_MOVING if self.moving else PacketType.SIP_STOPPED
        try:
            head = [getattr(self, name) for name in _SIP_HEAD_FIELDS]
            parts = [_SIP_HEAD.pack(kind, self.x, self.y, *head, len(self.sonars))]
            parts += [_SONAR.pack(index, reading) for index, reading in self.sonars]
            parts += self._encode_tail()
        except struct.error as exc:
            raise EncodeError(f"SIP field out of range: {exc}") from exc
        return encode_packet(b"".join(parts) + self.extra)

    def _encode_tail(self) -> list[bytes]:
        out: list[bytes] = []
        missing: str | None = None
        for names, layout in SIP_TAIL:
            values = [getattr(self, name) for name in names]
            if any(v is None for v in values):
                missing = missing or names[0]
                if not all(v is None for v in values):
                    raise EncodeError(f"SIP fields {names} go together")
                continue
            if missing is not None:
                raise EncodeError(f"SIP field {names[0]} needs {missing} before it")
            out.append(layout.pack(*values))
        return out


def _decode_sip(data: bytes, wire_size: int) -> StandardSip | None:
    if len(data) < _SIP_HEAD.size:
        return None
    head = _SIP_HEAD.unpack_from(data)
    count = head[-1]
    pos = _SIP_HEAD.size
    if pos + count * _SONAR.size > len(data):
        return None
    sonars = tuple(_SONAR.unpack_from(data, pos + i * _SONAR.size) for i in range(count))
    pos += count * _SONAR.size
    tail: dict[str, Any] = {}
    for names, layout in SIP_TAIL:
        if pos + layout.size > len(data):
            break
        tail.update(zip(names, layout.unpack_from(data, pos), strict=True))
        pos += layout.size
    fields: dict[str, Any] = dict(zip(_SIP_HEAD_FIELDS, head[3:11], strict=True))
    return StandardSip(
        moving=head[0] == PacketType.SIP_MOVING,
        x=head[1] & POSITION_MASK,
        y=head[2] & POSITION_MASK,
        sonars=sonars,
        extra=data[pos:],
        **fields,
        **tail,
        wire_size=wire_size,
    )


#: CONFIG packet fields in wire order ("s" = NUL-terminated string), as ARIA reads them.
CONFIG_FIELDS: Final[tuple[tuple[str, str], ...]] = (
    ("robot_type", "s"),
    ("subtype", "s"),
    ("serial_number", "s"),
    ("four_mots", "B"),
    ("rot_vel_top", "H"),
    ("trans_vel_top", "H"),
    ("rot_accel_top", "H"),
    ("trans_accel_top", "H"),
    ("pwm_max", "H"),
    ("name", "s"),
    ("sip_cycle_ms", "B"),
    ("host_baud", "B"),
    ("aux1_baud", "B"),
    ("has_gripper", "H"),
    ("front_sonar", "H"),
    ("rear_sonar", "B"),
    ("low_battery", "H"),
    ("rev_count", "H"),
    ("watchdog_ms", "H"),
    ("normal_motor_packets", "B"),
    ("stall_val", "H"),
    ("stall_count", "H"),
    ("joy_vel", "H"),
    ("joy_rot_vel", "H"),
    ("rot_vel_max", "H"),
    ("trans_vel_max", "H"),
    ("rot_accel", "H"),
    ("rot_decel", "H"),
    ("rot_kp", "H"),
    ("rot_kv", "H"),
    ("rot_ki", "H"),
    ("trans_accel", "H"),
    ("trans_decel", "H"),
    ("trans_kp", "H"),
    ("trans_kv", "H"),
    ("trans_ki", "H"),
    ("front_bumps", "B"),
    ("rear_bumps", "B"),
    ("has_charger", "B"),
    ("sonar_cycle", "B"),
    ("reset_baud", "B"),
    ("gyro_type", "B"),
    ("drift_factor", "h"),
    ("aux2_baud", "B"),
    ("aux3_baud", "B"),
    ("ticks_mm", "H"),
    ("shutdown_voltage", "H"),
    ("firmware_version", "s"),
    ("gyro_cw", "H"),
    ("gyro_ccw", "H"),
    ("kinematics_delay", "B"),
    ("lat_vel_top", "H"),
    ("lat_accel_top", "H"),
    ("lat_vel_max", "H"),
    ("lat_accel", "H"),
    ("lat_decel", "H"),
    ("powerbot_charge_threshold", "H"),
    ("pdb_port", "B"),
    ("gyro_rate_limit", "H"),
    ("high_temperature_shutdown", "b"),
    ("power_bits", "H"),
    ("battery_type", "B"),
    ("state_of_charge_low", "H"),
    ("state_of_charge_shutdown", "H"),
    ("bootloader_version", "s"),
    ("config_flags", "I"),
    ("gyro_fw_version", "h"),
)
_CONFIG_STRUCTS: Final = {kind: struct.Struct("<" + kind) for kind in "BHhbI"}
CONFIG_FIELD_NAMES: Final = frozenset(name for name, _ in CONFIG_FIELDS)

ConfigValue = int | str


@dataclass(frozen=True, slots=True)
class ConfigPacket(WireSized):
    """A CONFIG packet (type 0x20): the fields present, in wire order.

    Older firmware sends fewer fields; a field is present only if all its bytes arrived.
    ``extra`` keeps bytes after the last complete field.
    """

    fields: tuple[tuple[str, ConfigValue], ...]
    extra: bytes = b""

    def get(self, name: str) -> ConfigValue | None:
        for key, value in self.fields:
            if key == name:
                return value
        return None

    def as_dict(self) -> dict[str, ConfigValue]:
        return dict(self.fields)

    @property
    def watchdog_ms(self) -> int | None:
        """How long the robot keeps driving without hearing from the host."""
        value = self.get("watchdog_ms")
        return value if isinstance(value, int) else None

    @property
    def sip_cycle_ms(self) -> int | None:
        value = self.get("sip_cycle_ms")
        return value if isinstance(value, int) else None

    def encode(self) -> bytes:
        return encode_config(self.as_dict(), self.extra)


def encode_config(values: dict[str, ConfigValue], extra: bytes = b"") -> bytes:
    """A CONFIG packet with the leading fields given in ``values`` (no gaps allowed)."""
    unknown = set(values) - CONFIG_FIELD_NAMES
    if unknown:
        raise EncodeError(f"unknown CONFIG fields {sorted(unknown)}")
    parts = [bytes((PacketType.CONFIG,))]
    written = 0
    for name, kind in CONFIG_FIELDS:
        if name not in values:
            break
        parts.append(_encode_config_value(name, kind, values[name]))
        written += 1
    if written != len(values):
        raise EncodeError("CONFIG fields must be a leading run of CONFIG_FIELDS, no gaps")
    return encode_packet(b"".join(parts) + extra)


def _encode_config_value(name: str, kind: str, value: ConfigValue) -> bytes:
    if kind == "s":
        if not isinstance(value, str) or "\x00" in value:
            raise EncodeError(f"CONFIG {name} must be a string without NUL")
        return value.encode("latin-1") + b"\x00"
    if not isinstance(value, int):
        raise EncodeError(f"CONFIG {name} must be an integer")
    try:
        return _CONFIG_STRUCTS[kind].pack(value)
    except struct.error as exc:
        raise EncodeError(f"CONFIG {name}={value} out of range") from exc


def _decode_config(data: bytes, wire_size: int) -> ConfigPacket:
    fields: list[tuple[str, ConfigValue]] = []
    pos = 1
    for name, kind in CONFIG_FIELDS:
        if kind == "s":
            nul = data.find(b"\x00", pos)
            if nul < 0:
                break
            fields.append((name, data[pos:nul].decode("latin-1")))
            pos = nul + 1
            continue
        layout = _CONFIG_STRUCTS[kind]
        if pos + layout.size > len(data):
            break
        fields.append((name, layout.unpack_from(data, pos)[0]))
        pos += layout.size
    return ConfigPacket(tuple(fields), data[pos:], wire_size=wire_size)


@dataclass(frozen=True, slots=True)
class RobotPacket(WireSized):
    """Any other robot packet (encoder, IO, serial-aux, ...), kept raw."""

    packet_type: int
    data: bytes = b""

    def encode(self) -> bytes:
        return encode_packet(bytes((self.packet_type,)) + self.data)


RobotMessage = SyncEcho | Sync2Info | StandardSip | ConfigPacket | RobotPacket
P2osMessage = RobotMessage | CommandPacket | BadFrame


def encode_sync_echo(step: int) -> bytes:
    return SyncEcho(step).encode()


def _decode_robot_packet(data: bytes, wire_size: int) -> RobotMessage | None:
    kind = data[0]
    if kind <= PacketType.SYNC2:
        if len(data) == 1:
            return SyncEcho(kind, wire_size=wire_size)
        if kind != PacketType.SYNC2:
            return None
        parts = data[1:].decode("latin-1").split("\x00")
        parts += [""] * (3 - len(parts))
        return Sync2Info(parts[0], parts[1], parts[2], wire_size=wire_size)
    if kind in (PacketType.SIP_STOPPED, PacketType.SIP_MOVING):
        return _decode_sip(data, wire_size)
    if kind == PacketType.CONFIG:
        return _decode_config(data, wire_size)
    return RobotPacket(kind, data[1:], wire_size=wire_size)


def _decode_command(data: bytes, wire_size: int) -> CommandPacket | None:
    if len(data) == 1:
        return CommandPacket(data[0], wire_size=wire_size)
    kind = data[1]
    if kind in (ArgType.INT, ArgType.NEG_INT) and len(data) == 4:
        (magnitude,) = _U16.unpack_from(data, 2)
        argument = -magnitude if kind == ArgType.NEG_INT else magnitude
        return CommandPacket(data[0], argument, wire_size=wire_size)
    if kind == ArgType.STRING and len(data) >= 3 and data[2] == len(data) - 3:
        return CommandPacket(data[0], data[3:], wire_size=wire_size)
    return None


# ---------------------------------------------------------------------------------------------
# Decoder
# ---------------------------------------------------------------------------------------------

Source = Literal["robot", "host"]


class Decoder(BufferedDecoder[P2osMessage]):
    """Bytes in, P2OS messages out.

    ``source="robot"`` (the daemon) decodes what a robot sends; ``source="host"`` (the
    simulated robot) decodes commands. COUNT is bounded to MIN_COUNT..MAX_COUNT before any
    wait; after a bad COUNT or checksum the search resumes at the byte after FA, so a packet
    starting inside the rejected bytes is still found. Discarded bytes are reported as one
    :class:`BadFrame` per run (``garbage``, ``length``, ``checksum``), emitted when the run
    ends so the output never depends on how the stream was chunked; a packet whose checksum
    holds but whose content contradicts itself is ``format``. :meth:`flush` at end of stream.
    """

    def __init__(self, source: Source = "robot") -> None:
        if source not in ("robot", "host"):
            raise ConfigError(f"P2OS decoder source is 'robot' or 'host', not {source!r}")
        super().__init__()
        self.source: Source = source

    def _process(self) -> list[P2osMessage]:
        buf = self._buf
        out: list[P2osMessage] = []
        pos = 0
        end = len(buf)
        while pos < end:
            found = buf.find(SYNC, pos)
            if found != pos:
                stop = end if found < 0 else found
                if found < 0 and buf[end - 1] == SYNC[0]:
                    stop = end - 1  # may be the first half of a header
                if stop == pos:
                    break
                self._run.absorb(buf, pos, stop, out)
                pos = stop
                continue
            if end - pos < HEADER_BYTES:
                break
            count = buf[pos + 2]
            if not MIN_COUNT <= count <= MAX_COUNT:
                pos = self._run.reject("length", buf, pos, out)
                continue
            stop = pos + HEADER_BYTES + count
            if stop > end:
                break
            body = bytes(buf[pos + HEADER_BYTES : stop - CHECKSUM_BYTES])
            if checksum(body) != buf[stop - 2] << 8 | buf[stop - 1]:
                pos = self._run.reject("checksum", buf, pos, out)
                continue
            self._run.end(out)
            message = self._decode(body, stop - pos)
            if message is None:
                out.append(self.stats.count_bad(BadFrame.of("format", buf[pos:stop])))
            else:
                self.stats.frames += 1
                out.append(message)
            pos = stop
        del buf[:pos]
        return out

    def _decode(self, body: bytes, wire_size: int) -> RobotMessage | CommandPacket | None:
        if self.source == "host":
            return _decode_command(body, wire_size)
        return _decode_robot_packet(body, wire_size)
