"""Where a gate case's error lies: the trajectories a ``bench/gate.py --keep DIR`` run kept,
against the reference, along the run.

    .venv/bin/python bench/gate_errors.py [DIR] [--cases REGEX] [--seeds S] [--extra CASE]
                                            [--window-m 10] [--stretches 3] [--stretch-scans 25]

For each case and seed kept in DIR (``CASE-sSEED/out/trajectory.tum``):

- ATE after the gate's rigid alignment, and after a similarity (the rigid motion and one
  scale, Umeyama): what a uniform scale between ours and the reference explains, and that
  scale (ours to the reference: above 1, ours is the smaller);
- the local error over every ``--window-m`` of travel (the motion between a scan and the
  first one that far along the reference, ours against the reference's, in the reference's
  frame at the start): along the motion (its mean, in per cent of the window, is a
  difference of step length; its RMS), across it, in heading, in the straight windows (under
  10 degrees of turn) and the turning ones;
- the ``--stretches`` stretches of ``--stretch-scans`` scans (disjoint) where ours lies
  furthest from the reference after the rigid alignment: their scans, travel and mean error.

The revisit consistency of the same trajectories against the reference's (which of the two
the scans agree with where the run passes a place again) is ``bench/consistency.py --gate
DIR``. Not part of the package: it reads the gate's scratch files.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import gate

#: A window turning less than this is straight.
STRAIGHT_DEG = 10.0


def window_errors(est: np.ndarray, ref: np.ndarray, window_m: float) -> dict[str, np.ndarray]:
    """Ours against the reference over every window of ``window_m`` of the reference's travel:
    along and across the reference's motion (m), heading (deg), the reference's travel and turn."""
    from baromap.mapping import se2

    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(ref[:, :2], axis=0).T))])
    j = np.searchsorted(travel, travel + window_m)
    i = np.nonzero(j < len(travel))[0]
    j = j[i]
    moved_ref, moved_est = se2.between(ref[i], ref[j]), se2.between(est[i], est[j])
    length = np.hypot(moved_ref[:, 0], moved_ref[:, 1])
    ok = length > 0.5 * window_m  # not a window that comes back on itself
    unit = moved_ref[ok, :2] / length[ok, None]
    miss = moved_est[ok, :2] - moved_ref[ok, :2]
    return {
        "along": np.sum(miss * unit, axis=1),
        "across": miss[:, 1] * unit[:, 0] - miss[:, 0] * unit[:, 1],
        "heading": np.degrees(se2.wrap(moved_est[ok, 2] - moved_ref[ok, 2])),
        "length": length[ok],
        "turn": np.degrees(np.abs(se2.wrap(ref[j[ok], 2] - ref[i[ok], 2]))),
    }


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2))) if len(values) else float("nan")


def describe(name: str, seed: int, case_dir: Path, args: argparse.Namespace) -> list[str]:
    from baromap.evaluation.trajectory import similarity_error, trajectory_error

    spec = gate.parse_case(name)
    source, _ = SOURCES.get(spec.log)
    variant = gate.variant_of(spec, source, seed)
    t, poses = gate._tum(case_dir / "out" / "trajectory.tum")
    rows = gate.scan_rows(variant, t)
    if rows is None or (rows < 0).any():
        return [f"{name} seed {seed}: scans missing from the trajectory, not described"]
    est, ref = poses[rows], variant.reference
    ate = trajectory_error(est, ref)
    sim, scale = similarity_error(est, ref)
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(ref[:, :2], axis=0).T))])
    lines = [
        f"{name} seed {seed}: ATE {ate.rms_m:.3f} m (max {ate.max_m:.3f}), after a similarity "
        f"{sim:.3f} m, scale ours to reference {scale:.4f}; {len(ref)} scans over "
        f"{travel[-1]:.0f} m"
    ]
    w = window_errors(est, ref, args.window_m)
    straight = w["turn"] < STRAIGHT_DEG
    step = 100.0 * np.sum(w["along"]) / np.sum(w["length"])
    lines.append(
        f"  over {args.window_m:g} m: along {step:+.2f} % (RMS {_rms(w['along']):.3f} m), across "
        f"RMS {_rms(w['across']):.3f} m, heading RMS {_rms(w['heading']):.2f} deg; straight "
        f"({straight.mean():.0%}) along {_rms(w['along'][straight]):.3f} / across "
        f"{_rms(w['across'][straight]):.3f} m, turning along {_rms(w['along'][~straight]):.3f}"
        f" / across {_rms(w['across'][~straight]):.3f} m"
    )
    size = args.stretch_scans
    means = [
        (float(ate.errors_m[a : a + size].mean()), a) for a in range(0, len(ref) - size + 1, size)
    ]
    for error, a in sorted(means, reverse=True)[: args.stretches]:
        b = a + size - 1
        lines.append(
            f"  scans {a}-{b} (travel {travel[a]:.0f}-{travel[b]:.0f} m): {error:.3f} m from "
            "the reference"
        )
    return lines


SOURCES = gate.Sources()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("keep", type=Path, nargs="?", help="a bench/gate.py --keep directory")
    parser.add_argument("--cases", default=None, help="only the cases whose name matches REGEX")
    parser.add_argument(
        "--extra", action="append", default=[], metavar="CASE", help="a gate.py --extra case"
    )
    parser.add_argument("--seeds", default=None, help="these seeds (comma-separated)")
    parser.add_argument("--window-m", type=float, default=10.0)
    parser.add_argument("--stretches", type=int, default=3)
    parser.add_argument("--stretch-scans", type=int, default=25)
    args = parser.parse_args()
    if args.keep is None:
        print("gate_errors: nothing to describe without a bench/gate.py --keep DIR")
        return 0
    found = 0
    for name, seeds, _ in [*gate.CASES, *((name, (0, 1, 2), False) for name in args.extra)]:
        if args.cases is not None and not re.search(args.cases, name):
            continue
        for seed in tuple(int(s) for s in args.seeds.split(",")) if args.seeds else seeds:
            case_dir = args.keep / gate.case_dir_name(name, seed)
            if not (case_dir / "out" / "trajectory.tum").exists():
                continue
            found += 1
            print("\n".join(describe(name, seed, case_dir, args)))
    if not found:
        print(f"gate_errors: no kept case in {args.keep}")
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
