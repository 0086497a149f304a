"""Live floor decisions against the simulator's truth: how soon, how right, what was retold.

    .venv/bin/python bench/floors_live.py [--seeds 60] [--first-seed 0] [--real DIR]
                                          [--variants] [--jobs 2]

For each set of simulated runs (46 minutes, 6 floors, 1.5 hPa/h drift, ventilation spikes and
door seals in the car) it prints, from the events as a consumer received them:

- the decision delay after the car arrives (the true end of its vertical motion), p50 / p95:
  when the consumer first held each transition between the floors it ends up between;
- ``ride_started`` after the car starts, p50 / p95, over the rides announced the right way
  (a ride not announced, or announced the wrong way, counts as never);
- transitions found / true and false ones (corrections applied), storeys right;
- corrections (those that moved the robot to another floor), retractions, and rides
  announced / withdrawn.

``--variants`` adds the variants the floors evaluation runs (no odometry, halts at a passing
floor with the robot in the car or out of it, two hours of 3 hPa/h weather with and without a
reference station); ``--real`` the shared IPIN walks (no odometry: a walker). Figures, not
a pass or fail; the live figures are causal (what was known when), apart from post-run.
"""

from __future__ import annotations

import argparse
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from baromap import logs
from baromap.evaluation.floor_live import percentile, ride_delays
from baromap.evaluation.floors import (
    CaseResult,
    MethodTotals,
    SimSettings,
    evaluate_case,
    real_cases,
    sim_case,
)

SHARED = Path(os.environ.get("BAROMAP_SHARED_DATA", Path(__file__).parents[2] / "shared/data"))
ROUTE_2H = (4, 5, 3, 2, 1, 0, 2, 5, 1, 4, 0, 3)


@dataclass(frozen=True, slots=True)
class Variant:
    name: str
    settings: SimSettings
    seeds: int | None = None  # None: as many as asked


VARIANTS = (
    Variant("no odometry", SimSettings(use_odometry=False)),
    Variant("halts, robot in the car", SimSettings(stops="stay")),
    Variant("halts, robot in the car, no odometry", SimSettings(stops="stay", use_odometry=False)),
    Variant("halts, robot gets out", SimSettings(stops="leave")),
    Variant("halts, robot gets out, no odometry", SimSettings(stops="leave", use_odometry=False)),
    Variant("2 h, 3 hPa/h", SimSettings(drift_hpa_per_h=3.0, minutes=120, route=ROUTE_2H), 10),
    Variant(
        "2 h, 3 hPa/h, reference station",
        SimSettings(drift_hpa_per_h=3.0, minutes=120, route=ROUTE_2H, use_reference=True),
        10,
    ),
)


def _one(job: tuple[int, SimSettings]) -> CaseResult:
    logs.configure("console", "WARNING")
    seed, settings = job
    return evaluate_case(sim_case(seed, settings), "online")


def _row(name: str, totals: MethodTotals) -> str:
    live = totals.live
    delays, right, total = ride_delays(totals.rides)
    return (
        f"{name:38s} {totals.live_cases:5d} {live.found:4d}/{live.true:<4d} {live.false:5d} "
        f"{live.storeys:5d} {percentile(live.delays, 50):6.2f} {percentile(live.delays, 95):6.2f}"
        f" {percentile(delays, 50):6.2f} {percentile(delays, 95):6.2f} {right:4d}/{total:<4d}"
        f" {totals.corrections:4d} ({totals.moves:3d}) {totals.retractions:5d} "
        f"{sum(r.announced for r in totals.rides):6d} {sum(r.withdrawn for r in totals.rides):6d}"
    )


HEADER = (
    f"{'runs':38s} {'cases':>5s} {'found':>9s} {'false':>5s} {'stor.':>5s} "
    f"{'dec50':>6s} {'dec95':>6s} {'ride50':>6s} {'ride95':>6s} {'right':>9s} "
    f"{'corr (moving)':>10s} {'retr.':>5s} {'rides':>6s} {'withdr':>6s}"
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=60)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--real", type=Path, default=None, help="IPIN logs (e.g. SHARED/baro)")
    parser.add_argument("--variants", action="store_true")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    logs.configure("console", "WARNING")
    load = os.getloadavg()[0]
    print(f"load average {load:.1f}; delays in seconds of the run (sample time, not wall time)")
    print(HEADER)
    sets = [Variant("odometry (the robot's own)", SimSettings())]
    if args.variants:
        sets += list(VARIANTS)
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for variant in sets:
            count = args.seeds if variant.seeds is None else min(variant.seeds, args.seeds)
            seeds = range(args.first_seed, args.first_seed + count)
            totals = MethodTotals()
            for result in pool.map(_one, [(seed, variant.settings) for seed in seeds]):
                totals.add(result)
            print(_row(f"{variant.name} (seeds {seeds[0]}-{seeds[-1]})", totals), flush=True)
    if args.real is not None:
        for case in real_cases(args.real):
            totals = MethodTotals()
            totals.add(evaluate_case(case, "online"))
            print(_row(case.name[-38:], totals))
    print(
        "dec = decision delay after the car arrives (IPIN: after the next waypoint); ride = "
        "ride_started after the car starts (IPIN: after the last waypoint before the stairs)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
