"""P2OS codec: protocols.md vectors, round trips, resynchronisation, odometry across the wrap."""

from __future__ import annotations

import dataclasses
import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from baromap.errors import ConfigError, EncodeError
from baromap.odometry.integrator import BREAK_S, OdometryIntegrator, position_delta
from baromap.protocols import p2os as P
from baromap.protocols.framing import BAD_FRAME_SAMPLE_BYTES, MAX_DISCARD_RUN, BadFrame
from baromap.protocols.robot_models import (
    MODELS,
    P2AT,
    P3AT,
    P3AT_SH,
    P3DX,
    ModelMismatchError,
    robot_model,
    select_model,
)

VECTORS = [
    ("SYNC0", lambda: P.sync(0), "FA FB 03 00 00 00", P.CommandPacket(0)),
    ("PULSE", P.pulse, "FA FB 03 00 00 00", P.CommandPacket(0)),
    ("SYNC1", lambda: P.sync(1), "FA FB 03 01 00 01", P.CommandPacket(1)),
    ("OPEN", P.open_controller, "FA FB 03 01 00 01", P.CommandPacket(1)),
    ("SYNC2", lambda: P.sync(2), "FA FB 03 02 00 02", P.CommandPacket(2)),
    ("CLOSE", P.close_controller, "FA FB 03 02 00 02", P.CommandPacket(2)),
    ("ENABLE 1", P.enable_motors, "FA FB 06 04 3B 01 00 05 3B", P.CommandPacket(4, 1)),
    ("VEL +300", lambda: P.vel(300), "FA FB 06 0B 3B 2C 01 37 3C", P.CommandPacket(11, 300)),
    ("VEL -300", lambda: P.vel(-300), "FA FB 06 0B 1B 2C 01 37 1C", P.CommandPacket(11, -300)),
    ("RVEL +10", lambda: P.rvel(10), "FA FB 06 15 3B 0A 00 1F 3B", P.CommandPacket(21, 10)),
]


def decode(data: bytes, source: P.Source = "robot", chunk: int | None = None) -> list:
    decoder = P.Decoder(source)
    if chunk is None:
        return decoder.feed(data) + decoder.flush()
    out: list = []
    for i in range(0, len(data), chunk):
        out += decoder.feed(data[i : i + chunk])
    return out + decoder.flush()


@pytest.mark.parametrize(
    ("name", "build", "expected", "command"), VECTORS, ids=[v[0] for v in VECTORS]
)
def test_encoders_reproduce_protocol_vectors(name, build, expected: str, command) -> None:
    assert build() == bytes.fromhex(expected)
    assert command.encode() == bytes.fromhex(expected)


@pytest.mark.parametrize(
    ("name", "build", "expected", "command"), VECTORS, ids=[v[0] for v in VECTORS]
)
def test_host_side_decoder_reads_vectors_back(name, build, expected: str, command) -> None:
    assert decode(bytes.fromhex(expected), "host") == [command]


def test_checksum_worked_example() -> None:
    assert P.checksum(bytes.fromhex("0B 3B 2C 01")) == 0x373C
    assert P.checksum(b"\x01") == 0x0001
    assert P.checksum(b"") == 0
    assert P.checksum(b"\xff\xff\xff\xff\x07") == (0xFFFE ^ 0x07)


def _word_sum(data: bytes) -> int:
    """The checksum as protocols.md words it: big-endian words summed, an odd byte XORed."""
    total = 0
    for i in range(0, len(data) - 1, 2):
        total = (total + (data[i] << 8 | data[i + 1])) & 0xFFFF
    return total ^ data[-1] if len(data) % 2 else total


def test_checksum_of_every_length_and_of_longer_data_than_a_packet_holds() -> None:
    rng = random.Random(3)
    for n in [*range(P.MAX_COUNT + 4), 300, 301, 1000]:
        data = rng.randbytes(n)
        assert P.checksum(data) == _word_sum(data), n


def test_encoders_take_the_extremes_the_wire_can_carry() -> None:
    longest = P.encode_packet(b"\x90" * P.MAX_DATA)
    assert len(longest) == 3 + P.MAX_COUNT
    assert decode(longest) == [P.RobotPacket(0x90, b"\x90" * (P.MAX_DATA - 1))]
    assert decode(P.encode_command(0xFF), "host") == [P.CommandPacket(0xFF)]
    assert P.encode_command(11, 0)[3:7] == b"\x0b\x3b\x00\x00"
    assert P.encode_command(11, -1)[3:7] == b"\x0b\x1b\x01\x00"
    extremes = [P.encode_command(11, v) for v in (P.INT_ARG_MAX, P.INT_ARG_MIN)]
    assert decode(b"".join(extremes), "host") == [
        P.CommandPacket(11, 0x7FFF),
        P.CommandPacket(11, -0x8000),
    ]
    text = b"t" * (P.MAX_DATA - 3)
    assert decode(P.encode_command(28, text), "host") == [P.CommandPacket(28, text)]
    with pytest.raises(EncodeError, match="196 bytes is too long"):
        P.encode_command(28, text + b"t")
    with pytest.raises(EncodeError, match="32768 is not a 2-byte short"):
        P.encode_command(11, 0x8000)


def test_a_sip_with_fewer_sonar_readings_than_its_count_is_a_format_error() -> None:
    body = bytearray(SIP.encode()[3:-2])  # two readings
    body[19] = 3
    (bad,) = decode(P.encode_packet(bytes(body)))
    assert isinstance(bad, BadFrame) and bad.reason == "format"


def test_a_config_packet_keeps_its_trailing_bytes() -> None:
    values = {name: (name if kind == "s" else 1) for name, kind in P.CONFIG_FIELDS[:4]}
    raw = P.encode_config(values, b"\xfe")
    (config,) = decode(raw)
    assert config.extra == b"\xfe" and config.encode() == raw


@pytest.mark.parametrize(
    ("call", "args", "message"),
    [
        (P.sync, (3,), "there is no SYNC3"),
        (P.encode_sync_echo, (3,), "there is no SYNC3 echo"),
        (P.host_baud, (4800,), "P2OS speaks [9600, 19200, 38400, 57600, 115200] baud, not 4800"),
        (P.encode_command, (256,), "command 256 does not fit in a byte"),
        (P.Sync2Info("a\x00", "b", "c").encode, (), "SYNC2 strings cannot contain NUL"),
        (P.encode_config, ({"bogus": 1},), "unknown CONFIG fields ['bogus']"),
        (
            P.encode_config,
            ({"robot_type": "a\x00"},),
            "CONFIG robot_type must be a string without NUL",
        ),
        (
            P.encode_config,
            ({"robot_type": "a", "subtype": "b", "serial_number": "c", "four_mots": "x"},),
            "CONFIG four_mots must be an integer",
        ),
        (
            P.encode_config,
            ({"robot_type": "a", "subtype": "b", "serial_number": "c", "four_mots": 300},),
            "CONFIG four_mots=300 out of range",
        ),
        (
            P.encode_config,
            ({"robot_type": "a", "subtype": "b", "serial_number": "c", "rot_vel_top": 1},),
            "CONFIG fields must be a leading run of CONFIG_FIELDS, no gaps",
        ),
    ],
)
def test_refusals_name_the_value_and_what_the_robot_takes(call, args, message) -> None:
    with pytest.raises(EncodeError) as refused:
        call(*args)
    assert str(refused.value) == message


def test_sync_echoes_are_the_step_byte_alone() -> None:
    echoes = [P.encode_sync_echo(step) for step in (0, 1)]
    assert echoes == [P.encode_packet(b"\x00"), P.encode_packet(b"\x01")]
    assert decode(b"".join(echoes)) == [P.SyncEcho(0), P.SyncEcho(1)]


def test_other_commands() -> None:
    assert decode(
        P.stop() + P.reset_odometry() + P.config_request() + P.host_baud(38400), "host"
    ) == [
        P.CommandPacket(P.Command.STOP),
        P.CommandPacket(P.Command.SETO),
        P.CommandPacket(P.Command.CONFIG, 1),
        P.CommandPacket(P.Command.HOSTBAUD, 2),
    ]
    text = P.encode_command(P.Command.SONAR, b"abc")
    assert text[3:8] == b"\x1c\x2b\x03ab"
    assert decode(text, "host") == [P.CommandPacket(28, b"abc")]


@pytest.mark.parametrize(
    ("call", "args"),
    [
        (P.sync, (3,)),
        (P.host_baud, (4800,)),
        (P.encode_sync_echo, (3,)),
        (P.vel, (40000,)),
        (P.encode_command, (256,)),
        (P.encode_command, (1, b"x" * 200)),
        (P.encode_packet, (b"",)),
        (P.encode_packet, (b"x" * (P.MAX_DATA + 1),)),
        (P.encode_config, ({"name": "x"},)),  # leading fields missing
        (P.encode_config, ({"robot_type": 5},)),
        (P.encode_config, ({"bogus": 1},)),
    ],
)
def test_encoders_refuse_what_the_wire_cannot_carry(call, args) -> None:
    with pytest.raises(EncodeError):
        call(*args)


def test_decoder_source_is_checked() -> None:
    with pytest.raises(ConfigError):
        P.Decoder("sideways")  # type: ignore[arg-type]


# -- round trips -------------------------------------------------------------------------------

i16 = st.integers(-0x8000, 0x7FFF)
u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)


@st.composite
def sips(draw: st.DrawFn) -> P.StandardSip:
    tail: dict[str, int] = {}
    kinds = {
        "B": u8,
        "H": u16,
        "h": i16,
        "b": st.integers(-128, 127),
        "I": st.integers(0, 2**32 - 1),
    }
    groups = draw(st.integers(0, len(P.SIP_TAIL)))
    for names, layout in P.SIP_TAIL[:groups]:
        for name, kind in zip(names, layout.format.lstrip("<"), strict=True):
            tail[name] = draw(kinds[kind])
    sonar_count = draw(st.integers(0, 16))
    sonars = tuple(draw(st.tuples(u8, u16)) for _ in range(sonar_count))
    extra = draw(st.binary(max_size=6)) if groups == len(P.SIP_TAIL) else b""
    return P.StandardSip(
        moving=draw(st.booleans()),
        x=draw(st.integers(0, 0x7FFF)),
        y=draw(st.integers(0, 0x7FFF)),
        theta=draw(i16),
        left_vel=draw(i16),
        right_vel=draw(i16),
        battery_dv=draw(u8),
        stall_bumpers=draw(u16),
        control=draw(i16),
        flags=draw(u16),
        compass=draw(u8),
        sonars=sonars,
        extra=extra,
        **tail,
    )


@st.composite
def configs(draw: st.DrawFn) -> P.ConfigPacket:
    n = draw(st.integers(0, len(P.CONFIG_FIELDS)))
    text = st.text(st.characters(min_codepoint=1, max_codepoint=255), max_size=12)
    ints = {
        "B": u8,
        "H": u16,
        "h": i16,
        "b": st.integers(-128, 127),
        "I": st.integers(0, 2**32 - 1),
    }
    fields = tuple(
        (name, draw(text if kind == "s" else ints[kind])) for name, kind in P.CONFIG_FIELDS[:n]
    )
    extra = draw(st.binary(max_size=4)) if n == len(P.CONFIG_FIELDS) else b""
    return P.ConfigPacket(fields, extra)


names = st.text(st.characters(min_codepoint=1, max_codepoint=255), max_size=16)
robot_messages = st.one_of(
    sips(),
    configs(),
    st.builds(P.SyncEcho, st.integers(0, 2)),
    st.builds(P.Sync2Info, names, names, names),
    st.builds(
        P.RobotPacket,
        st.integers(0x03, 0xFF).filter(lambda t: t not in (0x20, 0x32, 0x33)),
        st.binary(max_size=40),
    ),
)
commands = st.builds(
    P.CommandPacket,
    u8,
    st.none() | st.integers(P.INT_ARG_MIN, P.INT_ARG_MAX).filter(bool) | st.binary(max_size=40),
)


@settings(max_examples=150, deadline=None)
@given(robot_messages)
def test_every_robot_packet_type_round_trips(message) -> None:
    wire = message.encode()
    [decoded] = decode(wire)
    assert decoded == message
    assert decoded.wire_size == len(wire)


@settings(max_examples=100, deadline=None)
@given(sips())
def test_a_sips_wire_size_is_its_encoded_length(sip: P.StandardSip) -> None:
    [decoded] = decode(sip.encode())
    assert decoded.wire_size == len(sip.encode())


@settings(max_examples=80, deadline=None)
@given(commands)
def test_every_command_round_trips(command: P.CommandPacket) -> None:
    assert decode(command.encode(), "host") == [command]


@settings(max_examples=60, deadline=None)
@given(st.lists(robot_messages, min_size=1, max_size=6), st.randoms(use_true_random=False))
def test_any_chunking_gives_identical_output(batch, rnd: random.Random) -> None:
    stream = b"".join(m.encode() for m in batch)
    assert decode(stream) == batch
    assert decode(stream, chunk=1) == batch
    cuts = sorted(rnd.sample(range(1, len(stream)), min(len(stream) - 1, 5)))
    decoder = P.Decoder()
    out: list = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        out += decoder.feed(stream[a:b])
    assert out + decoder.flush() == batch


@settings(max_examples=60, deadline=None)
@given(st.binary(min_size=1, max_size=80), st.lists(robot_messages, min_size=1, max_size=3))
def test_garbage_is_counted_and_chunking_still_does_not_matter(garbage: bytes, batch) -> None:
    frames = [m.encode() for m in batch]
    stream = garbage + b"".join(frames) + garbage
    whole = decode(stream)
    assert whole == decode(stream, chunk=1)
    decoder = P.Decoder()
    out = decoder.feed(stream) + decoder.flush()
    good_bytes = sum(len(m.encode()) for m in out if not isinstance(m, BadFrame))
    assert good_bytes + decoder.stats.bytes_discarded == len(stream) == decoder.stats.bytes_in


# -- resynchronisation -----------------------------------------------------------------------

SIP = P.StandardSip(False, 10, 20, 30, 0, 0, 125, 0, 0, 1, 0, ((0, 1500), (7, 300)))
ECHO = P.SyncEcho(1)


@pytest.mark.parametrize(
    "garbage",
    [
        b"\x00",
        b"\xfa",
        b"\xfa\xfb",
        b"\xfa\xfb\x05",
        b"\xfa\xfb\x02",
        b"\xfa\xfb\xff",
        b"\xfb\xfa" * 5,
    ],
    ids=["nul", "fa", "sync", "sync-count", "count-too-small", "count-too-big", "reversed"],
)
@pytest.mark.parametrize("where", ["before", "between", "after"])
def test_garbage_is_counted_and_the_next_packet_decodes(garbage: bytes, where: str) -> None:
    a, b = ECHO.encode(), SIP.encode()
    stream = {"before": garbage + a + b, "between": a + garbage + b, "after": a + b + garbage}[
        where
    ]
    for chunk in (None, 1, 4):
        out = decode(stream, chunk=chunk)
        assert [m for m in out if not isinstance(m, BadFrame)] == [ECHO, SIP]
        assert sum(m.size for m in out if isinstance(m, BadFrame)) == len(garbage)


def test_one_feed_returns_every_complete_packet_and_accounts_for_every_byte() -> None:
    """Long garbage, a bad COUNT, a bad checksum and a format error between packets: one feed
    returns each packet whole and each run of discarded bytes with its reason, the items'
    wire sizes add up to every byte but a trailing FA (a header may start there)."""
    bad_sum = bytearray(SIP.encode())
    bad_sum[-1] ^= 1
    short_sip = P.encode_packet(b"\x32" + b"\x00" * 10)
    stream = b"".join(
        (
            b"\x55" * (2 * MAX_DISCARD_RUN + 3),
            ECHO.encode(),
            b"\xfa\xfb\xff",
            SIP.encode(),
            bytes(bad_sum),
            short_sip,
            SIP.encode(),
            b"\xfa",
        )
    )
    decoder = P.Decoder()
    out = decoder.feed(stream)
    assert out[3] == ECHO and out[5] == SIP and out[8] == SIP
    bad = [(m.reason, m.size, m.sample, m.wire_size) for m in out if isinstance(m, BadFrame)]
    assert bad == [
        ("garbage", MAX_DISCARD_RUN, b"\x55" * BAD_FRAME_SAMPLE_BYTES, MAX_DISCARD_RUN),
        ("garbage", MAX_DISCARD_RUN, b"\x55" * BAD_FRAME_SAMPLE_BYTES, MAX_DISCARD_RUN),
        ("garbage", 3, b"\x55" * 3, 3),
        ("length", 3, b"\xfa\xfb\xff", 3),
        ("checksum", len(bad_sum), bytes(bad_sum[:BAD_FRAME_SAMPLE_BYTES]), len(bad_sum)),
        ("format", len(short_sip), short_sip[:BAD_FRAME_SAMPLE_BYTES], len(short_sip)),
    ]
    assert [m.wire_size for m in out if not isinstance(m, BadFrame)] == [6, 31, 31]
    assert sum(m.wire_size for m in out) == len(stream) - 1
    assert decoder.stats.as_dict() == {
        "frames": 3,
        "bytes_in": len(stream),
        "bytes_discarded": 2 * MAX_DISCARD_RUN + 3 + 3 + len(bad_sum) + len(short_sip),
        "bad_checksum": 1,
        "bad_format": 1,
        "bad_garbage": 3,
        "bad_length": 1,
    }


def test_two_unfinished_headers_at_the_end_are_one_truncated_run() -> None:
    decoder = P.Decoder()
    cut = b"\xfa\xfb\x10" * 2
    assert decoder.feed(cut) == []
    assert decoder.flush() == [BadFrame("truncated", len(cut), cut)]


def test_bad_checksum_resyncs_at_the_byte_after_fa() -> None:
    inner = ECHO.encode()
    count = 2 + len(inner) + 1  # a header whose body swallows a real packet
    bogus = b"\xfa\xfb" + bytes((count,))
    out = decode(bogus + inner + b"\x99\x98\x97" + SIP.encode())
    assert [type(m) for m in out] == [BadFrame, P.SyncEcho, BadFrame, P.StandardSip]
    assert out[0].reason == "checksum" and out[0].size == len(bogus)


def test_truncated_packets_and_self_contradicting_sips() -> None:
    raw = SIP.encode()
    for cut in range(1, len(raw)):
        decoder = P.Decoder()
        assert decoder.feed(raw[:cut]) == []
        (bad,) = decoder.flush()
        assert bad.reason == "truncated" and bad.size == cut
    lying = bytearray(SIP.encode()[3:-2])
    lying[19] = 40  # sonar count larger than the packet
    short_sip = bytes((0x32,)) + b"\x00" * 10
    sync0_with_junk = b"\x00\x01"
    stream = b"".join(P.encode_packet(bytes(d)) for d in (lying, short_sip, sync0_with_junk))
    assert [getattr(m, "reason", None) for m in decode(stream)] == ["format"] * 3
    assert [
        getattr(m, "reason", None) for m in decode(P.encode_packet(b"\x04\x3b\x01"), "host")
    ] == ["format"]


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"x": 0x8000}, "SIP positions are 15-bit counters (0..0x7FFF)"),
        ({"y": 0x8000}, "SIP positions are 15-bit counters (0..0x7FFF)"),
        ({"y": -1}, "SIP positions are 15-bit counters (0..0x7FFF)"),
        ({"sonars": ((0, 1),) * 256}, "at most 255 sonar readings per SIP"),
        ({"sonars": ((0, 1),) * 255}, "P2OS packets carry 1..198 data bytes, not 785"),
        ({"battery_dv": 256}, "SIP field out of range: ubyte format requires 0 <= number <= 255"),
        ({"timer": 1}, "SIP fields ('timer', 'analog', 'digital_in', 'digital_out') go together"),
        ({"battery_x10": 120}, "SIP field battery_x10 needs timer before it"),
    ],
)
def test_sip_refusals_name_what_is_wrong(changes, message) -> None:
    with pytest.raises(EncodeError) as refused:
        dataclasses.replace(SIP, **changes).encode()
    assert str(refused.value) == message


def test_sip_positions_take_the_whole_15_bits() -> None:
    corner = dataclasses.replace(SIP, x=P.POSITION_MASK, y=P.POSITION_MASK)
    assert decode(corner.encode()) == [corner]


def test_host_commands_with_a_malformed_argument_are_format_errors() -> None:
    """An argument type byte the length contradicts is no command (a string's length byte
    must match, an integer takes two bytes, other type bytes take none)."""
    malformed = [
        bytes((8, P.ArgType.STRING)),  # string without its length byte
        bytes((8, P.ArgType.INT, 0)),  # integer one byte short
        bytes((8, 0x99, 0)),  # no such argument type
        bytes((8, P.ArgType.STRING, 5, 0x41)),  # length says 5, one byte follows
    ]
    stream = b"".join(P.encode_packet(data) for data in malformed)
    assert [getattr(m, "reason", None) for m in decode(stream, "host")] == ["format"] * 4


def test_decoded_commands_carry_their_wire_size() -> None:
    packets = [P.encode_command(4), P.encode_command(11, -300), P.encode_command(28, b"abc")]
    decoded = decode(b"".join(packets), "host")
    assert [m.wire_size for m in decoded] == [len(p) for p in packets]


def test_sip_fields_and_partial_tail() -> None:
    sip = P.StandardSip(
        True,
        0x7FFF,
        0,
        -5,
        100,
        -100,
        131,
        0x0102,
        7,
        0x0001,
        90,
        timer=1,
        analog=2,
        digital_in=3,
        digital_out=4,
        battery_x10=129,
        charge_state=1,
        rot_vel=-155,
    )
    (decoded,) = decode(sip.encode())
    assert decoded == sip and decoded.motors_enabled and decoded.battery_v == pytest.approx(12.9)
    # a firmware that stops half way through a field: the half field is kept as extra bytes
    body = sip.encode()[3:-2] + b"\x01"
    (partial,) = decode(P.encode_packet(body))
    assert partial.fault_flags is None and partial.extra == b"\x01"
    # the top bit of a position word is not part of the counter
    body = bytearray(sip.encode()[3:-2])
    body[4] |= 0x80  # y high byte
    (masked,) = decode(P.encode_packet(bytes(body)))
    assert masked.y == 0
    with pytest.raises(EncodeError):
        P.StandardSip(False, 0x8000, 0, 0, 0, 0, 0, 0, 0, 0, 0).encode()
    with pytest.raises(EncodeError):
        P.StandardSip(False, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, rot_vel=5).encode()


def test_config_packet_properties() -> None:
    values = {name: (name if kind == "s" else 7) for name, kind in P.CONFIG_FIELDS[:20]}
    values["watchdog_ms"] = 2000
    values["sip_cycle_ms"] = 100
    (config,) = decode(P.encode_config(values))
    assert config.as_dict() == values
    assert config.watchdog_ms == 2000 and config.sip_cycle_ms == 100
    assert config.get("name") == "name" and config.get("firmware_version") is None


def test_sync2_info_strings() -> None:
    (info,) = decode(P.Sync2Info("Pioneer", "Pioneer", "p3at").encode())
    assert info == P.Sync2Info("Pioneer", "Pioneer", "p3at")
    raw = P.encode_packet(b"\x02Pioneer\x00Pioneer")  # a firmware that stops early
    assert decode(raw) == [P.Sync2Info("Pioneer", "Pioneer", "")]
    with pytest.raises(EncodeError):
        P.Sync2Info("a\x00b", "", "").encode()


# -- models and odometry -----------------------------------------------------------------------


#: (subclass, DistConvFactor, DiffConvFactor, RangeConvFactor, MaxVelocity, MaxRVelocity) as
#: ARIA's params/<subclass>.p and p2os_driver's robot_params.cpp list them.
ARIA_PARAMS = [
    ("p3at-sh", 1.0, 0.0034, 1.0, 1200, 300),
    ("p3at", 0.465, 0.0034, 1.0, 1200, 300),
    ("p3atiw-sh", 1.0, 0.0034, 1.0, 1200, 300),
    ("p2at", 1.32, 0.0034, 0.268, 1200, 300),
    ("p2at8", 1.32, 0.0034, 1.0, 1200, 300),
    ("p3dx-sh", 1.0, 0.0056, 1.0, 2200, 500),
    ("p3dx", 0.485, 0.0056, 1.0, 2200, 500),
    ("p2dx", 0.84, 0.0056, 0.268, 2200, 500),
]


@pytest.mark.parametrize("row", ARIA_PARAMS, ids=[r[0] for r in ARIA_PARAMS])
def test_models_carry_arias_factors(row: tuple[str, float, float, float, int, int]) -> None:
    subclass, dist, diff, rng, vmax, rvmax = row
    model = robot_model(subclass)
    assert model.name == subclass and model.robot_class == "Pioneer"
    assert (model.dist_conv_factor, model.diff_conv_factor, model.range_conv_factor) == (
        dist,
        diff,
        rng,
    )
    assert (model.max_velocity_mmps, model.max_rot_velocity_degps) == (vmax, rvmax)
    assert model.angle_conv_factor == pytest.approx(0.001534, abs=1e-6)
    assert model.vel_conv_factor == 1.0 and model.sonar_count == 16


def test_model_names_ignore_case_and_separators() -> None:
    for alias in ("p3at", "P3-AT", "p3_at", " P3AT "):
        assert robot_model(alias) is P3AT
    assert robot_model("P3-AT-SH") is P3AT_SH and robot_model("p3dx") is P3DX
    assert set(MODELS) == {row[0] for row in ARIA_PARAMS}
    with pytest.raises(ConfigError, match="p3at-sh"):  # the message lists what is known
        robot_model("p3-sh")


def test_the_reported_subclass_chooses_the_model() -> None:
    assert select_model("p3at-sh") is P3AT_SH
    assert select_model("p3at") is P3AT
    assert select_model("P3AT-SH", "p3at-sh") is P3AT_SH
    with pytest.raises(ConfigError) as unknown:
        select_model("p3at-xx")
    assert str(unknown.value) == (
        "the robot reports subclass 'p3at-xx', which has no known parameter set (known: p2at, "
        "p2at8, p2dx, p3at, p3at-sh, p3atiw-sh, p3dx, p3dx-sh); configure the robot model to "
        "use one"
    )
    # A robot whose subclass has no parameter set runs only with a model pinned on purpose.
    assert select_model("p3at-xx", "p3at-sh", allow_mismatch=True) is P3AT_SH


def test_a_configured_model_the_robot_contradicts_is_refused_naming_both() -> None:
    with pytest.raises(ModelMismatchError) as refused:
        select_model("p3at-sh", "p3at")
    assert str(refused.value) == (
        "configured robot model 'p3at' does not match the subclass 'p3at-sh' the robot reports; "
        "fix the configuration, or allow the mismatch if the robot's firmware reports the wrong "
        "subclass"
    )
    assert isinstance(refused.value, ConfigError)
    assert select_model("p3at-sh", "p3at", allow_mismatch=True) is P3AT
    with pytest.raises(ConfigError) as unknown:
        select_model("p3at-sh", "p9xx", allow_mismatch=True)
    assert str(unknown.value) == (
        "unknown robot model 'p9xx'; known: p2at, p2at8, p2dx, p3at, p3at-sh, p3atiw-sh, p3dx, "
        "p3dx-sh"
    )


def test_a_p3at_sh_read_as_p3at_shrinks_distances_to_465_per_mille() -> None:
    """Why the subclass matters: the same counters, two parameter sets."""
    ticks = 10_000  # 10 m on an ARCOS P3-AT
    right = OdometryIntegrator(P3AT_SH, origin_at_start=True)
    wrong = OdometryIntegrator(P3AT, origin_at_start=True)
    for integrator in (right, wrong):
        integrator.update(_sip(0, 0, 0), 0)
    assert right.update(_sip(ticks, 0, 0), 1).x_m == pytest.approx(10.0)
    assert wrong.update(_sip(ticks, 0, 0), 1).x_m == pytest.approx(4.65)


def _sip(
    x: int, y: int, theta: int, lvel: int = 0, rvel: int = 0, rot_vel: int | None = None
) -> P.StandardSip:
    tail = {}
    if rot_vel is not None:
        tail = dict(
            timer=0,
            analog=0,
            digital_in=0,
            digital_out=0,
            battery_x10=0,
            charge_state=0,
            rot_vel=rot_vel,
        )
    return P.StandardSip(False, x & 0x7FFF, y & 0x7FFF, theta, lvel, rvel, 0, 0, 0, 0, 0, **tail)


@pytest.mark.parametrize(
    ("previous", "current", "delta"),
    [
        (0x7FF0, 0x0010, 0x20),
        (0x0010, 0x7FF0, -0x20),
        (100, 4196, 4096),
        (4196, 100, -4096),
        (5, 5, 0),
    ],
)
def test_position_delta_unwraps_like_aria(previous: int, current: int, delta: int) -> None:
    assert position_delta(previous, current) == delta


@st.composite
def drives(draw: st.DrawFn) -> list[tuple[int, int, int]]:
    """Steps of up to 0x1000 ticks (ARIA's limit), drifting one way so the counters wrap."""
    n = draw(st.integers(50, 300))
    sx, sy = draw(st.sampled_from([-1, 1])), draw(st.sampled_from([-1, 1]))
    noise = st.integers(-0x400, 0x400)
    return [
        (sx * 0xC00 + draw(noise), sy * 0xC00 + draw(noise), draw(st.integers(-2047, 2047)))
        for _ in range(n)
    ]


@pytest.mark.parametrize("model", [P3AT_SH, P3AT, P2AT, P3DX], ids=lambda m: m.name)
@settings(max_examples=20, deadline=None)
@given(
    steps=drives(),
    start=st.tuples(st.integers(0, 0x7FFF), st.integers(0, 0x7FFF), st.integers(0, 4095)),
)
def test_long_drives_cross_the_wrap_without_losing_a_tick(model, steps, start) -> None:
    integrator = OdometryIntegrator(model, origin_at_start=True)
    x, y, th = start
    integrator.update(_sip(x, y, th), 0)
    tx = ty = tth = 0
    wraps = 0
    for i, (dx, dy, dth) in enumerate(steps, start=1):
        wraps += (x + dx) // 0x8000 != x // 0x8000
        x, y, th, tx, ty, tth = x + dx, y + dy, (th + dth) % 4096, tx + dx, ty + dy, tth + dth
        odom = integrator.update(_sip(x, y, th), i)
    assert wraps >= 3
    assert odom.x_m == pytest.approx(tx * model.dist_conv_factor / 1000, abs=1e-9)
    assert odom.y_m == pytest.approx(ty * model.dist_conv_factor / 1000, abs=1e-9)
    expected_heading = (start[2] + tth) * model.angle_conv_factor
    assert math.isclose(
        math.remainder(odom.theta_rad - expected_heading, math.tau), 0, abs_tol=1e-9
    )
    assert odom.raw_x == x & 0x7FFF and odom.raw_theta == th


def test_ten_kilometre_drive_in_both_directions() -> None:
    """A P3-AT at full speed, 100 ms SIPs, 5 km out and 5 km back: 330 wraps each way."""
    model = P3AT
    integrator = OdometryIntegrator(model)
    step = round(model.max_velocity_mmps * 0.1 / model.dist_conv_factor)  # ticks per SIP
    ticks, n = 0, 42_000
    first = integrator.update(_sip(0, 0, 0), 0)
    assert (first.x_m, first.y_m, first.theta_rad) == (0, 0, 0)
    for i in range(n):
        ticks += step
        odom = integrator.update(_sip(ticks, 0, 0, 1200, 1200), i)
    assert odom.x_m == pytest.approx(n * step * model.dist_conv_factor / 1000)
    assert odom.x_m > 5000 and ticks // 0x8000 >= 330
    assert odom.v_mps == pytest.approx(1.2)
    for i in range(n):
        ticks -= step
        odom = integrator.update(_sip(ticks, 0, 2048, -1200, -1200), n + i)
    assert odom.x_m == pytest.approx(0.0, abs=1e-9)
    assert abs(odom.theta_rad) == pytest.approx(math.pi)


def test_first_sip_uses_the_counters_as_aria_does() -> None:
    odom = OdometryIntegrator(P2AT).update(_sip(1000, 2000, 1024), 5)
    assert odom.x_m == pytest.approx(1.32) and odom.y_m == pytest.approx(2.64)
    assert odom.theta_rad == pytest.approx(math.pi / 2, abs=1e-12) and odom.t_ns == 5
    zeroed = OdometryIntegrator(P2AT, origin_at_start=True).update(_sip(1000, 2000, 1024), 5)
    assert (zeroed.x_m, zeroed.y_m) == (0, 0)


def test_rotation_rate_from_firmware_or_wheels() -> None:
    integrator = OdometryIntegrator(P3AT)
    wheels = integrator.update(_sip(0, 0, 0, lvel=-100, rvel=100), 0)
    assert wheels.omega_radps == pytest.approx(100 * 0.0034)
    firmware = integrator.update(_sip(0, 0, 0, lvel=-100, rvel=100, rot_vel=-450), 1)
    assert firmware.omega_radps == pytest.approx(math.radians(-45.0))


_SIP_NS = 100_000_000


def _drive(integrator: OdometryIntegrator, sips: list[tuple[int, int, int]], t0_ns: int) -> list:
    """SIPs every 100 ms from ``t0_ns``: the odometry of each."""
    return [integrator.update(_sip(*s), t0_ns + i * _SIP_NS) for i, s in enumerate(sips)]


def test_a_reconnect_goes_on_counting_when_the_robot_kept_its_counters() -> None:
    """Three seconds without SIPs (the USB link replugged) while the robot drove 2 m on: its
    counters went on, so does the track, tick for tick."""
    integrator = OdometryIntegrator(P3AT_SH, origin_at_start=True)
    _drive(integrator, [(100 * i, 0, 0) for i in range(10)], 0)
    integrator.resume(P3AT_SH)
    after = _drive(integrator, [(900 + 2000, 0, 0), (900 + 2100, 0, 0)], 4_000_000_000)
    assert [o.x_m for o in after] == pytest.approx([2.9, 3.0])
    assert integrator.tracks_joined == 0


@pytest.mark.parametrize("reconnected", [True, False], ids=["resumed", "recording-gap"])
def test_counters_that_start_again_are_joined_at_the_last_pose(reconnected: bool) -> None:
    """The robot power-cycled: 1.7 s later its counters read zero again, in a frame of
    its own. ARIA would place it at 0, 0 (a jump of metres no robot drove); the track is
    joined at the last pose instead, and the new frame's motion turned into the run's."""
    break_s = None if reconnected else BREAK_S  # a recording re-integrated: the gap tells
    integrator = OdometryIntegrator(P3AT_SH, origin_at_start=True, break_s=break_s)
    before = _drive(integrator, [(500 * i, 0, 0) for i in range(13)] + [(6000, 0, 1024)], 0)
    assert (before[-1].x_m, before[-1].theta_rad) == pytest.approx((6.0, math.pi / 2))
    if reconnected:
        integrator.resume()
    # forward 1 m in the robot's new frame (heading 0 there), then a quarter turn left
    after = _drive(integrator, [(0, 0, 0), (1000, 0, 0), (1000, 0, 1024)], 3_000_000_000)
    assert integrator.tracks_joined == 1
    assert (after[0].x_m, after[0].y_m, after[0].theta_rad) == pytest.approx((6, 0, math.pi / 2))
    assert (after[1].x_m, after[1].y_m) == pytest.approx((6.0, 1.0))
    assert after[2].theta_rad == pytest.approx(math.pi)
    assert after[2].raw_x == 1000


def test_counters_back_at_the_origin_after_a_reconnect_are_a_new_track_however_near() -> None:
    """Twelve seconds without SIPs, 3 m from the origin: a P3-AT could have driven back, but
    counters that read (0, 0, 0) are a robot that counts from zero again; a robot that was
    at the origin already and reads it again goes on."""
    integrator = OdometryIntegrator(P3AT_SH, origin_at_start=True)
    _drive(integrator, [(1000 * i, 0, 512) for i in range(4)], 0)
    integrator.resume()
    after = _drive(integrator, [(0, 0, 0), (1000, 0, 0)], 12_300_000_000)
    assert integrator.tracks_joined == 1
    assert (after[0].x_m, after[0].theta_rad) == pytest.approx((3.0, math.pi / 4))
    assert (after[1].x_m, after[1].y_m) == pytest.approx((3.0 + math.sqrt(0.5), math.sqrt(0.5)))
    standing = OdometryIntegrator(P3AT_SH)
    _drive(standing, [(0, 0, 0), (10, 0, 1)], 0)
    standing.resume()
    assert _drive(standing, [(0, 0, 0)], 12_000_000_000)[0].x_m == 0.0
    assert standing.tracks_joined == 0


def test_a_late_sip_alone_is_no_break() -> None:
    """Two seconds without SIPs and no reconnect: the host stalled while the robot counted
    on, even if (a demo's twins, six times faster than real time) it looks too fast."""
    integrator = OdometryIntegrator(P3AT_SH, origin_at_start=True)
    _drive(integrator, [(0, 0, 0), (100, 0, 0)], 0)
    after = _drive(integrator, [(4100, 0, 0)], 2_100_000_000)
    assert after[0].x_m == pytest.approx(4.1) and integrator.tracks_joined == 0


def test_a_short_reconnect_to_zeroed_counters_is_still_a_new_track() -> None:
    """Back within half a second, but the counters jumped 5 m: only a reconnect can say so
    (a half-second gap alone is a late SIP, not a break)."""
    integrator = OdometryIntegrator(P3AT_SH, origin_at_start=True)
    _drive(integrator, [(5000, 0, 0), (5100, 0, 0)], 0)
    integrator.resume()
    after = _drive(integrator, [(0, 0, 0)], 600_000_000)
    assert after[0].x_m == pytest.approx(0.1) and integrator.tracks_joined == 1


def test_another_model_after_a_reconnect_scales_only_what_comes_after() -> None:
    integrator = OdometryIntegrator(P3AT, origin_at_start=True)
    _drive(integrator, [(0, 0, 0), (1000, 0, 0)], 0)
    integrator.resume(P3AT_SH)
    after = _drive(integrator, [(1000, 0, 0), (1500, 0, 0)], 1_000_000_000)
    assert [o.x_m for o in after] == pytest.approx([0.465, 0.965])
