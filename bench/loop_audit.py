"""Which loop closures were wrong: every closure a gate run's SLAM took, against the reference.

    .venv/bin/python bench/loop_audit.py DIR CASE [CASE ...] [--seeds 0,1,2] [--wrong-m 1.0]

A closure is a motion between two keyframes that a scan match measured. The gate's logs come
with the corrected poses, so each closure can be checked on its own: the reference's motion
between the two keyframes' scans against the closure's. One wrong closure can cost a run metres
of ATE, or nothing where later ones outvote it; the gate's ATE cannot tell those apart, this
can. For each CASE and seed of a ``bench/gate.py --keep DIR`` run (the same names as the gate's
cases and ``--extra`` ones), the maps are built again from the kept recording and the run's
closures are counted: taken, wrong (further from the reference motion than ``--wrong-m``, well
beyond the corrected logs' own disagreement with their scans, a few decimetres on the
Infinite Corridor), and of those the ones the finished graph follows (its motion between the
two keyframes nearer the closure than the reference). Each wrong closure is listed with its
keyframes, the scans they stand for, and its miss. Not part of the package: a measure for
the loop closer's decisions (docs/mapping-gate.md, "Wrong closures").
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import gate


def audit(
    case: str, seed: int, case_dir: Path, sources: gate.Sources, wrong_m: float
) -> tuple[str, tuple[int, int, int]]:
    """The report on one run and its counts: closures, wrong ones, wrong ones followed."""
    from baromap.mapping import se2
    from baromap.mapping.build import build_maps

    spec = gate.parse_case(case)
    source, _ = sources.get(spec.log)
    variant = gate.variant_of(spec, source, seed)
    if variant.extra_scans:
        return f"{case} seed {seed}: scans added by the variant, not audited", (0, 0, 0)
    with tempfile.TemporaryDirectory() as out:
        slam = build_maps(case_dir / "run.mcap", Path(out) / "maps").slam
    scan_of = slam.keyframes
    if len(slam.scan_poses) != len(variant.reference):
        return f"{case} seed {seed}: {len(slam.scan_poses)} scans mapped, not the log's", (0, 0, 0)
    reference = variant.reference[scan_of]
    final = slam.keyframe_poses
    lines, wrong, followed = [], 0, 0
    for (i, j), motion in zip(slam.loop_edges, slam.loop_motions, strict=True):
        truth = se2.between(reference[i], reference[j])
        miss = se2.between(truth, motion)
        miss_m = float(np.hypot(miss[0], miss[1]))
        if miss_m <= wrong_m:
            continue
        wrong += 1
        placed = se2.between(final[i], final[j])
        to_closure = se2.between(motion, placed)
        to_truth = se2.between(truth, placed)
        follows = bool(np.hypot(*to_closure[:2]) < np.hypot(*to_truth[:2]))
        followed += int(follows)
        lines.append(
            f"    keyframes {i}->{j} (scans {scan_of[i]}->{scan_of[j]}): "
            f"{miss_m:.2f} m off; the run placed them {np.hypot(*to_truth[:2]):.2f} m from "
            f"the reference, nearer {'the closure' if follows else 'the reference'}"
        )
    counts = (len(slam.loop_edges), wrong, followed)
    head = f"{case} seed {seed}: {counts[0]} closures, {wrong} wrong, {followed} followed"
    return "\n".join([head, *lines]), counts


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("keep", type=Path, nargs="?", help="a bench/gate.py --keep directory")
    parser.add_argument("cases", nargs="*", help="case names, as the gate's --cases/--extra")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--wrong-m", type=float, default=1.0)
    args = parser.parse_args()
    if args.keep is None or not args.cases:
        # `make bench` runs every script bare
        print("loop_audit: nothing to audit without a bench/gate.py --keep DIR and its cases")
        return 0
    import structlog

    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.ERROR))
    sources = gate.Sources()
    seeds = [int(s) for s in args.seeds.split(",")]
    totals = [0, 0, 0]
    for case in args.cases:
        for seed in seeds:
            case_dir = args.keep / gate.case_dir_name(case, seed)
            if not (case_dir / "run.mcap").exists():
                print(f"{case} seed {seed}: no recording in {case_dir}")
                continue
            report, counts = audit(case, seed, case_dir, sources, args.wrong_m)
            print(report, flush=True)
            totals = [a + b for a, b in zip(totals, counts, strict=True)]
    print(
        f"all: {totals[0]} closures, {totals[1]} wrong by more than {args.wrong_m} m, "
        f"{totals[2]} of them followed by the finished graph"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
