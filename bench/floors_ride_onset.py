"""What the barometer has seen of a ride shortly after the car starts: how soon a ride can be
announced at all, whatever the detector.

    .venv/bin/python bench/floors_ride_onset.py [--seeds 60] [--first-seed 0]

For every ride of the simulated runs (46 minutes, 6 floors: the floors bench's default) it
takes the sensor's reading (the BMP280 model: its filter, its noise) averaged over the last
three samples at 0.5, 1, 1.5 and 2 s after the car starts, less its mean over the second
before the car started, signed so that positive is the way the car goes (pressure falls going
up). It prints, per delay, percentiles of that and the share of rides whose reading has moved
the wrong way or less than 1 Pa (8 cm): a causal detector cannot announce those rides' direction
by then from the pressure alone.

The same figures follow for a perfect barometer at the robot (the air pressure itself: no
filter, no noise; the weather's gusts are in it, as they are in any reading) and for that
pressure less the weather (a perfect reference station's), and each split by the sign of the
building's piston effect: against the ride (the car pushes the air so that the pressure in it
moves the other way while the car speeds up, as in half the simulated buildings) or along it.
What a perfect barometer cannot tell by then, no barometer can. Figures, not a pass or fail.
"""

from __future__ import annotations

import argparse

import numpy as np

from baromap import logs
from baromap.arrays import FloatArray
from baromap.evaluation.floors import SimSettings, sim_case
from baromap.sim.scenario import make_scenario, scenario_pressure_run

DELAYS_S = (0.5, 1.0, 1.5, 2.0)
NS_PER_S = 1_000_000_000
SOURCES = ("sensor", "perfect barometer", "perfect, less the weather")


def onsets(seeds: range) -> dict[tuple[str, bool, float], list[float]]:
    """Per source, piston sign (True: against the ride) and delay, the reading's move toward
    the ride's direction (Pa), one per ride."""
    out: dict[tuple[str, bool, float], list[float]] = {}
    for seed in seeds:
        case = sim_case(seed, SimSettings())
        scenario = make_scenario(seed)
        run = scenario_pressure_run(scenario)
        # the piston term is k * vertical speed: k > 0 raises the pressure going up, against
        # the hydrostatic fall, whichever way the car goes
        against = scenario.ventilation.piston_pa_per_mps > 0.0
        true = np.asarray(run.true_pressure_pa)
        series: dict[str, FloatArray] = {
            "sensor": case.pressure_pa,
            "perfect barometer": true,
            "perfect, less the weather": true - scenario.reference_true_pa(run.t_s),
        }
        t = case.t_ns
        for ride in case.truth.transitions:
            toward = -1.0 if ride.to_floor > ride.from_floor else 1.0
            lo = np.searchsorted(t, ride.t_begin_ns - NS_PER_S)
            hi = np.searchsorted(t, ride.t_begin_ns)
            for source, p in series.items():
                base = float(p[lo:hi].mean())
                for delay in DELAYS_S:
                    j = int(np.searchsorted(t, ride.t_begin_ns + int(delay * NS_PER_S)))
                    move = toward * (float(p[j - 2 : j + 1].mean()) - base)
                    out.setdefault((source, against, delay), []).append(move)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=60)
    parser.add_argument("--first-seed", type=int, default=0)
    args = parser.parse_args(argv)
    logs.configure("console", "WARNING")
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    moves = onsets(seeds)
    print(f"seeds {seeds[0]}-{seeds[-1]}; the reading's move the ride's way after the car starts")
    for source in SOURCES:
        for piston in (None, True, False):
            label = {None: "all rides", True: "piston against", False: "piston along"}[piston]
            for delay in DELAYS_S:
                sides = (True, False) if piston is None else (piston,)
                v = np.concatenate([np.asarray(moves.get((source, s, delay), [])) for s in sides])
                if not len(v):
                    continue
                p5, p25, p50 = np.percentile(v, [5, 25, 50])
                wrong, small = np.mean(v <= 0.0) * 100, np.mean(v < 1.0) * 100
                print(
                    f"{source:26s} {label:15s} {delay:.1f} s ({len(v)} rides): p5 {p5:+.2f} "
                    f"p25 {p25:+.2f} p50 {p50:+.2f} Pa; the wrong way or not at all "
                    f"{wrong:.0f} %, less than 1 Pa {small:.0f} %"
                )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
