"""The barometer board codec against firmware/test_vectors.txt and under hypothesis."""

from __future__ import annotations

import random
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from baromap.errors import EncodeError
from baromap.messages import PressureSample
from baromap.protocols import baro
from baromap.protocols.framing import BadFrame

VECTORS = Path(__file__).resolve().parent.parent / "firmware" / "test_vectors.txt"
CLASS_BY_TYPE_NAME = {cls.TYPE.name: cls for cls in baro.FRAME_CLASSES}


def load_vectors() -> list[tuple[str, dict[str, str]]]:
    vectors = []
    for line in VECTORS.read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        kind, *tokens = line.split()
        vectors.append((kind, dict(token.split("=", 1) for token in tokens)))
    return vectors


def vectors_of(kind: str) -> list[Any]:
    return [pytest.param(v, id=v["name"]) for k, v in load_vectors() if k == kind]


def frame_from_vector(v: dict[str, str]) -> baro.Frame:
    cls = CLASS_BY_TYPE_NAME[v["type"]]
    names = ["seq", "time_us", *baro.PAYLOAD_FIELDS[cls]]
    return cls(*(int(v[name]) for name in names))


def frames_and_bad(items: list[baro.DecodedItem]) -> tuple[list[baro.Frame], list[BadFrame]]:
    frames = [item for item in items if not isinstance(item, BadFrame)]
    bad = [item for item in items if isinstance(item, BadFrame)]
    return frames, bad


# --- shared vectors -------------------------------------------------------------------------


def test_vector_file_covers_every_frame_type_and_reason() -> None:
    kinds = {k for k, _ in load_vectors()}
    assert {"crc", "cobs", "frame", "bad", "bmp280", "bmp280_calib"} <= kinds
    types = {v["type"] for k, v in load_vectors() if k == "frame"}
    assert types == set(CLASS_BY_TYPE_NAME)
    reasons = {v["reason"] for k, v in load_vectors() if k == "bad"}
    assert reasons == {"cobs", "short", "crc", "version", "type", "length"}


def test_crc_check_value() -> None:
    assert baro.crc16(b"123456789") == 0x29B1


@pytest.mark.parametrize("v", vectors_of("crc"))
def test_crc_vectors(v: dict[str, str]) -> None:
    assert baro.crc16(bytes.fromhex(v["data"])) == int(v["crc"], 16)


@pytest.mark.parametrize("v", vectors_of("cobs"))
def test_cobs_vectors(v: dict[str, str]) -> None:
    data, encoded = bytes.fromhex(v["data"]), bytes.fromhex(v["encoded"])
    assert baro.cobs_encode(data) == encoded
    assert baro.cobs_decode(encoded) == data


@pytest.mark.parametrize("v", vectors_of("frame"))
def test_frame_vectors(v: dict[str, str]) -> None:
    wire = bytes.fromhex(v["wire"])
    frame = frame_from_vector(v)
    decoder = baro.Decoder()
    assert decoder.feed(wire) == [frame]
    assert decoder.stats.frames == 1
    if v.get("decode_only") != "1":
        assert baro.encode(frame) == wire


@pytest.mark.parametrize("v", vectors_of("bad"))
def test_bad_frame_vectors(v: dict[str, str]) -> None:
    wire = bytes.fromhex(v["wire"])
    decoder = baro.Decoder()
    (bad,) = decoder.feed(wire)
    assert isinstance(bad, BadFrame)
    assert bad.reason == v["reason"]
    assert bad.size == len(wire) - 1
    assert decoder.stats.bad == {v["reason"]: 1}


def test_worked_example_in_protocol_md() -> None:
    frame = baro.SampleFrame(1, 1_000_000, 25767233, 2508)
    raw = baro.encode_raw(frame)
    assert raw[:14] == bytes.fromhex("01 02 01 00 40 42 0F 00 41 2D 89 01 CC 09")
    assert frame.pressure_pa == pytest.approx(100653.25390625)
    assert frame.temperature_c == pytest.approx(25.08)


# --- hypothesis ------------------------------------------------------------------------------

_FIELD_STRATEGY = {
    "B": st.integers(0, 0xFF),
    "H": st.integers(0, 0xFFFF),
    "h": st.integers(-0x8000, 0x7FFF),
    "I": st.integers(0, 0xFFFF_FFFF),
}


def _codes(fmt: str) -> Iterator[str]:
    count = ""
    for char in fmt.lstrip("<"):
        if char.isdigit():
            count += char
            continue
        yield from char * int(count or "1")
        count = ""


def frame_strategy(cls: type[baro.Frame]) -> st.SearchStrategy[baro.Frame]:
    fields = [_FIELD_STRATEGY["H"], _FIELD_STRATEGY["I"]]
    fields += [_FIELD_STRATEGY[code] for code in _codes(cls.PAYLOAD.format)]
    return st.tuples(*fields).map(lambda values: cls(*values))


any_frame = st.one_of(*(frame_strategy(cls) for cls in baro.FRAME_CLASSES))


@pytest.mark.parametrize("cls", baro.FRAME_CLASSES, ids=lambda cls: cls.__name__)
@given(data=st.data())
def test_round_trip_every_frame_type(cls: type[baro.Frame], data: st.DataObject) -> None:
    frame = data.draw(frame_strategy(cls))
    wire = baro.encode(frame)
    assert wire[-1] == 0 and 0 not in wire[:-1]
    assert len(wire) <= baro.MAX_ENCODED + 1
    assert baro.Decoder().feed(wire) == [frame]


@given(st.binary(max_size=600))
def test_cobs_round_trip(data: bytes) -> None:
    encoded = baro.cobs_encode(data)
    assert 0 not in encoded
    assert len(encoded) <= len(data) + len(data) // 254 + 1
    assert baro.cobs_decode(encoded) == data


@given(
    frames=st.lists(any_frame, max_size=12),
    cuts=st.lists(st.integers(min_value=0, max_value=800), max_size=30),
)
def test_any_chunking_gives_identical_output(frames: list[baro.Frame], cuts: list[int]) -> None:
    stream = baro.encode_all(frames)
    decoder = baro.Decoder()
    items: list[baro.DecodedItem] = []
    previous = 0
    for cut in [*sorted({min(c, len(stream)) for c in cuts}), len(stream)]:
        items += decoder.feed(stream[previous:cut])
        previous = cut
    assert items == frames
    assert decoder.buffered == 0


noise = st.one_of(
    st.binary(max_size=120),
    st.integers(60, 9000).map(lambda n: b"\x5a" * n),  # long runs without a delimiter
)


@given(
    parts=st.lists(st.one_of(any_frame.map(baro.encode), noise), max_size=10),
    cuts=st.lists(st.integers(min_value=0, max_value=20_000), max_size=40),
)
@settings(suppress_health_check=[HealthCheck.too_slow])
def test_any_chunking_of_a_hostile_stream_gives_identical_output(
    parts: list[bytes], cuts: list[int]
) -> None:
    """Good frames, noise and over-long runs: the records do not depend on read sizes."""
    stream = b"".join(parts)
    whole = baro.Decoder()
    expected = whole.feed(stream) + whole.flush()
    decoder = baro.Decoder()
    items: list[baro.DecodedItem] = []
    previous = 0
    for cut in [*sorted({min(c, len(stream)) for c in cuts}), len(stream)]:
        items += decoder.feed(stream[previous:cut])
        previous = cut
        assert decoder.buffered <= 2 * baro.MAX_ENCODED
    items += decoder.flush()
    assert items == expected
    assert decoder.stats == whole.stats


@given(
    frames=st.lists(any_frame, min_size=1, max_size=8),
    garbage=st.lists(st.binary(max_size=150), min_size=9, max_size=9),
)
@settings(suppress_health_check=[HealthCheck.too_slow])
def test_garbage_between_frames_is_counted_and_every_frame_survives(
    frames: list[baro.Frame], garbage: list[bytes]
) -> None:
    """Noise before, between and after frames: each frame still decodes, the noise is counted."""
    stream = bytearray()
    for frame, noise in zip(frames, garbage, strict=False):
        stream += noise + baro.encode(frame)
    tail = garbage[len(frames)]
    stream += tail + b"\x00"
    decoder = baro.Decoder()
    decoded, bad = frames_and_bad(decoder.feed(bytes(stream)))
    assert decoded == frames
    noisy_pieces = sum(1 for noise in [*garbage[: len(frames)], tail] if noise.strip(b"\x00"))
    assert len(bad) >= noisy_pieces
    assert decoder.stats.bytes_discarded == sum(b.size for b in bad)
    assert decoder.stats.frames == len(frames)


@given(
    frames=st.lists(any_frame, min_size=2, max_size=6),
    victim=st.integers(min_value=0),
    where=st.integers(min_value=0),
    noise=st.binary(min_size=1, max_size=80),
)
@example(
    frames=[baro.SampleFrame(0, 0, 0, 0), baro.IdentifyCommand(257, 257)],
    victim=1,
    where=0,
    noise=b"\x07",
)
def test_garbage_inside_a_frame_loses_only_that_frame(
    frames: list[baro.Frame], victim: int, where: int, noise: bytes
) -> None:
    victim %= len(frames)
    parts = [baro.encode(frame) for frame in frames]
    wire = parts[victim]
    cut = 1 + where % (len(wire) - 2)  # strictly inside the encoded bytes
    parts[victim] = wire[:cut] + noise + wire[cut:]
    decoded, bad = frames_and_bad(baro.Decoder().feed(b"".join(parts)))
    # Noise that repeats the frame's own first bytes can leave the whole frame intact at the
    # end of the damaged bytes (07 + 07 01 ... is garbage, then the frame): it must decode.
    intact = parts[victim].endswith(wire)
    assert decoded == (frames if intact else frames[:victim] + frames[victim + 1 :])
    assert bad  # the noise is counted


@given(frames=st.lists(any_frame, min_size=2, max_size=6), cut=st.integers(min_value=1))
def test_truncated_frame_then_next_frame(frames: list[baro.Frame], cut: int) -> None:
    """A frame cut short (a reset mid-frame) is counted; the frame after it still decodes."""
    first = baro.encode(frames[0])
    cut %= len(first) - 1
    stream = first[: cut + 1] + b"".join(baro.encode(f) for f in frames[1:])
    decoded, bad = frames_and_bad(baro.Decoder().feed(stream))
    assert decoded == frames[1:]
    assert len(bad) == 1


def test_a_crc_good_frame_of_an_unknown_type_is_never_split_into_garbage_and_a_frame() -> None:
    """A newer firmware's frame may end in bytes that are, by themselves, a valid frame."""
    inner = baro.encode_raw(baro.IdentifyCommand(0x0101, 0x01010101))
    assert 0 not in inner  # so its COBS form is one block: code byte, then the raw bytes
    # An outer frame of type 0x06 ending in "00 <inner without its CRC>", whose own CRC is the
    # inner frame's: two free payload bytes are searched until the CRCs agree.
    head = baro.HEADER.pack(baro.PROTOCOL_VERSION, 0x06, 7, 0)
    for free in range(1 << 16):
        body = head + free.to_bytes(2, "little") + b"\x00" + inner[:-2]
        if baro.CRC.pack(baro.crc16(body)) == inner[-2:]:
            break
    wire = baro.cobs_encode(body + inner[-2:]) + b"\x00"
    assert wire.endswith(baro.encode(baro.IdentifyCommand(0x0101, 0x01010101)))
    (bad,) = baro.Decoder().feed(wire)
    assert isinstance(bad, BadFrame) and (bad.reason, bad.size) == ("type", len(wire) - 1)


def test_flush_reports_a_frame_without_delimiter() -> None:
    decoder = baro.Decoder()
    wire = baro.encode(baro.IdentifyCommand(1, 2))
    assert decoder.feed(wire[:-1]) == []
    assert decoder.buffered == len(wire) - 1
    (bad,) = decoder.flush()
    assert isinstance(bad, BadFrame) and bad.reason == "truncated"
    assert decoder.buffered == 0


@pytest.mark.parametrize("run", [60, 61, 200, 4096, 20_000])
def test_oversized_run_is_counted_and_bounded(run: int) -> None:
    good = baro.encode(baro.SampleFrame(3, 4, 5, 6))
    decoder = baro.Decoder()
    items: list[baro.DecodedItem] = []
    for start in range(0, run, 1000):
        items += decoder.feed(b"\x55" * min(1000, run - start))
        assert decoder.buffered <= 2 * baro.MAX_ENCODED
    items += decoder.feed(b"\x00" + good)
    decoded, bad = frames_and_bad(items)
    assert decoded == [baro.SampleFrame(3, 4, 5, 6)]
    assert {b.reason for b in bad} == {"oversized"}
    assert sum(b.size for b in bad) == run
    # One record per run, or fixed 4096-byte blocks and the rest for a very long one.
    assert [b.size for b in bad[:-1]] == [4096] * (len(bad) - 1)
    assert len(bad) == 1 + max(0, run - baro.MAX_ENCODED) // 4096


def test_oversized_run_glued_to_a_frame_still_yields_the_frame() -> None:
    frame = baro.StatusFrame(1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 2)
    decoder = baro.Decoder()
    decoded, bad = frames_and_bad(decoder.feed(b"\x33" * 500 + baro.encode(frame)))
    assert decoded == [frame]
    assert [(b.reason, b.size) for b in bad] == [("oversized", 500)]


@pytest.mark.parametrize(
    "stream",
    [
        b"",
        b"\x00" * 50,
        b"\x01",
        b"\xff" * 59 + b"\x00",
        b"\xff" * 60 + b"\x00",
        b"\x02\x00\x02\x00",
        bytes(range(256)) * 3,
    ],
    ids=["empty", "zeros", "one", "max_run", "over_max", "tiny_frames", "ramp"],
)
def test_edge_streams_never_raise(stream: bytes) -> None:
    decoder = baro.Decoder()
    decoder.feed(stream)
    decoder.flush()
    assert decoder.buffered == 0


def test_short_fuzz_pass() -> None:
    """A few thousand random and mutated inputs; bench/codecs.py runs a million."""
    rng = random.Random(20240601)
    frames = [
        baro.encode(f)
        for f in (
            baro.HelloFrame(0, 1, 0, 1, 0, 0, 1, 0x58, 0x76, 25, 16, 2, 16, 1),
            baro.SampleFrame(5, 6, 25767233, 2508),
            baro.StatusFrame(1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 2),
            baro.AckFrame(1, 2, 0x81, 3, 0),
            baro.SetRateCommand(1, 2, 25),
        )
    ]
    decoder = baro.Decoder()
    total_bad = 0
    discarded = 0
    for _ in range(5000):
        choice = rng.random()
        if choice < 0.3:
            data = rng.randbytes(rng.randrange(0, 120))
        else:
            data = bytearray(b"".join(rng.choices(frames, k=rng.randrange(1, 4))))
            for _ in range(rng.randrange(1, 4)):
                pos = rng.randrange(len(data))
                op = rng.randrange(3)
                if op == 0:
                    data[pos] = rng.randrange(256)
                elif op == 1:
                    del data[pos]
                else:
                    data[pos:pos] = rng.randbytes(rng.randrange(1, 8))
            data = bytes(data)
        for item in decoder.feed(data):
            if isinstance(item, BadFrame):
                total_bad += 1
                discarded += item.size
        assert decoder.buffered <= 2 * baro.MAX_ENCODED
    assert sum(decoder.stats.bad.values()) == total_bad
    assert decoder.stats.bytes_discarded == discarded
    assert decoder.stats.frames > 1000


# --- encoders and helpers ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "frame",
    [
        baro.SampleFrame(65536, 0, 0, 0),
        baro.SampleFrame(0, 1 << 32, 0, 0),
        baro.SampleFrame(0, 0, -1, 0),
        baro.SampleFrame(0, 0, 0, 40000),
        baro.SetRateCommand(0, 0, 256),
        baro.AckFrame(0, 0, 0, -1, 0),
    ],
    ids=["seq", "time", "pressure", "temperature", "rate", "ack_seq"],
)
def test_encoder_refuses_values_the_wire_cannot_carry(frame: baro.Frame) -> None:
    with pytest.raises(EncodeError):
        baro.encode(frame)


def test_encoder_refuses_non_frames() -> None:
    with pytest.raises(EncodeError):
        baro.encode(PressureSample(0, 1.0))  # type: ignore[arg-type]


def test_command_helpers_lead_with_a_flushing_delimiter() -> None:
    decoder = baro.Decoder()
    stream = baro.set_rate(50, seq=1) + baro.set_oversampling(4, 1, 0, seq=2) + baro.identify(3)
    assert stream[0] == 0
    assert decoder.feed(stream) == [
        baro.SetRateCommand(1, 0, 50),
        baro.SetOversamplingCommand(2, 0, 4, 1, 0),
        baro.IdentifyCommand(3, 0),
    ]


def test_commands_are_numbered_zero_at_time_zero_unless_told() -> None:
    stream = baro.set_rate(10) + baro.set_oversampling(2, 1, 4) + baro.identify()
    assert baro.Decoder().feed(stream) == [
        baro.SetRateCommand(0, 0, 10),
        baro.SetOversamplingCommand(0, 0, 2, 1, 4),
        baro.IdentifyCommand(0, 0),
    ]


def test_flush_counts_lone_delimiters_into_the_truncated_frame() -> None:
    decoder = baro.Decoder()
    partial = baro.encode(baro.IdentifyCommand(1, 2))[:-3]
    assert decoder.feed(b"\x00\x00" + partial) == []
    (truncated,) = decoder.flush()
    assert truncated.reason == "truncated" and truncated.size == len(partial)
    assert truncated.wire_size == len(partial) + 2 and decoder.idle == 0


def test_a_frame_that_ends_an_oversized_run_without_its_delimiter_is_lost_on_flush() -> None:
    """With no delimiter after it, a whole frame at the end of line noise is no frame yet."""
    frame = baro.encode(baro.IdentifyCommand(1, 2))[:-1]  # without its delimiter
    stream = b"\x55" * (baro.MAX_ENCODED + 10) + frame
    decoder = baro.Decoder()
    out = decoder.feed(stream) + decoder.flush()
    assert all(isinstance(m, BadFrame) and m.reason == "oversized" for m in out)
    assert sum(m.wire_size for m in out) == len(stream)


def test_every_item_of_a_hostile_stream_has_its_wire_size_and_sample() -> None:
    """A lone delimiter, noise glued to a frame, over-long runs with and without a frame at
    their end, two lone delimiters before a corrupted frame, a cut frame: each item's wire
    size counts its delimiter and the lone ones before it, and all of them add up to the
    stream; each discarded run keeps its first bytes as its sample."""
    frames = [baro.IdentifyCommand(i, 10 * i) for i in range(1, 6)]
    wire = [baro.encode(frame) for frame in frames]  # 12 bytes each, the delimiter included
    corrupted = bytearray(wire[4])
    corrupted[-3] ^= 0x40
    long_run = baro.MAX_ENCODED + 10
    stream = b"".join(
        (
            b"\x00" + wire[0],
            b"\x55\x55" + wire[1],
            b"\x01" * long_run + wire[2],
            b"\x02" * (baro.MAX_ENCODED + 5) + b"\x00",
            b"\x00\x00" + bytes(corrupted),
            wire[3][:-2],
        )
    )
    decoder = baro.Decoder()
    out = decoder.feed(stream) + decoder.flush()
    assert [m for m in out if not isinstance(m, BadFrame)] == frames[:3]
    items = [
        (getattr(m, "reason", "frame"), getattr(m, "sample", b"")[:2], m.wire_size) for m in out
    ]
    assert items == [
        ("frame", b"", 13),
        ("garbage", b"\x55\x55", 2),
        ("frame", b"", 12),
        ("oversized", b"\x01\x01", long_run),
        ("frame", b"", 12),
        ("oversized", b"\x02\x02", baro.MAX_ENCODED + 5 + 1),
        ("crc", bytes(corrupted[:2]), 11 + 1 + 2),
        ("truncated", wire[3][:2], 10),
    ]
    assert sum(m.wire_size for m in out) == len(stream) and decoder.idle == 0
    assert decoder.stats.frames == 3


def test_to_pressure_sample() -> None:
    frame = baro.SampleFrame(7, 123456, 25767233, -1234)
    sample = baro.to_pressure_sample(frame, t_ns=42)
    assert sample == PressureSample(
        t_ns=42, pressure_pa=25767233 / 256, temperature_c=-12.34, seq=7, device_time_us=123456
    )


def test_from_values_rounds_to_wire_resolution() -> None:
    frame = baro.SampleFrame.from_values(1, 2, 101325.126, 21.456)
    assert (frame.seq, frame.time_us) == (1, 2)
    assert frame.pressure_q24_8 == round(101325.126 * 256)
    assert frame.temperature_centi_c == 2146


@pytest.mark.parametrize(
    ("previous", "current", "gap"),
    [(0, 1, 0), (5, 9, 3), (65535, 0, 0), (65530, 2, 7), (3, 3, 65535)],
)
def test_seq_gap(previous: int, current: int, gap: int) -> None:
    assert baro.seq_gap(previous, current) == gap


def test_time_delta_across_wrap() -> None:
    assert baro.time_delta_us(0xFFFF_FF00, 0x100) == 0x200
    assert baro.time_delta_us(1000, 41000) == 40000


def test_status_counters_by_name() -> None:
    status = baro.StatusFrame(0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 2)
    assert status.counters() == {
        "frames_sent": 1,
        "frames_dropped": 2,
        "i2c_errors": 3,
        "samples_missed": 4,
        "rx_bytes": 5,
        "rx_frames": 6,
        "rx_crc_errors": 7,
        "rx_bad_frames": 8,
        "rx_overflows": 9,
    }


def test_payload_fields_follow_the_struct_layout() -> None:
    for cls in baro.FRAME_CLASSES:
        assert len(baro.PAYLOAD_FIELDS[cls]) == len(list(_codes(cls.PAYLOAD.format)))
        assert struct.calcsize(cls.PAYLOAD.format) <= baro.MAX_PAYLOAD
