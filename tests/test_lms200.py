"""LMS200 codec: protocols.md test vectors, round trips, resynchronisation, scans, real data."""

from __future__ import annotations

import dataclasses
import math
import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from baromap.errors import ConfigError, EncodeError
from baromap.messages import BeamFlag
from baromap.protocols import lms200 as L
from baromap.protocols.framing import MAX_DISCARD_RUN, BadFrame

# protocols.md section 1: every telegram, byte for byte.
VECTORS = [
    ("request continuous output", L.start_continuous, "02 00 02 00 20 24 34 08"),
    ("stop continuous output", L.stop_continuous, "02 00 02 00 20 25 35 08"),
    ("switch to 9600", lambda: L.switch_baud(9600), "02 00 02 00 20 42 52 08"),
    ("switch to 19200", lambda: L.switch_baud(19200), "02 00 02 00 20 41 51 08"),
    ("switch to 38400", lambda: L.switch_baud(38400), "02 00 02 00 20 40 50 08"),
    ("switch to 500000", lambda: L.switch_baud(500000), "02 00 02 00 20 48 58 08"),
    ("status request", L.status_request, "02 00 01 00 31 15 12"),
    ("installation mode", L.installation_mode, "02 00 0A 00 20 00 53 49 43 4B 5F 4C 4D 53 BE C5"),
    ("variant 180/0.5", lambda: L.set_variant(180, 50), "02 00 05 00 3B B4 00 32 00 3B 1F"),
    ("reply mode change ok", L.mode_reply, "02 80 03 00 A0 00 10 16 0A"),
]


def decode(data: bytes, chunk: int | None = None) -> list[L.LmsMessage]:
    decoder = L.Decoder()
    if chunk is None:
        return decoder.feed(data) + decoder.flush()
    out: list[L.LmsMessage] = []
    for i in range(0, len(data), chunk):
        out += decoder.feed(data[i : i + chunk])
    return out + decoder.flush()


def good(messages: list[L.LmsMessage]) -> list[L.LmsMessage]:
    return [m for m in messages if not isinstance(m, BadFrame)]


@pytest.mark.parametrize(("name", "build", "expected"), VECTORS, ids=[v[0] for v in VECTORS])
def test_encoders_reproduce_protocol_vectors(name: str, build, expected: str) -> None:
    assert build() == bytes.fromhex(expected)


@pytest.mark.parametrize(("name", "build", "expected"), VECTORS, ids=[v[0] for v in VECTORS])
def test_decoder_reads_protocol_vectors_back(name: str, build, expected: str) -> None:
    raw = bytes.fromhex(expected)
    (message,) = decode(raw)
    assert isinstance(message, L.Telegram)
    assert message.command == raw[4]
    assert message.encode() == raw
    if raw[1] == L.SENSOR_ADDRESS:
        assert message.status == 0x10
        assert message.data == b"\x00"
        assert L.mode_result(message) == L.ModeResult.OK
    else:
        assert message.status is None
        assert message.data == raw[5:-2]


def test_baud_modes_map_both_ways() -> None:
    for baud, mode in L.BAUD_MODES.items():
        assert L.MODE_BAUDS[mode] == baud
        assert L.switch_baud(baud)[5] == mode


def test_reply_vector_with_its_ack() -> None:
    stream = b"\x06" + bytes.fromhex("02 80 03 00 A0 00 10 16 0A")
    assert decode(stream) == [L.Ack(), L.Telegram(0x80, 0xA0, b"\x00", 0x10)]


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=L.MAX_TELEGRAM_BYTES + 20))
def test_table_crc_equals_sicks_loop(data: bytes) -> None:
    assert L.crc16(data) == L.crc16_bitwise(data)


def test_table_crc_every_length() -> None:
    rng = random.Random(5)
    for n in range(L.MAX_TELEGRAM_BYTES + 1):
        data = rng.randbytes(n)
        assert L.crc16(data) == L.crc16_bitwise(data), n


def test_crc_table_rows_are_each_bytes_contribution() -> None:
    """The table :func:`L.crc16` reads is built once at import; built again here (any number
    of rows), XOR of its entries for each byte at its distance from the end is SICK's CRC."""
    rng = random.Random(11)
    for rows in (1, 5, 40):
        table = L._crc_table(rows)
        assert table.shape == (rows, 256) and table.dtype == np.uint16
        for n in range(rows + 1):
            data = rng.randbytes(n)
            crc = 0
            for j, byte in enumerate(data):
                crc ^= int(table[n - 1 - j][byte])
            assert crc == L.crc16_bitwise(data), (rows, n)


# -- round trips -------------------------------------------------------------------------------

commands = st.integers(0, 255)
payloads = st.binary(max_size=60)
statuses = st.integers(0, 255)


@st.composite
def scan_telegrams(draw: st.DrawFn) -> L.ScanTelegram:
    n = draw(st.sampled_from([0, 1, 2, 101, 181, 201, 361, 401]) | st.integers(0, 401))
    values = draw(st.lists(st.integers(0, 0xFFFF), min_size=n, max_size=n))
    units = draw(st.sampled_from(["cm", "mm"]))
    count = L.scan_count_word(
        n, units, partial=draw(st.booleans()), partial_index=draw(st.integers(0, 3))
    )
    extra = draw(st.binary(max_size=1 if n == 401 else 3))
    reply = draw(st.sampled_from(SCAN_REPLIES))
    mean = reply in (L.Reply.MEAN_SCAN, L.Reply.MEAN_SUBRANGE_SCAN)
    sub = reply in (L.Reply.SUBRANGE_SCAN, L.Reply.MEAN_SUBRANGE_SCAN)
    if n > 400 and (mean or sub):  # the header bytes must fit LEN too
        reply, mean, sub = L.Reply.SCAN, False, False
    return L.ScanTelegram(
        count,
        np.array(values, dtype=np.uint16),
        draw(statuses),
        extra,
        reply=reply,
        sample_size=draw(st.integers(2, 250)) if mean else None,
        subrange=(draw(st.integers(1, 401)), draw(st.integers(1, 401))) if sub else None,
    )


SCAN_REPLIES = (
    L.Reply.SCAN,
    L.Reply.MEAN_SCAN,
    L.Reply.SUBRANGE_SCAN,
    L.Reply.MEAN_SUBRANGE_SCAN,
)


@st.composite
def messages(draw: st.DrawFn) -> L.Ack | L.Nak | L.Telegram | L.ScanTelegram:
    kind = draw(st.sampled_from(["ack", "nak", "host", "reply", "scan"]))
    if kind == "ack":
        return L.Ack()
    if kind == "nak":
        return L.Nak()
    if kind == "host":
        return L.Telegram(L.HOST_ADDRESS, draw(commands), draw(payloads))
    if kind == "reply":
        command = draw(commands.filter(lambda c: c not in SCAN_REPLIES))
        return L.Telegram(L.SENSOR_ADDRESS, command, draw(payloads), draw(statuses))
    return draw(scan_telegrams())


def encode(message: L.Ack | L.Nak | L.Telegram | L.ScanTelegram) -> bytes:
    if isinstance(message, L.Ack):
        return bytes((L.ACK,))
    if isinstance(message, L.Nak):
        return bytes((L.NAK,))
    return message.encode()


@pytest.mark.slow
@settings(max_examples=100, deadline=None)
@given(messages())
def test_every_message_type_round_trips(message) -> None:
    assert decode(encode(message)) == [message]


@pytest.mark.slow
@settings(max_examples=60, deadline=None)
@given(st.lists(messages(), min_size=1, max_size=8), st.randoms(use_true_random=False))
def test_any_chunking_gives_identical_output(batch, rnd: random.Random) -> None:
    stream = b"".join(encode(m) for m in batch)
    assert decode(stream) == batch
    assert decode(stream, chunk=1) == batch
    cuts = (
        sorted(rnd.sample(range(1, len(stream)), min(len(stream) - 1, 5)))
        if len(stream) > 1
        else []
    )
    decoder = L.Decoder()
    out: list[L.LmsMessage] = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        out += decoder.feed(stream[a:b])
    assert out + decoder.flush() == batch


@settings(max_examples=60, deadline=None)
@given(st.binary(min_size=1, max_size=120), st.lists(messages(), min_size=1, max_size=4))
def test_garbage_chunking_invariance_and_byte_accounting(garbage: bytes, batch) -> None:
    stream = garbage + b"".join(encode(m) for m in batch) + garbage
    whole, by_byte = decode(stream), decode(stream, chunk=1)
    assert whole == by_byte
    decoder = L.Decoder()
    out = decoder.feed(stream) + decoder.flush()
    good_bytes = sum(len(encode(m)) for m in out if not isinstance(m, BadFrame))
    assert good_bytes + decoder.stats.bytes_discarded == len(stream) == decoder.stats.bytes_in


def test_config_status_variant_type_replies_round_trip() -> None:
    config = L.LmsConfig(blanking=7, units=0, contours=tuple(range(15)), dazzle_evaluation=513)
    assert L.LmsConfig.unpack(config.pack()) == config
    report = L.StatusReport(angle_deg=100, resolution_cdeg=25, units=0, operating_mode=0x24)
    variant = L.VariantReply(False, 100, 25)
    stream = (
        L.config_reply(config)
        + L.config_write_reply(True, config)
        + L.status_reply(report)
        + L.variant_reply(variant)
        + L.type_reply("LMS200;30106")
    )
    read, written, status, var, kind = decode(stream)
    assert L.LmsConfig.unpack(read.data) == config
    assert L.parse_config_write_reply(written) == (True, config)
    assert L.parse_status_reply(status) == report
    assert L.parse_variant_reply(var) == variant
    assert L.parse_type_reply(kind) == "LMS200;30106"
    assert L.set_config(config)[5:-2] == config.pack()


def test_status_reply_fields_sit_at_sicktoolboxs_offsets() -> None:
    """Every field a B1 reply carries, each a value no other field has, at its data offset;
    the two version strings padded or cut to their seven bytes."""
    report = L.StatusReport(
        software_version="V3.2",
        operating_mode=0x24,
        device_status=3,
        variant=4,
        measuring_mode=5,
        angle_deg=100,
        resolution_cdeg=25,
        address=6,
        units=1,
        laser_on=7,
        prom_version="P0123456X",
    )
    (telegram,) = decode(L.status_reply(report, status=0x11))
    assert telegram.status == 0x11 and len(telegram.data) == L.STATUS_FULL_BYTES
    data = telegram.data
    assert data[0:7] == b"V3.2   " and data[123:130] == b"P012345"
    assert (data[7], data[8], data[17], data[101]) == (0x24, 3, 4, 5)
    assert data[106:110] == bytes((100, 0, 25, 0))
    assert (data[119], data[121], data[122]) == (6, 1, 7)
    assert sum(data) == sum(b"V3.2   P012345") + 0x24 + 3 + 4 + 5 + 100 + 25 + 6 + 1 + 7
    parsed = L.parse_status_reply(telegram)
    assert parsed == dataclasses.replace(report, software_version="V3.2   ", prom_version="P012345")
    # the shortest reply that holds every field; a longer version string is cut to 7
    longer = dataclasses.replace(report, software_version="V03.21XYZ", prom_version="P1")
    (telegram,) = decode(L.status_reply(longer, size=130))
    parsed = L.parse_status_reply(telegram)
    assert len(telegram.data) == 130 and parsed is not None
    assert parsed.software_version == "V03.21X" and parsed.prom_version == "P1     "
    with pytest.raises(EncodeError, match="130"):
        L.status_reply(report, size=129)
    cut = L.Telegram(L.SENSOR_ADDRESS, L.Reply.STATUS, telegram.data[:129], 0x10)
    assert L.parse_status_reply(cut) is None
    # bytes that are no ASCII read as replacement characters, never as an error
    garbled = L.Telegram(L.SENSOR_ADDRESS, L.Reply.STATUS, b"\xff" * 130, 0x10)
    parsed = L.parse_status_reply(garbled)
    assert parsed is not None and parsed.software_version == "\ufffd" * 7
    assert parsed.prom_version == "\ufffd" * 7
    # UTF-8 is no ASCII either: each of its bytes is a replacement character of its own
    utf8 = L.Telegram(L.SENSOR_ADDRESS, L.Reply.STATUS, "é".encode() * 65, 0x10)
    parsed = L.parse_status_reply(utf8)
    assert parsed is not None and parsed.software_version == "\ufffd" * 7
    assert parsed.prom_version == "\ufffd" * 7


def test_reply_parsers_refuse_other_or_short_telegrams() -> None:
    short = L.Telegram(L.SENSOR_ADDRESS, L.Reply.STATUS, b"\x00" * 10, 0x10)
    assert L.parse_status_reply(short) is None
    assert L.parse_variant_reply(short) is None
    assert L.mode_result(short) is None
    assert L.LmsConfig.unpack(b"\x00" * 33) is None


def test_host_commands_are_the_listed_bytes() -> None:
    """Each command builder is its command byte and arguments (LEN, CRC: the vectors above)."""
    assert L.reset() == L.encode_telegram(0x10)
    assert L.type_request() == L.encode_telegram(0x3A)
    assert L.config_request() == L.encode_telegram(0x74)
    assert L.start_mean(2) == L.encode_telegram(0x20, b"\x26\x02")
    assert L.start_mean(250) == L.encode_telegram(0x20, b"\x26\xfa")
    assert L.start_subrange(1, 181) == L.encode_telegram(0x20, b"\x27\x01\x00\xb5\x00")
    assert L.start_subrange(7, 7) == L.encode_telegram(0x20, b"\x27\x07\x00\x07\x00")
    assert L.start_subrange(1, 1023) == L.encode_telegram(0x20, b"\x27\x01\x00\xff\x03")
    assert L.start_mean_subrange(2, 11, 300) == L.encode_telegram(0x20, b"\x28\x02\x0b\x00\x2c\x01")
    assert L.start_mean_subrange(250, 1, 1) == L.encode_telegram(0x20, b"\x28\xfa\x01\x00\x01\x00")


@pytest.mark.parametrize(
    ("call", "args"),
    [
        (L.start_mean, (1,)),
        (L.start_mean, (251,)),
        (L.start_subrange, (0, 10)),
        (L.start_subrange, (11, 10)),
        (L.start_subrange, (1, 1024)),
        (L.start_mean_subrange, (1, 1, 10)),
        (L.start_mean_subrange, (251, 1, 10)),
        (L.start_mean_subrange, (5, 0, 10)),
        (L.start_mean_subrange, (5, 11, 10)),
        (L.start_mean_subrange, (5, 1, 1024)),
    ],
)
def test_mean_and_subrange_modes_refuse_what_the_sensor_cannot_do(call, args) -> None:
    with pytest.raises(EncodeError):
        call(*args)


def test_reset_and_power_on_replies_decode() -> None:
    stream = L.reset_reply() + L.power_on_telegram("LMS ready", status=0x11) + L.reset_reply(0x12)
    assert decode(stream) == [
        L.Telegram(L.SENSOR_ADDRESS, 0x91, b"", 0x10),
        L.Telegram(L.SENSOR_ADDRESS, 0x90, b"LMS ready", 0x11),
        L.Telegram(L.SENSOR_ADDRESS, 0x91, b"", 0x12),
    ]
    assert L.power_on_telegram("x") == L.encode_reply(0x90, b"x", 0x10)


def test_a_short_configuration_block_updates_the_leading_fields() -> None:
    """ARIA's 32-byte 77 block sets the fields it holds; the last one (two bytes) keeps its
    value."""
    current = L.LmsConfig(blanking=1, fields_bc_restart_times=9, dazzle_evaluation=7)
    wanted = L.LmsConfig(
        blanking=300,
        units=0,
        contours=tuple(range(15)),
        fields_bc_restart_times=4,
        dazzle_evaluation=5,
    )
    block = wanted.pack()
    assert current.updated(block) == wanted
    merged = current.updated(block[: L.MIN_CONFIG_BLOCK])
    assert merged == dataclasses.replace(wanted, dazzle_evaluation=7)
    assert current.updated(block[: L.MIN_CONFIG_BLOCK - 1]) is None
    assert current.updated(block + b"\x00") is None


def test_range_bits_per_measuring_mode() -> None:
    assert [L.range_bits(mode) for mode in L.MeasuringMode] == [13, 13, 13, 14, 14, 15, 15, 16]
    with pytest.raises(ConfigError, match="0x07"):
        L.range_bits(0x07)


@pytest.mark.parametrize(
    ("call", "args"),
    [
        (L.switch_baud, (57600,)),
        (L.set_variant, (180, 25)),
        (L.set_variant, (90, 100)),
        (L.installation_mode, (b"SICK",)),
        (L.encode_telegram, (256,)),
        (L.encode_reply, (0xA0, b"", 300)),
        (L.encode_telegram, (0x20, b"\x00" * L.MAX_LEN)),
        (L.scan_count_word, (1024,)),
    ],
)
def test_encoders_refuse_what_the_wire_cannot_carry(call, args) -> None:
    with pytest.raises(EncodeError):
        call(*args)


_FIELD_REFUSALS = [
    (L.set_mode, (256,), "mode 256 does not fit in a byte"),
    (L.mode_reply, (256,), "result 256 does not fit in a byte"),
    *(
        (
            L.status_reply,
            (L.StatusReport(**{field: 256}),),
            f"{field.replace('_', ' ')} 256 does not fit in a byte",
        )
        for field in (
            "operating_mode",
            "device_status",
            "variant",
            "measuring_mode",
            "address",
            "units",
            "laser_on",
        )
    ),
]


@pytest.mark.parametrize(
    ("call", "args", "message"),
    [
        (L.switch_baud, (57600,), "LMS200 speaks [9600, 19200, 38400, 500000] baud, not 57600"),
        (L.start_mean, (1,), "mean values take 2..250 scans, not 1"),
        (L.start_mean_subrange, (251, 1, 10), "mean values take 2..250 scans, not 251"),
        (L.start_subrange, (0, 10), "subrange 0..10 is not 1 <= first <= last"),
        (L.installation_mode, (b"SICK",), "the installation password is 8 bytes"),
        (L.set_variant, (180, 25), "no LMS200 variant 180 deg at 0.25 deg"),
        (L.LmsConfig(contours=(0,) * 14).pack, (), "contours hold 3 x 5 bytes"),
        (
            L.LmsConfig(blanking=70000).pack,
            (),
            "configuration field out of range: ushort format requires 0 <= number <= 65535",
        ),
        (
            lambda: L.range_words([1.0], bits=12),
            (),
            "value words have 13 to 16 range bits, not 12",
        ),
        (lambda: L.range_words([[1.0]]), (), "ranges must be a 1-D sequence"),
        (lambda: L.range_words([1.0, 2.0], [0]), (), "flags must have one entry per range"),
        *_FIELD_REFUSALS,
    ],
)
def test_refusals_name_the_value_and_what_the_sensor_takes(call, args, message) -> None:
    """The message is what a user reads when a configuration asks for the impossible."""
    with pytest.raises(EncodeError) as refused:
        call(*args)
    assert str(refused.value) == message


def test_replies_keep_their_status_byte_and_parsers_their_command() -> None:
    config = L.LmsConfig(blanking=7)
    accepted = L.VariantReply(True, 180, 50)
    stream = (
        L.config_reply(config, status=0x12)
        + L.config_write_reply(False, config, status=0x13)
        + L.variant_reply(accepted, status=0x14)
        + L.mode_reply(status=0x15)
        + L.type_reply("LMS200", status=0x16)
    )
    read, written, variant, mode, kind = decode(stream)
    statuses = [t.status for t in (read, written, variant, mode, kind)]
    assert statuses == [0x12, 0x13, 0x14, 0x15, 0x16]
    assert L.parse_config_write_reply(written) == (False, config)
    assert L.parse_variant_reply(variant) == accepted
    # a telegram of another command is none of these, whatever its data
    other = L.Telegram(L.SENSOR_ADDRESS, L.Reply.MODE, variant.data, 0x10)
    assert L.parse_variant_reply(other) is None
    assert L.parse_config_write_reply(other) is None


def test_type_reply_text_loses_only_trailing_padding() -> None:
    def kind(data: bytes) -> str | None:
        return L.parse_type_reply(L.Telegram(L.SENSOR_ADDRESS, L.Reply.TYPE, data, 0x10))

    assert kind(b" LMS200;30106 \x00\x00") == " LMS200;30106"
    assert kind(b"LMS200X\x00") == "LMS200X"
    assert kind(b"LMS\xc3\xa9\xff") == "LMS\ufffd\ufffd\ufffd"  # not ASCII: never an error


def test_scan_telegram_checks_its_count() -> None:
    with pytest.raises(EncodeError):
        L.ScanTelegram(L.scan_count_word(3), np.zeros(2, dtype=np.uint16))
    with pytest.raises(EncodeError):
        L.ScanTelegram(3 | 0x8000, np.zeros(3, dtype=np.uint16))


# -- resynchronisation -----------------------------------------------------------------------

REPLY = L.mode_reply()
SCAN = L.encode_scan(L.range_words(np.linspace(0.5, 7.5, 181)), units="mm")


@pytest.mark.parametrize(
    "garbage",
    [b"\x00", b"\xff" * 7, b"\x02", b"\x02\x80", b"\x02\x80\x03", b"\x02\x00\xff\xff", b"\x15\x06"],
    ids=["nul", "ff", "stx", "stx-adr", "stx-adr-len", "huge-len", "nak-ack"],
)
@pytest.mark.parametrize("where", ["before", "between", "after"])
def test_garbage_is_counted_and_the_next_frame_decodes(garbage: bytes, where: str) -> None:
    if where == "before":
        stream = garbage + REPLY + SCAN
    elif where == "between":
        stream = REPLY + garbage + SCAN
    else:
        stream = REPLY + SCAN + garbage
    for chunk in (None, 1, 5):
        out = decode(stream, chunk)
        scans = [m for m in out if isinstance(m, L.ScanTelegram)]
        assert len(scans) == 1 and scans[0].encode() == SCAN
        replies = [m for m in out if isinstance(m, L.Telegram)]
        assert [r.encode() for r in replies] == [REPLY]
        bad = [m for m in out if isinstance(m, BadFrame)]
        acks = [m for m in out if isinstance(m, (L.Ack, L.Nak))]
        assert sum(b.size for b in bad) + len(acks) == len(garbage)


@pytest.mark.parametrize("cut", [1, 3, 4, 10, 100, len(SCAN) - 1])
def test_garbage_inside_a_frame_loses_only_that_frame(cut: int) -> None:
    broken = SCAN[:cut] + b"\x55\xaa" + SCAN[cut:]
    out = decode(REPLY + broken + REPLY)
    assert [m for m in out if isinstance(m, L.Telegram)] == [
        L.Telegram(0x80, 0xA0, b"\x00", 0x10)
    ] * 2
    assert not any(isinstance(m, L.ScanTelegram) for m in out)
    assert sum(m.size for m in out if isinstance(m, BadFrame)) == len(broken)


@pytest.mark.parametrize("cut", range(1, len(REPLY)))
def test_truncated_frames_are_reported_at_end_of_stream(cut: int) -> None:
    decoder = L.Decoder()
    assert decoder.feed(REPLY[:cut]) == []
    (bad,) = decoder.flush()
    assert bad.reason == "truncated" and bad.size == cut


def test_oversized_len_is_rejected_without_waiting() -> None:
    bogus = b"\x02\x80" + (L.MAX_LEN + 1).to_bytes(2, "little")
    out = decode(bogus + REPLY)
    assert isinstance(out[0], BadFrame) and out[0].reason == "length"
    assert out[0].size == len(bogus)
    assert out[1:] == [L.Telegram(0x80, 0xA0, b"\x00", 0x10)]


def test_a_frame_inside_a_rejected_candidate_is_still_found() -> None:
    # A plausible header whose "body" swallows a real reply: the CRC fails, the search resumes
    # after the bogus STX and finds the reply inside.
    length = 40
    bogus = b"\x02\x80" + length.to_bytes(2, "little")
    filler = bytes(range(0x30, 0x30 + length + 2 - len(REPLY)))
    out = decode(bogus + REPLY + filler + SCAN)
    assert [type(m) for m in out] == [BadFrame, L.Telegram, BadFrame, L.ScanTelegram]
    assert out[0].reason == "crc" and out[0].size == len(bogus)
    assert out[2].size == len(filler)


def test_ack_and_nak_only_at_a_telegram_boundary() -> None:
    assert decode(b"\x06" + REPLY + b"\x15") == [L.Ack(), good(decode(REPLY))[0], L.Nak()]
    out = decode(b"\x33\x06" + REPLY)  # after garbage, 0x06 is garbage too
    assert isinstance(out[0], BadFrame) and out[0].size == 2
    assert out[1:] == good(decode(REPLY))


def test_joining_mid_stream_trusts_no_ack_before_a_telegram() -> None:
    mid_scan = SCAN[100:140]
    decoder = L.Decoder(at_boundary=False)
    out = decoder.feed(b"\x06" + mid_scan + REPLY + b"\x06") + decoder.flush()
    assert [type(m) for m in out] == [BadFrame, L.Telegram, L.Ack]
    assert out[0].size == 1 + len(mid_scan)
    assert decode(b"\x06")[0] == L.Ack()  # a fresh decoder is at a boundary by default


def test_long_garbage_is_reported_in_bounded_runs() -> None:
    garbage = bytes([0x55]) * (3 * MAX_DISCARD_RUN + 5)
    decoder = L.Decoder()
    out = decoder.feed(garbage) + decoder.feed(REPLY) + decoder.flush()
    sizes = [m.size for m in out if isinstance(m, BadFrame)]
    assert sizes == [MAX_DISCARD_RUN] * 3 + [5]
    assert len(decoder._buf) == 0
    assert decoder.stats.as_dict()["bad_garbage"] == 4


def test_decoder_counters_are_named_for_health_messages() -> None:
    decoder = L.Decoder()
    decoder.feed(b"\x55\x55" + REPLY)
    decoder.flush()
    assert decoder.stats.as_dict() == {
        "frames": 1,
        "bytes_in": 2 + len(REPLY),
        "bytes_discarded": 2,
        "bad_garbage": 1,
    }


def test_format_errors_for_self_contradicting_scans() -> None:
    lying_count = L.encode_reply(L.Reply.SCAN, (181).to_bytes(2, "little") + b"\x00" * 10)
    bad_units = L.encode_reply(L.Reply.SCAN, (1 | 0x8000).to_bytes(2, "little") + b"\x00\x00")
    out = decode(lying_count + bad_units + REPLY)
    assert [getattr(m, "reason", None) for m in out] == ["format", "format", None]
    too_short = L.encode_reply(L.Reply.SCAN, b"\x01")  # not even a count field
    assert decode(too_short) == [BadFrame("format", len(too_short), too_short)]


def test_decoded_telegrams_carry_their_wire_size() -> None:
    items = [L.status_request(), REPLY, L.encode_scan([1, 2, 3])]
    decoded = decode(b"".join(items))
    assert [m.wire_size for m in decoded] == [len(item) for item in items]


def test_scans_equal_only_in_every_field() -> None:
    base = L.ScanTelegram(L.scan_count_word(3), np.array([1, 2, 3]), extra=b"\x01")
    assert base == L.ScanTelegram(L.scan_count_word(3), np.array([1, 2, 3]), extra=b"\x01")
    others = [
        dataclasses.replace(base, count_word=L.scan_count_word(3, "cm")),
        dataclasses.replace(base, status=0x11),
        dataclasses.replace(base, extra=b"\x02"),
        dataclasses.replace(base, address=0x81),
        dataclasses.replace(base, values=np.array([1, 2, 4])),
    ]
    assert all(other != base for other in others)


def test_a_scan_keeps_its_own_read_only_words() -> None:
    """Writeable words are copied (the caller's array stays the caller's); read-only uint16
    words are shared, not copied."""
    words = np.array([1, 2, 3], dtype=np.uint16)
    scan = L.ScanTelegram(L.scan_count_word(3), words)
    words[0] = 9
    assert scan.values.tolist() == [1, 2, 3] and words.flags.writeable
    assert not scan.values.flags.writeable
    assert L.ScanTelegram(scan.count_word, scan.values).values is scan.values
    assert L.scan_count_word(3) == 3 | 1 << 14  # whole (not partial), in mm, unless told
    for values in ([70000], [-1]):
        with pytest.raises(EncodeError, match=r"^scan values must fit in 16 bits$"):
            L.encode_scan(values)


# -- scans as LaserScans ---------------------------------------------------------------------


@pytest.mark.parametrize(
    ("n", "field_deg", "step_deg"),
    [(181, 180, 1.0), (361, 180, 0.5), (101, 100, 1.0), (201, 100, 0.5), (401, 100, 0.25)],
)
@pytest.mark.parametrize(("units", "range_max"), [("mm", 8.19), ("cm", 81.9)])
def test_scan_geometry_and_units(
    n: int, field_deg: float, step_deg: float, units, range_max
) -> None:
    words = np.full(n, 1234, dtype=np.uint16)
    (scan,) = decode(L.encode_scan(words, units=units, status=0x10))
    laser = scan.to_laser_scan(t_ns=42)
    assert laser.t_ns == 42 and laser.beam_count == n and laser.status == 0x10
    assert math.isclose(laser.angle_min_rad, -math.radians(field_deg / 2))
    assert math.isclose(laser.angle_max_rad, math.radians(field_deg / 2))
    assert math.isclose(laser.angle_increment_rad, math.radians(step_deg))
    assert laser.range_max_m == range_max
    scale = 0.001 if units == "mm" else 0.01
    assert np.allclose(laser.ranges_m, 1234 * scale)
    assert laser.valid().all()


@pytest.mark.parametrize("index", [0, 1, 2, 3])
def test_partial_scans_start_a_quarter_degree_further_per_index(index: int) -> None:
    (scan,) = decode(L.encode_scan(np.full(101, 500), partial=True, partial_index=index))
    laser = scan.to_laser_scan(0)
    assert scan.partial and scan.partial_index == index
    assert math.isclose(laser.angle_min_rad, math.radians(-50.0 + 0.25 * index))
    assert math.isclose(laser.angle_increment_rad, math.radians(1.0))


def test_scan_encoder_defaults_and_header_fields() -> None:
    """A B0 in mm, whole, with nothing after the values, unless told; a sample size makes a
    B6, a subrange a B7, both a BF, each header field read back."""
    (plain,) = decode(L.encode_scan([1, 2, 3]))
    assert plain.reply == L.Reply.SCAN and plain.count_word == 3 | 1 << 14
    assert plain.extra == b"" and plain.sample_size is None and plain.subrange is None
    assert len(L.encode_scan([1, 2, 3])) == 4 + 1 + 2 + 6 + 1 + 2
    cases = [
        ({"sample_size": 5}, L.Reply.MEAN_SCAN, 5, None),
        ({"subrange": (2, 4)}, L.Reply.SUBRANGE_SCAN, None, (2, 4)),
        ({"sample_size": 7, "subrange": (3, 5)}, L.Reply.MEAN_SUBRANGE_SCAN, 7, (3, 5)),
    ]
    for header, reply, sample_size, subrange in cases:
        (scan,) = decode(L.encode_scan([1, 2, 3], extra=b"\x09\x00", **header))
        assert (scan.reply, scan.sample_size, scan.subrange) == (reply, sample_size, subrange)
        assert scan.extra == b"\x09\x00" and scan.values.tolist() == [1, 2, 3]


def test_laser_scans_carry_the_scan_index_and_the_range_of_the_mode() -> None:
    (scan,) = decode(L.encode_scan(np.full(181, 100), extra=b"\x05\x01"))
    laser = scan.to_laser_scan(0, bits=15)
    assert laser.scan_index == 0x105 and laser.range_max_m == pytest.approx(32.76)
    (single,) = decode(L.encode_scan([100]))  # one beam: its field is its step
    step = single.to_laser_scan(0, field_deg=10.0).angle_increment_rad
    assert math.isclose(step, math.radians(10.0))
    assert laser.flags.dtype == np.uint16 and laser.ranges_m.dtype == np.float32


def test_unknown_beam_count_needs_the_configured_field() -> None:
    (scan,) = decode(L.encode_scan(np.full(180, 100), units="cm"))
    with pytest.raises(ConfigError, match=r"^180 beams has no documented field; pass field_deg$"):
        scan.to_laser_scan(0)
    laser = scan.to_laser_scan(0, field_deg=179.0)
    assert math.isclose(laser.angle_increment_rad, math.radians(1.0))


def test_error_codes_and_raw_bits_become_flags() -> None:
    codes = [0x1FFF, 0x1FFE, 0x1FFD, 0x1FFB, 0x1FFA, 0x1FF7, 0x1FF8, 0x1FF6, 0x0123 | 0xE000]
    (scan,) = decode(L.encode_scan(codes, units="mm"))
    ranges, flags = scan.ranges_and_flags()
    expected = [
        BeamFlag.INVALID,
        BeamFlag.DAZZLE,
        BeamFlag.OVERFLOW,
        BeamFlag.LOW_SNR,
        BeamFlag.CHANNEL_ERROR,
        BeamFlag.OVER_RANGE,
        BeamFlag.INVALID,  # undocumented reserved value
        BeamFlag.NONE,  # 8.182 m, the longest real range
        BeamFlag.RAW_BIT13 | BeamFlag.RAW_BIT14 | BeamFlag.RAW_BIT15,
    ]
    assert [BeamFlag(int(f)) for f in flags] == expected
    assert np.isnan(ranges[:7]).all()
    assert ranges[7] == pytest.approx(8.182) and ranges[8] == pytest.approx(0.291)


def test_status_byte_decoding() -> None:
    assert L.decode_status(0x10).healthy
    assert L.decode_status(0x14) == L.SensorStatus(0x14, L.Severity.FATAL, False, False)
    # bits 3-5 are no flags, bits 0-2 the severity only
    assert L.decode_status(0x3B) == L.SensorStatus(0x3B, L.Severity.ERROR, False, False)
    assert L.decode_status(0x45) == L.SensorStatus(0x45, None, True, False)
    assert L.decode_status(0x86) == L.SensorStatus(0x86, None, False, True)
    (scan,) = decode(L.encode_scan(np.full(181, 100), status=0xC3))
    assert scan.sensor_status() == L.decode_status(0xC3)
    s = L.decode_status(0xC3)
    assert s.code is L.Severity.ERROR and s.implausible and s.pollution and not s.healthy
    assert L.decode_status(0x07).code is None


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.floats(0.0, 8.17) | st.just(math.nan) | st.floats(8.2, 1e6), min_size=1, max_size=401
    ),
    st.sampled_from(["mm", "cm"]),
)
def test_range_words_invert_the_decoding(ranges: list[float], units) -> None:
    words = L.range_words(ranges, units=units)
    decoded, flags = L.ScanTelegram(L.scan_count_word(len(ranges), units), words).ranges_and_flags()
    source = np.array(ranges)
    resolution = 0.001 if units == "mm" else 0.01
    in_range = source < L.FIRST_ERROR_CODE * resolution - resolution
    assert np.allclose(decoded[in_range], source[in_range], atol=resolution / 2 + 1e-6)
    assert (flags[np.isnan(source)] == BeamFlag.INVALID).all()
    over = source > L.RANGE_MAX_M[units]
    assert (flags[over] == BeamFlag.OVER_RANGE).all()


def test_range_words_carry_explicit_flags() -> None:
    flags = [int(BeamFlag.DAZZLE), int(BeamFlag.RAW_BIT14), 0]
    words = L.range_words([1.0, 2.0, 3.0], flags, units="mm")
    assert list(words) == [0x1FFE, 2000 | 0x4000, 3000]
    assert words.dtype == np.uint16 and not words.flags.writeable


def test_word_tables_are_float32_ranges_and_uint16_flags() -> None:
    """The definition the cached tables are built from, called directly (the cache would
    keep a table built before a change)."""
    words = np.array([1000, 0x1FFF, 1000 | 0x2000], dtype=np.uint16)
    ranges, flags = L._words_to_ranges_and_flags(words, "mm", 13)
    assert ranges.dtype == np.float32 and flags.dtype == np.uint16
    assert ranges[0] == np.float32(1.0) and math.isnan(ranges[1]) and flags[2] != 0


def test_range_words_of_wider_range_fields() -> None:
    """With 15 range bits (the 32 m modes) the error codes sit at the top of the wider field
    and one raw flag bit fits above it; with 16 none does."""
    nan = math.nan
    assert list(L.range_words([nan, 40.0, 10.0, -1.0], bits=15)) == [0x7FFF, 0x7FF7, 10000, 0x7FFF]
    assert list(L.range_words([1.0], [int(BeamFlag.DAZZLE)], bits=15)) == [0x7FFE]
    raw = int(BeamFlag.RAW_BIT13 | BeamFlag.RAW_BIT14 | BeamFlag.RAW_BIT15)
    expected = {13: 1000 | 0xE000, 14: 1000 | 0xC000, 15: 1000 | 0x8000, 16: 1000}
    for bits, word in expected.items():
        assert list(L.range_words([1.0], [raw], bits=bits)) == [word], bits
    assert list(L.range_words([1.0], [int(BeamFlag.RAW_BIT13)])) == [1000 | 0x2000]
    with pytest.raises(EncodeError):
        L.range_words([1.0], bits=12)
    with pytest.raises(EncodeError):
        L.range_words([[1.0]])
    with pytest.raises(EncodeError):
        L.range_words([1.0, 2.0], [0])


# -- real data -------------------------------------------------------------------------------


def test_intel_lab_scans_survive_the_wire(shared_data) -> None:
    """910 real LMS scans (cm units) through encoder, a noisy line and the decoder."""
    from baromap.recording.carmen import read_carmen

    log = read_carmen(shared_data / "laser" / "intel-corrected-abstime.log.gz")
    assert len(log.scans) == 910
    rng = random.Random(7)
    parts = []
    for scan in log.scans:
        parts.append(rng.randbytes(rng.randrange(4)))  # line noise between telegrams
        words = np.rint(scan.ranges_m * 100).astype(np.uint16)  # what the sensor sent
        parts.append(L.encode_scan(words, units="cm"))
    stream = b"".join(parts)
    decoder = L.Decoder()
    out: list[L.LmsMessage] = []
    for i in range(0, len(stream), 4096):
        out += decoder.feed(stream[i : i + 4096])
    out += decoder.flush()
    scans = [m for m in out if isinstance(m, L.ScanTelegram)]
    assert len(scans) == 910
    no_return = 0
    for source, scan in zip(log.scans, scans, strict=True):
        ranges, flags = scan.ranges_and_flags()
        # the logged 81.83 m is the sensor's own "over range" code 0x1FF7 in cm units
        far = np.isclose(source.ranges_m, 81.83)
        no_return += int(far.sum())
        assert (flags[far] == BeamFlag.OVER_RANGE).all() and np.isnan(ranges[far]).all()
        assert np.allclose(ranges[~far], source.ranges_m[~far], atol=0.005)
    assert no_return > 0
    # noise right after a telegram that happens to be 0x06/0x15 reads as ACK/NAK, by design
    acks = sum(isinstance(m, (L.Ack, L.Nak)) for m in out)
    assert decoder.stats.bytes_discarded + acks == sum(len(p) for p in parts[0::2])


@pytest.mark.parametrize("units", ["cm", "mm"])
@pytest.mark.parametrize("bits", sorted(set(L.RANGE_BITS.values())))
def test_scans_read_every_word_as_the_element_wise_definition_says(
    units: L.Units, bits: int
) -> None:
    """Scans look their words up in tables built per unit and range width: every word of
    every mode reads as the definition computes it on the scan's own words."""
    words = np.arange(1 << 16, dtype=np.uint16)
    words.setflags(write=False)
    for start in range(0, 1 << 16, 1023):  # scans of 1023 words (the 10-bit count's limit)
        chunk = words[start : start + 1023]
        scan = L.ScanTelegram(L.scan_count_word(len(chunk), units), chunk)
        ranges, flags = scan.ranges_and_flags(bits)
        expected_ranges, expected_flags = L._words_to_ranges_and_flags(chunk, units, bits)
        assert np.array_equal(ranges, expected_ranges, equal_nan=True)
        assert np.array_equal(flags, expected_flags)
        assert ranges.dtype == np.float32 and flags.dtype == np.uint16
        assert not ranges.flags.writeable and not flags.flags.writeable
