"""The slow tail of the live floor decisions: which rides are decided late, and what the
simulator put around their arrival.

    .venv/bin/python bench/floors_tail.py [--seeds 60] [--first-seed 0] [--stops none]
                                          [--slowest 12] [--jobs 2]

For every true ride of the simulated runs (the floors bench's default: 46 minutes, 6 floors,
the robot's odometry), the decision delay after the car arrives, as ``bench/floors_live.py``
counts it (when a consumer first held the transition between the floors it ends up between),
split by what was around the car's arrival:

- the sign of the building's piston effect (the car pushes the air: a pressure term
  proportional to its vertical speed). *Against* the ride, the pressure in the car lags the
  car while it speeds up and runs ahead of it while it brakes, so it moves fastest just
  before the car stops and then stops at once; *along* it, the pressure slows before the car
  does and is at rest when the car arrives;
- whether a ventilation spike came between 0.5 s before and 2 s after the arrival (the
  simulated car has 1 + Poisson(1.5) spikes of 5-25 Pa per ride, each fading over 0.4-2 s,
  at any time between its doors closing and opening).

Then the slowest rides, each with the spikes near its arrival (seconds after it, pascals).
Figures, not a pass or fail; live (causal) figures only.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from baromap import logs
from baromap.evaluation.floor_live import live_detection
from baromap.evaluation.floors import SimSettings, evaluate, sim_case
from baromap.floors.evaluation import match
from baromap.messages import NS_PER_S
from baromap.sim.scenario import make_scenario

#: Spikes this long before to this long after the car's arrival count as "at the arrival", s.
NEAR_S = (-0.5, 2.0)
SLOW_S = 2.0


@dataclass(frozen=True, slots=True)
class Ride:
    seed: int
    arrival_s: float  # into the run
    storeys: int
    delay_s: float
    piston_against: bool
    #: (seconds after the arrival, pascals) of the spikes within NEAR_S of it
    spikes: tuple[tuple[float, float], ...]


def _rides(job: tuple[int, str]) -> tuple[list[Ride], int, int]:
    """One run's rides found (with their delays), the rides missed and the false transitions."""
    logs.configure("console", "WARNING")
    seed, stops = job
    case = sim_case(seed, SimSettings(stops=stops))
    detection, _ = evaluate(case, "online")
    live = live_detection(list(detection.events), detection)
    pairs = match(live, case.truth)
    scenario = make_scenario(seed, stops=stops)
    vent = scenario.ventilation
    rides = []
    for true, det in pairs:
        arrival = (true.t_end_ns - scenario.start_ns) / NS_PER_S
        near = tuple(
            (round(float(t - arrival), 2), round(float(pa), 1))
            for t, pa in zip(vent.spike_t_s, vent.spike_pa, strict=True)
            if NEAR_S[0] <= t - arrival <= NEAR_S[1]
        )
        rides.append(
            Ride(
                seed,
                arrival,
                abs(true.to_floor - true.from_floor),
                (det.t_detect_ns - true.t_end_ns) / NS_PER_S,
                vent.piston_pa_per_mps > 0.0,
                near,
            )
        )
    missed = len(case.truth.transitions) - len(pairs)
    return rides, missed, len(live.transitions) - len(pairs)


def _line(label: str, delays: list[float]) -> str:
    if not delays:
        return f"{label:40s}    0 rides"
    v = np.asarray(delays)
    p50, p95 = np.percentile(v, [50, 95])
    return (
        f"{label:40s} {len(v):4d} rides  p50 {p50:5.2f} s  p95 {p95:5.2f} s  "
        f"over {SLOW_S:.0f} s: {int(np.sum(v > SLOW_S)):3d}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=60)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--stops", choices=("none", "stay", "leave"), default="none")
    parser.add_argument("--slowest", type=int, default=12)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    logs.configure("console", "WARNING")
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    rides: list[Ride] = []
    missed = false = 0
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for found, m, f in pool.map(_rides, [(s, args.stops) for s in seeds]):
            rides += found
            missed += m
            false += f
    print(
        f"seeds {seeds[0]}-{seeds[-1]}, stops {args.stops}: {len(rides)} rides found, "
        f"{missed} missed, {false} false; runs with the piston against the ride: "
        f"{len({r.seed for r in rides if r.piston_against})} of {len(seeds)}"
    )
    groups = {
        "all": lambda r: True,
        "piston against": lambda r: r.piston_against,
        "piston along": lambda r: not r.piston_against,
        "a spike at the arrival": lambda r: bool(r.spikes),
        "no spike at the arrival": lambda r: not r.spikes,
        "piston against, a spike at the arrival": lambda r: r.piston_against and bool(r.spikes),
        "piston against, no spike": lambda r: r.piston_against and not r.spikes,
        "piston along, a spike at the arrival": lambda r: not r.piston_against and bool(r.spikes),
        "piston along, no spike": lambda r: not r.piston_against and not r.spikes,
        "one storey": lambda r: r.storeys == 1,
        "two storeys or more": lambda r: r.storeys > 1,
    }
    for label, keep in groups.items():
        print(_line(label, [r.delay_s for r in rides if keep(r)]))
    print(f"the {args.slowest} slowest (seed, arrival s into the run, storeys, piston, spikes):")
    for r in sorted(rides, key=lambda r: -r.delay_s)[: args.slowest]:
        piston = "against" if r.piston_against else "along"
        spikes = ", ".join(f"{dt:+.2f} s {pa:+.0f} Pa" for dt, pa in r.spikes) or "none"
        print(
            f"  {r.delay_s:5.2f} s  seed {r.seed:3d} at {r.arrival_s:7.1f} s, "
            f"{r.storeys} storey(s), piston {piston}, spikes: {spikes}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
