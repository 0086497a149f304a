"""What the barometer has seen of a ride shortly after the car starts: how soon a ride can be
announced at all, whatever the detector.

    .venv/bin/python bench/floors_ride_onset.py [--seeds 60] [--first-seed 0]

For every ride of the simulated runs (46 minutes, 6 floors: the floors bench's default) it
takes the sensor's reading (the BMP280 model: its filter, its noise) averaged over the last
three samples at 0.5, 1, 1.5 and 2 s after the car starts, less its mean over the second
before the car started, signed so that positive is the way the car goes (pressure falls going
up). It prints, per delay, percentiles of that and the share of rides whose reading has moved
the wrong way or less than 1 Pa (8 cm): a causal detector cannot announce those rides' direction
by then from the pressure alone. Figures, not a pass or fail.
"""

from __future__ import annotations

import argparse

import numpy as np

from baromap import logs
from baromap.evaluation.floors import SimSettings, sim_case

DELAYS_S = (0.5, 1.0, 1.5, 2.0)
NS_PER_S = 1_000_000_000


def onsets(seeds: range) -> dict[float, list[float]]:
    """Per delay, the reading's move toward the ride's direction (Pa), one per ride."""
    out: dict[float, list[float]] = {d: [] for d in DELAYS_S}
    for seed in seeds:
        case = sim_case(seed, SimSettings())
        t, p = case.t_ns, case.pressure_pa
        for ride in case.truth.transitions:
            toward = -1.0 if ride.to_floor > ride.from_floor else 1.0
            before = p[
                np.searchsorted(t, ride.t_begin_ns - NS_PER_S) : np.searchsorted(t, ride.t_begin_ns)
            ]
            base = float(before.mean())
            for delay in DELAYS_S:
                j = int(np.searchsorted(t, ride.t_begin_ns + int(delay * NS_PER_S)))
                out[delay].append(toward * (float(p[j - 2 : j + 1].mean()) - base))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=60)
    parser.add_argument("--first-seed", type=int, default=0)
    args = parser.parse_args(argv)
    logs.configure("console", "WARNING")
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    for delay, moves in onsets(seeds).items():
        v = np.asarray(moves)
        p5, p25, p50 = np.percentile(v, [5, 25, 50])
        print(
            f"{delay:.1f} s after the car starts ({len(v)} rides, seeds {seeds[0]}-{seeds[-1]}): "
            f"reading moved the ride's way p5 {p5:+.2f} Pa, p25 {p25:+.2f} Pa, p50 {p50:+.2f} Pa;"
            f" the wrong way or not at all {np.mean(v <= 0.0) * 100:.0f} %, less than 1 Pa "
            f"{np.mean(v < 1.0) * 100:.0f} %"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
