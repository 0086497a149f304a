"""Recording bench: how fast a run's series load, and how fast ``baromap info`` answers.

    .venv/bin/python bench/recording.py [RUN.mcap] [--repeat 3]

Without a file it first writes the 46-minute simulated run (``baromap sim record``, six
floors, seed 0: about 69,000 pressure samples and 27,600 odometry messages). Prints, best of
``--repeat`` runs (wall time, this machine, whatever else is running on it):

- ``load_pressure`` and ``load_odometry`` alone, and both in one pass
  (``load_pressure_and_odometry``); target: both under 1.5 s;
- the same topics through the mcap package's own reader (``iter_messages``, log-time
  order, no decoding), the baseline this reader has to beat;
- ``baromap info`` in a fresh interpreter (imports included); target: under 1 s.

Each figure comes with its CPU time: on a machine shared with other work the wall time can be
several times the CPU time, and the CPU time says what the code itself costs.
"""

from __future__ import annotations

import argparse
import logging
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import structlog

from baromap.recording import load_odometry, load_pressure, load_pressure_and_odometry
from baromap.recording import topics as t


def _cpu_s() -> float:
    """CPU seconds of this process and its finished children."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


CPU: dict[str, float] = {}


def best_of(repeat: int, fn: Callable[[], Any], name: str = "") -> tuple[float, Any]:
    """Best wall time of ``repeat`` runs; the CPU time of that run goes to ``CPU[name]``."""
    best, result = float("inf"), None
    for _ in range(repeat):
        started, cpu = time.perf_counter(), _cpu_s()
        result = fn()
        wall = time.perf_counter() - started
        if wall < best:
            best, CPU[name] = wall, _cpu_s() - cpu
    return best, result


def mcap_package_baseline(path: Path) -> int:
    from mcap.reader import make_reader

    with path.open("rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages(topics=[t.BARO, t.ODOM]))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", nargs="?", type=Path)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.WARNING))
    with tempfile.TemporaryDirectory() as tmp:
        path = args.recording
        if path is None:
            from baromap.sim.record import record_run

            path = Path(tmp) / "run.mcap"
            started = time.perf_counter()
            record_run(path, minutes=46.0, floors=6, seed=0, progress=False)
            print(f"sim record (46 min, 6 floors): {time.perf_counter() - started:.1f} s")
        print(f"{path}: {path.stat().st_size / 1e6:.1f} MB")

        wall, pressure = best_of(args.repeat, lambda: load_pressure(path), "p")
        print(
            f"load_pressure: {wall:.3f} s (CPU {CPU['p']:.3f} s) for {len(pressure.t_ns)} samples"
        )
        wall, odom = best_of(args.repeat, lambda: load_odometry(path), "o")
        print(f"load_odometry: {wall:.3f} s (CPU {CPU['o']:.3f} s) for {len(odom)} messages")
        both, _ = best_of(args.repeat, lambda: load_pressure_and_odometry(path), "b")
        verdict = "met" if both < 1.5 else "NOT met"
        print(
            f"load_pressure_and_odometry: {both:.3f} s (CPU {CPU['b']:.3f} s; "
            f"target < 1.5 s: {verdict})"
        )
        wall, count = best_of(1, lambda: mcap_package_baseline(path), "m")
        print(
            f"mcap package iter_messages over the same topics, no decoding: {wall:.3f} s "
            f"(CPU {CPU['m']:.3f} s) for {count} messages ({wall / both:.1f}x the loaders' time)"
        )

        command = [sys.executable, "-m", "baromap.cli", "info", str(path)]
        info, proc = best_of(
            args.repeat,
            lambda: subprocess.run(command, check=False, capture_output=True, text=True),
            "i",
        )
        if proc.returncode != 0:
            print(proc.stdout, proc.stderr)
            return 1
        verdict = "met" if info < 1.0 else "NOT met"
        print(
            f"baromap info (fresh process, imports included): {info:.3f} s (CPU {CPU['i']:.3f} s)"
        )
        print(f"  target < 1 s: {verdict}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
