"""In which frame do the relations hold? Ours and GMapping's poses scored with the robot's
centre moved along the laser's axis.

    .venv/bin/python bench/relations_frame.py DIR [--cases REGEX]

Kuemmerle et al.'s relations are the robot's motion. The corrected logs print one pose for
the laser and the robot (GMapping's, the laser's), and the gate's odometry is made from it,
so our trajectory is the laser's too. Where the robot's centre is elsewhere, a relation
between two poses turned by an angle a apart differs from the laser's motion by
``2 * mount * sin(a / 2)``: an error no accuracy of the laser's poses removes. The log's
``PARAM robot_frontlaser_offset`` declares the mount (Freiburg 079: -0.04, the laser 4 cm
behind the centre; Intel: 0).

For each case of a ``bench/gate.py --keep DIR`` run that is scored on relations (every scan
kept), and for the reference poses: the relations' mean translational error with the pose
moved forward by each offset of a sweep (the offset is the robot's centre in the laser's
frame: minus the declared mount), the offset where it is least, and the error at the declared
mount beside the error as the gate scores it (offset 0). Not part of the package: a check of
the bench's metric (docs/mapping-gate.md, "The frame of the relations").
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import gate

#: The logs' files with their PARAM lines (the gate reads copies with the relations' times,
#: which keep only the laser lines).
PARAM_FILES = {"intel": "intel-corrected.log.gz", "fr079": "freiburg-079-corrected.log.gz"}
#: Offsets of the sweep (m, forward along the laser's axis).
SWEEP_M = np.round(np.arange(-0.08, 0.0801, 0.01), 3)


def relation_error(times: np.ndarray, poses: np.ndarray, relations, forward_m: float) -> float:  # type: ignore[no-untyped-def]
    """Mean translational error on the relations of poses moved ``forward_m`` along their axis."""
    from baromap.mapping import se2
    from baromap.mapping.relations import relation_errors

    moved = se2.compose(poses, np.array([forward_m, 0.0, 0.0]))
    return relation_errors(times, moved, relations).trans_mean


def sweep(times: np.ndarray, poses: np.ndarray, relations, declared: float) -> str:  # type: ignore[no-untyped-def]
    errors = [relation_error(times, poses, relations, float(o)) for o in SWEEP_M]
    best = int(np.argmin(errors))
    return (
        f"as scored {errors[int(np.flatnonzero(SWEEP_M == 0)[0])]:.4f} m, "
        f"at the declared mount {relation_error(times, poses, relations, -declared):.4f} m, "
        f"least {errors[best]:.4f} m at {SWEEP_M[best]:+.2f} m"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("keep", type=Path, nargs="?", help="a bench/gate.py --keep directory")
    parser.add_argument("--cases", default=None, help="only the cases whose name matches REGEX")
    args = parser.parse_args()
    if args.keep is None:
        # `make bench` runs every script bare
        print("relations_frame: nothing to score without a bench/gate.py --keep DIR")
        return 0
    import logging

    import structlog

    # the logs' own stamps are repaired on every read, as the gate's report says already
    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.ERROR))
    from baromap.recording.carmen import read_carmen
    from baromap.recording.carmen_import import declared_mount

    sources = gate.Sources()
    declared: dict[str, float] = {}
    for name, seeds, _ in gate.CASES:
        spec = gate.parse_case(name)
        if spec.log not in PARAM_FILES or spec.stride != 1 or spec.part is not None:
            continue
        if args.cases is not None and not re.search(args.cases, name):
            continue
        source, relations = sources.get(spec.log)
        if spec.log not in declared:
            mount = declared_mount(read_carmen(gate.LASER / PARAM_FILES[spec.log]))
            declared[spec.log] = 0.0 if mount is None else mount[0]
            line = sweep(source.times_ns, source.reference, relations, declared[spec.log])
            print(f"{spec.log}: declared mount {declared[spec.log]:+.3f} m")
            print(f"  reference (GMapping's poses): {line}")
        for seed in seeds:
            tum = args.keep / gate.case_dir_name(name, seed) / "out" / "trajectory.tum"
            if not tum.exists():
                continue
            variant = gate.variant_of(spec, source, seed)
            t, poses = gate._tum(tum)
            rows = gate.scan_rows(variant, t)
            if rows is None or (rows < 0).any():
                print(f"  {name} seed {seed}: scans missing, not scored")
                continue
            times = source.times_ns[variant.source_index]
            line = sweep(times, poses[rows], relations, declared[spec.log])
            print(f"  {name} seed {seed}: {line}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
