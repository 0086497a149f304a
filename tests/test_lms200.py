"""LMS200 codec: protocols.md test vectors, round trips, resynchronisation, scans, real data."""

from __future__ import annotations

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


def test_reply_parsers_refuse_other_or_short_telegrams() -> None:
    short = L.Telegram(L.SENSOR_ADDRESS, L.Reply.STATUS, b"\x00" * 10, 0x10)
    assert L.parse_status_reply(short) is None
    assert L.parse_variant_reply(short) is None
    assert L.mode_result(short) is None
    assert L.LmsConfig.unpack(b"\x00" * 33) is None


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


def test_format_errors_for_self_contradicting_scans() -> None:
    lying_count = L.encode_reply(L.Reply.SCAN, (181).to_bytes(2, "little") + b"\x00" * 10)
    bad_units = L.encode_reply(L.Reply.SCAN, (1 | 0x8000).to_bytes(2, "little") + b"\x00\x00")
    out = decode(lying_count + bad_units + REPLY)
    assert [getattr(m, "reason", None) for m in out] == ["format", "format", None]


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


def test_unknown_beam_count_needs_the_configured_field() -> None:
    (scan,) = decode(L.encode_scan(np.full(180, 100), units="cm"))
    with pytest.raises(ConfigError):
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
