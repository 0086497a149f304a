"""Codec bench: decode throughput of each device codec, and a fuzz pass that must raise nothing.

    .venv/bin/python bench/codecs.py [--fuzz N] [--frames N] [--only NAME] [--seed S]

Prints a throughput table (MB/s, frames/s, multiple of the device's fastest line rate), then
fuzzes every decoder with N inputs (default 1,000,000): random bytes, and windows of valid
streams with bit flips, insertions, deletions, truncations, duplicated slices and tampered
LEN/COUNT bytes, each fed in random chunks; a sample is also fed whole and must decode to the
same messages, and the wire sizes of the items decoded must add up to the bytes fed. Exits
non-zero if any input raised, chunking changed the output, or the wire sizes did not add up.

The codecs are a registry so each codec's author adds one line: ``CODECS[name] =
(make_stream, make_decoder)`` where ``make_stream(n_frames) -> bytes`` is a deterministic valid
stream and ``make_decoder()`` returns an object with ``feed(bytes) -> list`` and ``stats``
(``flush()`` is used when present). tests/test_codec_fuzz.py runs a short pass of the same fuzz.
"""

from __future__ import annotations

import argparse
import math
import random
import sys
import time
import traceback
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from baromap.messages import BeamFlag
from baromap.protocols import baro, lms200, p2os

StreamMaker = Callable[[int], bytes]
DecoderMaker = Callable[[], Any]

# ---------------------------------------------------------------------------------------------
# Streams
# ---------------------------------------------------------------------------------------------


def _room_ranges(rng: random.Random, beams: int, field_deg: float) -> np.ndarray:
    """Ranges (m) from a point inside a rectangular room: walls, and far beams through doors."""
    half_w, half_h = rng.uniform(1.5, 12.0), rng.uniform(1.5, 12.0)
    x, y = rng.uniform(-half_w, half_w) * 0.8, rng.uniform(-half_h, half_h) * 0.8
    heading = rng.uniform(-math.pi, math.pi)
    angles = heading + np.radians(np.linspace(-field_deg / 2, field_deg / 2, beams))
    c, s = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (half_w - x) / c, (-half_w - x) / c)
        ty = np.where(s > 0, (half_h - y) / s, (-half_h - y) / s)
    ranges = np.minimum(np.abs(tx), np.abs(ty)) + np.array(
        [rng.gauss(0, 0.01) for _ in range(beams)]
    )
    door = rng.randrange(beams)
    ranges[door : door + rng.randrange(1, 8)] = 30.0  # open door: nothing within 8 m
    return ranges


def lms_stream(n_frames: int, seed: int = 1) -> bytes:
    """Continuous output at 0.5 deg (361-value B0 scans, mm) with an occasional ACK + reply,
    power-on telegram or subrange (B7) / mean subrange (BF) scan of a 32 m mode."""
    rng = random.Random(seed)
    scans = []
    for _ in range(16):
        flags = np.zeros(361, dtype=np.uint16)
        flags[rng.randrange(361)] = int(BeamFlag.DAZZLE)
        words = lms200.range_words(_room_ranges(rng, 361, 180.0), flags, units="mm")
        scans.append(lms200.encode_scan(words, units="mm"))
    subrange = lms200.range_words(_room_ranges(rng, 40, 40.0), units="mm", bits=15)
    replies = [
        bytes((lms200.ACK,)) + lms200.mode_reply(),
        bytes((lms200.ACK,)) + lms200.status_reply(lms200.StatusReport()),
        bytes((lms200.ACK,)) + lms200.variant_reply(lms200.VariantReply(True, 180, 50)),
        bytes((lms200.ACK,)) + lms200.reset_reply(),
        lms200.power_on_telegram("V02.10 LMS ready"),
        lms200.encode_scan(subrange, units="mm", sample_size=5, subrange=(100, 139)),
        lms200.encode_scan(subrange, units="mm", subrange=(100, 139), extra=b"\x07"),
    ]
    parts = [
        rng.choice(replies) if rng.random() < 0.05 else rng.choice(scans) for _ in range(n_frames)
    ]
    return b"".join(parts)


def p2os_stream(n_frames: int, seed: int = 2) -> bytes:
    """Standard SIPs of a P3-AT driving about (15-bit counters wrapping), some with sonars."""
    rng = random.Random(seed)
    x = y = theta = 0
    parts = [
        p2os.encode_sync_echo(0),
        p2os.encode_sync_echo(1),
        p2os.Sync2Info("Pioneer", "Pioneer", "p3at").encode(),
        p2os.encode_config({"robot_type": "Pioneer", "subtype": "p3at", "serial_number": "42"}),
    ]
    for i in range(max(n_frames - len(parts), 0)):
        v = rng.randint(-1200, 1200)
        theta = (theta + rng.randint(-40, 40)) % 4096
        step = v * 0.1 / 0.465
        x = int(x + step * math.cos(theta * math.tau / 4096)) & 0x7FFF
        y = int(y + step * math.sin(theta * math.tau / 4096)) & 0x7FFF
        sonars = tuple((rng.randrange(16), rng.randrange(5000)) for _ in range(rng.randrange(9)))
        sip = p2os.StandardSip(
            moving=v != 0,
            x=x,
            y=y,
            theta=theta,
            left_vel=v - 20,
            right_vel=v + 20,
            battery_dv=128,
            stall_bumpers=0,
            control=theta,
            flags=1,
            compass=0,
            sonars=sonars,
            timer=i & 0xFFFF,
            analog=0,
            digital_in=0xFF,
            digital_out=0,
            battery_x10=128,
        )
        parts.append(sip.encode())
    return b"".join(parts[:n_frames])


def baro_stream(n_frames: int, seed: int = 3) -> bytes:
    """The barometer board at 50 Hz: HELLO, SAMPLEs, a STATUS a second, the odd ACK/ERROR."""
    rng = random.Random(seed)
    t_us, p_q8 = 0, 101325 * 256
    parts = [
        b"\x00",
        baro.encode(baro.HelloFrame(0, 0, 0, 1, 0, 0, 1, 0x58, 0x76, 50, 16, 2, 16, 1)),
    ]
    counts = Counter[int]()
    for _ in range(max(n_frames - 1, 0)):
        t_us = (t_us + 20_000) & 0xFFFF_FFFF
        p_q8 += rng.randint(-80, 80)
        roll = rng.random()
        if roll < 0.02:
            frame: baro.Frame = baro.StatusFrame(
                counts[3], t_us, *(rng.randrange(1 << 20) for _ in range(9)), 2
            )
        elif roll < 0.03:
            frame = baro.AckFrame(counts[5], t_us, 0x81, rng.randrange(1 << 16), 0)
        elif roll < 0.032:
            frame = baro.ErrorFrame(counts[4], t_us, 3, 0x20, rng.randrange(1, 4))
        else:
            frame = baro.SampleFrame(counts[2], t_us, p_q8, 2200 + rng.randint(-5, 5))
        counts[frame.TYPE] = (counts[frame.TYPE] + 1) & 0xFFFF
        parts.append(baro.encode(frame))
    return b"".join(parts[: n_frames + 1])


#: name -> (make_stream(n_frames) -> bytes, make_decoder()).
CODECS: dict[str, tuple[StreamMaker, DecoderMaker]] = {
    "lms200": (lms_stream, lms200.Decoder),
    "p2os": (p2os_stream, p2os.Decoder),
    "baro": (baro_stream, baro.Decoder),
}

#: Fastest line rate each device runs at (baud, 10 bits per byte on an 8N1 line).
LINE_BAUD: dict[str, int] = {"lms200": 500_000, "p2os": 115_200, "baro": 115_200}
#: Decode throughput the brief requires: 20 x the LMS200's 500 kbaud (as 500000/8 B/s).
LMS_TARGET_MBPS = 20 * 500_000 / 8 / 1e6

# ---------------------------------------------------------------------------------------------
# Throughput
# ---------------------------------------------------------------------------------------------


@dataclass
class Throughput:
    name: str
    megabytes: float
    seconds: float
    frames: int
    bad: int

    @property
    def mb_per_s(self) -> float:
        return self.megabytes / self.seconds

    @property
    def frames_per_s(self) -> float:
        return self.frames / self.seconds


def measure(name: str, n_frames: int, chunk: int = 4096, repeats: int = 3) -> Throughput:
    """Best of ``repeats`` decodes of an ``n_frames`` stream fed in ``chunk``-byte reads."""
    make_stream, make_decoder = CODECS[name]
    stream = make_stream(n_frames)
    best: Throughput | None = None
    for _ in range(repeats):
        decoder = make_decoder()
        frames = 0
        start = time.perf_counter()
        for offset in range(0, len(stream), chunk):
            frames += len(decoder.feed(stream[offset : offset + chunk]))
        elapsed = time.perf_counter() - start
        bad = sum(decoder.stats.bad.values())
        result = Throughput(name, len(stream) / 1e6, elapsed, frames - bad, bad)
        if best is None or result.seconds < best.seconds:
            best = result
    assert best is not None
    return best


# ---------------------------------------------------------------------------------------------
# Fuzz
# ---------------------------------------------------------------------------------------------


@dataclass
class FuzzResult:
    name: str
    inputs: int = 0
    exceptions: int = 0
    mismatches: int = 0
    miscounted: int = 0  # inputs whose items' wire sizes do not add up to the bytes fed
    messages: int = 0
    bad: Counter[str] = field(default_factory=Counter)
    seconds: float = 0.0
    first_errors: list[str] = field(default_factory=list)


def _mutate(data: bytearray, rng: random.Random, sync_byte: int) -> bytearray:
    for _ in range(rng.randint(0, 4)):
        if not data:
            break
        op = rng.randrange(7)
        j = rng.randrange(len(data))
        if op == 0:
            data[j] ^= 1 << rng.randrange(8)
        elif op == 1:
            data[j:j] = rng.randbytes(rng.randint(1, 4))
        elif op == 2:
            del data[j : j + rng.randint(1, 4)]
        elif op == 3:
            del data[j:]
        elif op == 4:
            data[j:j] = data[j : j + rng.randint(1, 16)]
        elif op == 5:
            data[j] = rng.choice((0x00, 0xFF, sync_byte))
        else:  # tamper with a header's LEN/COUNT bytes
            heads = [i for i in range(len(data) - 3) if data[i] == sync_byte]
            if heads:
                data[rng.choice(heads) + rng.choice((2, 3))] = rng.randrange(256)
    return data


def _chunks(data: bytes, rng: random.Random) -> list[bytes]:
    if len(data) < 2 or rng.random() < 0.2:
        return [data]
    if rng.random() < 0.2:
        return [data[i : i + 1] for i in range(len(data))]
    cuts = sorted(rng.sample(range(1, len(data)), min(len(data) - 1, rng.randint(1, 6))))
    return [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True)]


def _decode_all(make_decoder: DecoderMaker, chunks: list[bytes]) -> tuple[list[Any], Any]:
    decoder = make_decoder()
    out: list[Any] = []
    for piece in chunks:
        out += decoder.feed(piece)
    flush = getattr(decoder, "flush", None)
    if flush is not None:
        out += flush()
    return out, decoder


def fuzz_codec(
    name: str, n_inputs: int, seed: int = 0, compare_every: int = 16, progress: bool = False
) -> FuzzResult:
    """Feed ``n_inputs`` hostile inputs to fresh decoders; count exceptions and mismatches."""
    make_stream, make_decoder = CODECS[name]
    base = make_stream(64)
    sync_byte = base[0]
    # Windows mostly short (fast), sometimes long enough to hold two of the codec's frames.
    long_window = max(300, 2 * len(base) // 64)
    rng = random.Random(seed)
    result = FuzzResult(name)
    start = time.perf_counter()
    steps: Any = range(n_inputs)
    if progress:
        from tqdm import tqdm

        steps = tqdm(steps, desc=f"fuzz {name}", unit="input", mininterval=1.0)
    for i in steps:
        if rng.random() < 0.3:
            data = rng.randbytes(rng.randint(1, 300))
        else:
            size = rng.randint(1, 300) if rng.random() < 0.7 else rng.randint(1, long_window)
            offset = rng.randrange(len(base))
            data = bytes(_mutate(bytearray(base[offset : offset + size]), rng, sync_byte))
        chunks = _chunks(data, rng)
        result.inputs += 1
        try:
            out, decoder = _decode_all(make_decoder, chunks)
            result.messages += len(out)
            result.bad.update(decoder.stats.bad)
            counted = sum(item.wire_size for item in out) + getattr(decoder, "idle", 0)
            if counted != len(data):
                result.miscounted += 1
                if len(result.first_errors) < 3:
                    result.first_errors.append(
                        f"wire sizes add up to {counted} of {len(data)} bytes for {data.hex()}"
                    )
            if compare_every and i % compare_every == 0:
                whole, _ = _decode_all(make_decoder, [data])
                if whole != out:
                    result.mismatches += 1
                    if len(result.first_errors) < 3:
                        result.first_errors.append(f"chunking changed output for {data.hex()}")
        except Exception:
            result.exceptions += 1
            if len(result.first_errors) < 3:
                result.first_errors.append(f"input {data.hex()}\n{traceback.format_exc()}")
    result.seconds = time.perf_counter() - start
    return result


# ---------------------------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fuzz", type=int, default=1_000_000, help="fuzz inputs per decoder")
    parser.add_argument("--frames", type=int, default=0, help="frames per throughput stream")
    parser.add_argument("--only", choices=sorted(CODECS), action="append", help="codec(s) to run")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    names = args.only or list(CODECS)
    default_frames = {"lms200": 2000, "p2os": 50000}

    print("decode throughput, best of 3 (x line rate: fastest baud, 10 bits per byte)")
    print(
        f"{'codec':8} {'read':>5} {'MB':>6} {'MB/s':>7} {'frames/s':>9} {'x line rate':>11} "
        f"{'bad':>4}"
    )
    for name in names:
        for chunk in (4096, 64):
            t = measure(name, args.frames or default_frames.get(name, 20000), chunk=chunk)
            baud = LINE_BAUD.get(name)
            multiple = f"{t.mb_per_s * 1e6 / (baud / 10):11.0f}" if baud else f"{'-':>11}"
            print(
                f"{name:8} {chunk:5d} {t.megabytes:6.2f} {t.mb_per_s:7.2f} "
                f"{t.frames_per_s:9.0f} {multiple} {t.bad:4d}"
            )
            if name == "lms200":
                verdict = "meets" if t.mb_per_s >= LMS_TARGET_MBPS else "MISSES"
                print(f"{'':15}{verdict} the {LMS_TARGET_MBPS:.2f} MB/s target (20 x 500 kbaud)")

    failed = False
    if args.fuzz > 0:
        print(f"\nfuzz ({args.fuzz} inputs per decoder, random chunking, seed {args.seed})")
        print(
            f"{'codec':8} {'inputs':>9} {'exceptions':>10} {'mismatch':>9} {'wire':>5} "
            f"{'messages':>10} {'s':>7}  bad frames by reason"
        )
        for name in names:
            r = fuzz_codec(name, args.fuzz, args.seed, progress=sys.stderr.isatty())
            reasons = ", ".join(f"{k}={v}" for k, v in sorted(r.bad.items()))
            print(
                f"{name:8} {r.inputs:9d} {r.exceptions:10d} {r.mismatches:9d} {r.miscounted:5d} "
                f"{r.messages:10d} {r.seconds:7.1f}  {reasons}"
            )
            for err in r.first_errors:
                print(err, file=sys.stderr)
            failed |= r.exceptions > 0 or r.mismatches > 0 or r.miscounted > 0
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
