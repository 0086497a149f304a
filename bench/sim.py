"""Simulator bench: how fast the simulated world runs, and how fast the laser twin streams.

    .venv/bin/python bench/sim.py [--minutes 46] [--floors 6] [--seed 0] [--twin-seconds 3]

Prints the time to build the building, to make a pressure_run (the barometer part of a run),
to ray cast every scan of the run, and to write the whole run to MCAP with ``sim record``
(target: a 46-minute six-floor run in under 60 s on one core), plus the file's size. Then the
LMS200 twin's scan rate in continuous mode for several variants and line speeds, from its
truth log, beside the real sensor's limit (the line, or the mirror: 75 Hz, interlaced 2 or 4
turns at 0.5 or 0.25 deg); a loaded machine can only make it slower.
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

import numpy as np
import structlog

from baromap.protocols import lms200
from baromap.sim.building import make_building
from baromap.sim.laser import LaserConfig, cast
from baromap.sim.record import record_run, scan_floors
from baromap.sim.scenario import make_scenario, pressure_run
from baromap.sim.twins import Lms200Twin, SimClock
from baromap.sim.twins.lms200 import INTERLACE, MIRROR_HZ


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=46.0)
    parser.add_argument("--floors", type=int, default=6)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--twin-seconds", type=float, default=3.0)
    args = parser.parse_args()
    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.WARNING))

    t = time.perf_counter()
    building = make_building.__wrapped__(args.seed, args.floors)
    segments = sum(len(f.walls_m) for f in building.floors)
    print(f"make_building: {time.perf_counter() - t:.3f} s ({segments} wall segments)")

    t = time.perf_counter()
    run = pressure_run(args.seed + 1000, floors=args.floors, minutes=args.minutes)
    print(
        f"pressure_run (new seed, building included): {time.perf_counter() - t:.3f} s "
        f"for {len(run.t_ns)} samples, {len(run.transitions)} transitions"
    )
    t = time.perf_counter()
    pressure_run(args.seed + 1000, floors=args.floors, minutes=args.minutes, rate_hz=25.0)
    print(f"pressure_run (scenario cached): {time.perf_counter() - t:.3f} s")

    sc = make_scenario(args.seed, floors=args.floors, minutes=args.minutes)
    cfg = LaserConfig()
    times = np.arange(0.0, sc.duration_s, 1.0 / cfg.scan_rate_hz)
    truth = sc.truth(times)
    floors = scan_floors(truth, sc)
    t = time.perf_counter()
    for f in np.unique(floors):
        idx = np.nonzero(floors == f)[0]
        for j in range(0, len(idx), 200):
            s = idx[j : j + 200]
            cast(
                sc.building.floors[int(f)].walls_m,
                np.column_stack([truth.x[s], truth.y[s]]),
                truth.theta[s],
                cfg.angles_rad,
                cfg.range_max_m,
            )
    cast_s = time.perf_counter() - t
    print(
        f"ray casting: {len(times)} scans x {cfg.beams} beams in {cast_s:.2f} s "
        f"({len(times) / cast_s:.0f} scans/s)"
    )

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "run.mcap"
        summary = record_run(
            path, seed=args.seed, floors=args.floors, minutes=args.minutes, progress=False
        )
        size = path.stat().st_size
    total = sum(summary.counts.values())
    print(
        f"sim record: {args.minutes:.0f}-minute {args.floors}-floor run in {summary.wall_s:.1f} s "
        f"({summary.simulated_s / summary.wall_s:.0f}x real time; target < 60 s), "
        f"{total} messages, {size / 1e6:.1f} MB"
    )
    twin_rates(sc, args.twin_seconds)
    return 0


def twin_rates(sc: object, seconds: float) -> None:
    """The LMS200 twin streaming to a host that reads everything, per variant and baud."""
    import serial

    print("LMS200 twin, continuous mode (scans/s from its truth log; limit = line or mirror)")
    for baud, angle, res in (
        (38400, 180, 100),
        (500000, 180, 100),
        (500000, 180, 50),
        (500000, 100, 25),
    ):
        with Lms200Twin(SimClock(sc)) as twin:  # type: ignore[arg-type]
            twin.variant = (angle, res)
            twin.port.set_baud(baud)
            twin.mode = lms200.Mode.CONTINUOUS
            with serial.serial_for_url(twin.path, baudrate=baud, timeout=0.05) as port:
                deadline = time.monotonic() + seconds
                while time.monotonic() < deadline:
                    port.read(8192)
            taken = [t.t_mono_ns / 1e9 for t in twin.truth.records()]
        beams = angle * 100 // res + 1
        line_hz = baud / 10 / (10 + 2 * beams)
        mirror_hz = MIRROR_HZ / INTERLACE[res]
        rate = (len(taken) - 1) / (taken[-1] - taken[0]) if len(taken) > 1 else 0.0
        print(
            f"  {baud:>6} baud {angle} deg / {res / 100:.2f} deg: {rate:5.1f} scans/s "
            f"(limit {min(line_hz, mirror_hz):5.1f}: line {line_hz:.1f}, mirror {mirror_hz:.2f})"
        )


if __name__ == "__main__":
    raise SystemExit(main())
