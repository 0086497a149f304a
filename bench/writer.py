"""What one ``RecordingWriter.write`` costs, per message type, hot and cold.

    .venv/bin/python bench/writer.py [--rounds 400] [--sleep-ms 13] [--beams 181]

The daemon's recorder wakes for each message and writes it, 13 ms apart for scans at 75 Hz:
its caches are cold then, and a write costs several times what it costs in a loop. Each
round calls every case once, in a shuffled order, with ``--sleep-ms`` of sleep before each
call (cold); then the same cases back to back (hot). Printed per case: the thread's CPU time
of one call (``CLOCK_THREAD_CPUTIME_ID``), p50 / mean / p90 in microseconds. The writer is
the library's, on a temporary file, zstd, no fsync (the daemon fsyncs on another thread);
its chunk flushes (once a second of wall time) land in whichever call was due, as they do in
the daemon.

A scan's encoding and log are also timed alone, the SDK's way and :mod:`foxglove_wire`'s,
in the same rounds (an A/B in one process: the cold figures move by 2-3x between runs).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import random
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import structlog

from baromap import messages
from baromap.recording import RecordingWriter, foxglove_wire
from baromap.recording.frames import LaserMount


def scans(beams: int, count: int, seed: int) -> list[messages.LaserScan]:
    """Scans like the LMS200's: ranges 0.3-8 m in float32, a few error beams (NaN, flagged)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        ranges = rng.uniform(0.3, 8.0, beams).astype(np.float32)
        flags = np.zeros(beams, np.uint16)
        bad = rng.random(beams) < 0.03
        ranges[bad] = np.nan
        flags[bad] = messages.BeamFlag.DAZZLE
        out.append(
            messages.LaserScan(
                t_ns=1_764_000_000_000_000_000 + i * 13_333_333,
                angle_min_rad=-np.pi / 2,
                angle_increment_rad=np.pi / (beams - 1),
                range_max_m=8.183,
                ranges_m=ranges,
                flags=flags,
                scan_index=i,
            )
        )
    return out


def cases(writer: RecordingWriter, beams: int, rounds: int) -> dict[str, Callable[[int], None]]:
    t0 = 1_764_000_000_000_000_000
    scan_list = scans(beams, rounds * 2 + 2, seed=1)
    state = messages.FloorState(
        t0, messages.FloorPhase.SETTLED, 0, "ground", 0.0, 0.0, 101_325.0, t0, 1
    )
    health = messages.DeviceHealth(
        t0,
        "laser",
        messages.DeviceState.UP,
        "/dev/ttyUSB0",
        "streaming",
        {"scans": 1000, "bad_frames": 0, "reads": 4000, "bytes": 700_000},
    )
    step = 1_000_000

    def scan(i: int) -> None:
        writer.write(scan_list[i])

    def odom(i: int) -> None:
        writer.write(
            messages.Odometry(t0 + i * step, 1.0 + i * 1e-3, 2.0, 0.3, 0.2, 0.01, 100 + i, 50, 7)
        )

    def baro(i: int) -> None:
        writer.write(messages.PressureSample(t0 + i * step, 101_325.0 + i % 7, 21.5, i, i * 20_000))

    def floor_state(i: int) -> None:
        writer.write(dataclasses.replace(state, t_ns=t0 + i * step))

    def diagnostics(i: int) -> None:
        writer.write(dataclasses.replace(health, t_ns=t0 + i * step))

    out: dict[str, Callable[[int], None]] = {
        "/scan": scan,
        "/odom + /tf": odom,
        "/baro": baro,
        "/floor/state": floor_state,
        "/diagnostics": diagnostics,
    }
    out.update(scan_paths(writer, scan_list))
    return out


def scan_paths(
    writer: RecordingWriter, scan_list: list[messages.LaserScan]
) -> dict[str, Callable[[int], None]]:
    """A scan's encoding and log alone, two ways, into the same file on channels of their own:
    the SDK's message objects from two lists on a ``LaserScanChannel``, and
    :mod:`baromap.recording.foxglove_wire`'s bytes on a plain channel (what the writer does)."""
    import foxglove
    from foxglove.channels import LaserScanChannel
    from foxglove.messages import LaserScan, Pose, Quaternion, Timestamp, Vector3

    pose = Pose(position=Vector3(x=0, y=0, z=0), orientation=Quaternion(x=0, y=0, z=0, w=1))
    typed = LaserScanChannel("/bench/sdk", context=writer.context)

    def sdk(i: int) -> None:
        s = scan_list[i]
        sec, nsec = divmod(s.t_ns, 1_000_000_000)
        typed.log(
            LaserScan(
                timestamp=Timestamp(sec=sec, nsec=nsec),
                frame_id="laser",
                pose=pose,
                start_angle=s.angle_min_rad,
                end_angle=s.angle_max_rad,
                ranges=s.ranges_m.tolist(),
                intensities=s.flags.tolist(),
            ),
            log_time=s.t_ns,
        )

    def nothing(i: int) -> None:
        pass

    encoder = foxglove_wire.LaserScanEncoder("laser")
    plain = foxglove.Channel(
        "/bench/wire",
        schema=foxglove_wire.laser_scan_schema(),
        message_encoding="protobuf",
        context=writer.context,
    )

    def wire(i: int) -> None:
        s = scan_list[i]
        plain.log(encoder.encode(s), log_time=s.t_ns)

    return {
        "scan alone: SDK objects": sdk,
        "scan alone: foxglove_wire": wire,
        "nothing (timing floor)": nothing,
    }


def run(
    all_cases: dict[str, Callable[[int], None]], rounds: int, sleep_s: float, seed: int
) -> dict[str, list[int]]:
    rng = random.Random(seed)
    names = list(all_cases)
    cpu: dict[str, list[int]] = {name: [] for name in names}
    clock = time.thread_time_ns
    for i in range(rounds):
        rng.shuffle(names)
        for name in names:
            if sleep_s:
                time.sleep(sleep_s)
            fn = all_cases[name]
            t = clock()
            fn(i)
            cpu[name].append(clock() - t)
    return cpu


def report(title: str, cpu: dict[str, list[int]]) -> None:
    print(title)
    print(f"  {'case':28s} {'p50':>8s} {'mean':>8s} {'p90':>8s}  (us of thread CPU a call)")
    for name, values in cpu.items():
        v = sorted(values[len(values) // 10 :])  # the first tenth warms up
        p90 = v[int(0.9 * (len(v) - 1))]
        print(
            f"  {name:28s} {statistics.median(v) / 1e3:8.1f} {statistics.fmean(v) / 1e3:8.1f}"
            f" {p90 / 1e3:8.1f}"
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=400)
    parser.add_argument("--sleep-ms", type=float, default=13.0)
    parser.add_argument("--beams", type=int, default=181)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--compression", default="zstd", choices=("zstd", "lz4", "none"))
    args = parser.parse_args()
    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.WARNING))
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f}, {args.compression}")
    with tempfile.TemporaryDirectory() as tmp:
        mount = LaserMount(0.1, 0.0, 0.0)
        for title, sleep_s in (
            (f"cold ({args.sleep_ms:g} ms sleep before each call)", args.sleep_ms / 1e3),
            ("hot (back to back)", 0.0),
        ):
            with RecordingWriter(
                Path(tmp) / f"{sleep_s}.mcap",
                robot="bench",
                laser_mount=mount,
                fsync=False,
                compression=args.compression,
            ) as writer:
                cpu = run(cases(writer, args.beams, args.rounds), args.rounds, sleep_s, args.seed)
            report(title, cpu)
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
