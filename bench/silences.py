"""Post-run maps of a run with a device silent for a while, as the daemon's reconnects leave it.

    .venv/bin/python bench/silences.py [--seed N] [--keep DIR]

The simulated 46-minute run (seed 0 by default) is recorded once, then copied with the
laser's scans left out for 20, 60 or 120 s from 600, 1500 or 2200 s, with the odometry
left out for 60 s from 600 and from 1500 s, and with the base power-cycled (5 s from 1500 s,
60 s from 600 s) and counting from zero after it, joined at its last pose as baromapd records
it or left zeroed as another recorder would (baromap.evaluation.silences). Each copy is built
with build-maps and scored against the simulator's truth under one rigid transform: over every
scan on a floor, and over the scans the odometry spoke for (a scan without odometry is not
mapped; its pose is drawn across the gap). Figures, not a pass or fail: no bar is set on
silences; docs/results.md ("Maps: the simulated building") keeps what they print.
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

import structlog

from baromap.evaluation.silences import score_silence, without
from baromap.sim.record import record_run

CASES = [
    ("/scan", start, seconds, "kept") for start in (600, 1500, 2200) for seconds in (20, 60, 120)
]
CASES += [("/odom", 600, 60, "kept"), ("/odom", 1500, 60, "kept")]
# the base power-cycled: its counters from zero, joined by baromapd or left to the mapping
CASES += [("/odom", 1500, 5, "joined"), ("/odom", 600, 60, "joined")]
CASES += [("/odom", 1500, 5, "zeroed"), ("/odom", 600, 60, "zeroed")]


def bench(seed: int, work: Path) -> None:
    run = work / "run.mcap"
    t0 = time.perf_counter()
    record_run(run, seed=seed, progress=False)
    print(f"seed {seed}: recorded in {time.perf_counter() - t0:.1f} s")
    print(
        f"{'silent':>7} {'from':>5} {'for':>4} {'counters':>8} {'left out':>8}  "
        f"{'RMS':>6} {'max':>6}  "
        f"{'kept RMS':>8} {'max':>6}  {'walls':>5} {'lobby':>5}  {'wall':>5}"
    )
    for label, case in [("none", None), *[(c[0], c) for c in CASES]]:
        path, start, seconds, counters = run, 0, 0, "kept"
        left = 0
        if case is not None:
            topic, start, seconds, counters = case
            path = work / f"{topic.strip('/')}_{start}_{seconds}_{counters}.mcap"
            left = without(
                run, path, topic, float(start), float(start + seconds), counters=counters
            )
        t0 = time.perf_counter()
        score = score_silence(path, work / f"{path.stem}.maps")
        print(
            f"{label:>7} {start:>5} {seconds:>4} {counters:>8} {left:>8}  "
            f"{score.rms_m:6.3f} {score.max_m:6.3f}  "
            f"{score.kept_rms_m:8.3f} {score.kept_max_m:6.3f}  {score.worst_walls:5.3f} "
            f"{score.worst_lobby_m:5.2f}  {time.perf_counter() - t0:4.0f}s"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--keep", type=Path, default=None, help="keep the copies and maps here")
    args = parser.parse_args(argv)
    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.ERROR))
    print(
        "RMS / max: every scan on a floor; kept: the scans the odometry spoke for; walls: the "
        "worst floor's share within 10 cm under the building's transform; lobby: the worst [m]"
    )
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
        bench(args.seed, args.keep)
    else:
        with tempfile.TemporaryDirectory() as work:
            bench(args.seed, Path(work))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
