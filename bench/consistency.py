"""Revisit consistency (baromap.mapping.revisits) of several trajectories on the public
laser logs, beside their ground-truth relation errors and their ATE against GMapping.

    .venv/bin/python bench/consistency.py [--logs intel,fr079,acapulco] [--seeds 0,1,2,3,4]
                                          [--poses DIR] [--extra LABEL=DIR ...] [--gate DIR]
                                          [--no-loops] [--stretches N] [--window W]
                                          [--figures DIR] [--min-travel M] [--radius-scale F]
                                          [--truncate M]

Trajectories scored on each log: GMapping's corrected poses (the ATE's reference), odometry
alone (the synthesised odometry of each seed), ours (``run_log``, each seed; ``--poses DIR``
keeps them as ``DIR/ours/NAME_SEED.npy`` and ``DIR/noloops/...`` and reuses them), ours
without loop closures (``--no-loops``, seeds 0-1: a SLAM of the same kind with revisits left
open), and any ``--extra LABEL=DIR`` of saved poses (``bench/mrpt_logs.py --save-poses
DIR``: MRPT's icp-slam). ``--gate DIR`` takes ours from a ``bench/gate.py --keep DIR`` run
instead (each published log's case and seed, the gate's odometry, mapped by the CLI; no
odometry rows, as the synthesis's odometry is not the gate's; ``bench/mrpt_logs.py
--gate-odometry --save-poses`` gives MRPT the same odometry). The revisit partners are
chosen once per log from GMapping's poses, so every trajectory is scored on the same pairs of
scans.

Each trajectory gets its consistency (lower is better) and its revisit moves (median over
scans of how far a scan must move to lie on its partners; "beyond reach" where it does not
settle). Validation (logs with relations): the trajectories' order by consistency against
their order by relation error, all relations and the revisits only (ends more than 200 scans
apart), as Kendall's tau, and the share of pairs of trajectories whose relation errors differ
by more than 5, 10, 20 % that consistency and moves order as the relations do.

``--stretches N``: on each log, for each of our seeds, the share of revisit scans where ours
needs the smaller move than GMapping's, and the N stretches of ``--window`` scans (disjoint)
where our poses and GMapping's disagree most after the rigid alignment of the ATE, with both
trajectories' consistency and moves over the scans of each stretch; ``--figures DIR`` draws,
for seed 0's stretches, the whole run with the disagreement and, 4 m across, the stretch's
scan the two trajectories' moves judge most differently, on its partners, under each.
"""

from __future__ import annotations

import argparse
import itertools
import logging
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import structlog
from scipy.spatial import cKDTree
from scipy.stats import kendalltau

from baromap.evaluation.consistency import revisit_corrections
from baromap.evaluation.laser_logs import PreparedLog, run_prepared
from baromap.evaluation.trajectory import trajectory_error
from baromap.mapping import se2
from baromap.mapping.relations import Relations, relation_errors
from baromap.mapping.revisits import (
    MIN_TRAVEL_M,
    TRUNCATE_M,
    Consistency,
    ScanGeometry,
    consistency,
    revisit_partners,
)
from baromap.mapping.slam import SlamConfig
from baromap.odometry.synthesis import synthesize_odometry

REPO = Path(__file__).resolve().parent.parent
LASER = Path(os.environ.get("BAROMAP_SHARED_DATA", REPO.parent / "shared" / "data")) / "laser"

#: Relations whose ends are more than this many scans apart are revisits (634 of Freiburg
#: 079's 1615 relations).
REVISIT_SCANS = 200
#: Pairs of trajectories are counted as ordered alike or not when their relation errors differ
#: by more than these shares: how large a difference the consistency resolves.
MARGINS = (0.05, 0.1, 0.2)
#: A loop closure needs a match scoring this (a mean likelihood, below 1): never.
NO_LOOPS = SlamConfig(loop_min_score=0.999)


def _load() -> str:
    one, five, _ = os.getloadavg()
    return f"load {one:.1f} (5 min {five:.1f})"


def _revisits(times: np.ndarray, rel: Relations) -> Relations:
    i1 = np.clip(np.searchsorted(times, rel.t1_ns), 0, len(times) - 1)
    i2 = np.clip(np.searchsorted(times, rel.t2_ns), 0, len(times) - 1)
    far = np.abs(i2 - i1) > REVISIT_SCANS
    return Relations(rel.t1_ns[far], rel.t2_ns[far], rel.motion[far])


def _ours(log: PreparedLog, seed: int, store: Path | None, no_loops: bool) -> np.ndarray:
    tag = f"{log.name}_{seed}.npy"
    path = None if store is None else store / ("noloops" if no_loops else "ours") / tag
    if path is not None and path.exists():
        return np.load(path)
    poses = run_prepared(log, seed, config=NO_LOOPS if no_loops else None).result.scan_poses
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.save(path, poses)
    return poses


def _gate_poses(directory: Path, name: str, seed: int, scans: int) -> np.ndarray | None:
    """The poses of ``bench/gate.py --keep DIR``'s case ``name`` (the log as published),
    ``seed``: its ``trajectory.tum``, one line per scan in the log's order."""
    path = directory / f"{name}-s{seed}" / "out" / "trajectory.tum"
    if not path.exists():
        return None
    poses = np.loadtxt(path, usecols=(1, 2, 6, 7), ndmin=2)
    if len(poses) != scans:
        raise SystemExit(f"{path}: {len(poses)} poses for {scans} scans")
    return np.column_stack([poses[:, 0], poses[:, 1], 2.0 * np.arctan2(poses[:, 2], poses[:, 3])])


def trajectories(log: PreparedLog, args: argparse.Namespace) -> dict[str, np.ndarray]:
    name, reference = log.name, log.reference
    seeds = [int(s) for s in args.seeds.split(",")]
    out: dict[str, np.ndarray] = {"gmapping": reference}
    if args.gate is not None:
        # the gate's odometry is its own (log_variants), not the synthesis's: no odometry rows
        for seed in seeds:
            poses = _gate_poses(args.gate, name, seed, len(reference))
            if poses is not None:
                out[f"ours {seed}"] = poses
        return _extra(out, name, seeds, args)
    for seed in seeds:
        out[f"odometry {seed}"] = synthesize_odometry(reference, seed)
    for seed in seeds:
        out[f"ours {seed}"] = _ours(log, seed, args.poses, no_loops=False)
    if args.no_loops:
        for seed in seeds[:2]:
            out[f"ours, no loops {seed}"] = _ours(log, seed, args.poses, no_loops=True)
    return _extra(out, name, seeds, args)


def _extra(
    out: dict[str, np.ndarray], name: str, seeds: list[int], args: argparse.Namespace
) -> dict[str, np.ndarray]:
    """``out`` with the ``--extra LABEL=DIR`` trajectories of each seed that has one."""
    for extra in args.extra:
        label, _, directory = extra.partition("=")
        for seed in seeds:
            path = Path(directory) / f"{name}_{seed}.npy"
            if path.exists():
                out[f"{label} {seed}"] = np.load(path)
    return out


def bench_log(name: str, args: argparse.Namespace) -> None:
    log = PreparedLog(LASER, name)  # read once: every seed's SLAM runs on it
    times, reference, relations = log.times, log.reference, log.relations
    geometry = ScanGeometry(log.block)
    partners = revisit_partners(
        reference, geometry.radius_m * args.radius_scale, min_travel_m=args.min_travel
    )
    with_partners = sum(len(p) > 0 for p in partners)
    print(f"{name}: {len(times)} scans, {with_partners} with revisit partners; {_load()}")
    rows: list[dict[str, Any]] = []
    for label, poses in trajectories(log, args).items():
        start = time.process_time()
        score = consistency(geometry, poses, partners, truncate_m=args.truncate)
        moves = revisit_corrections(geometry, poses, partners, truncate_m=args.truncate)
        cpu = time.process_time() - start
        row: dict[str, Any] = {"label": label, "score": score, "poses": poses, "moves": moves}
        ok = ~np.isnan(moves[:, 0])
        row["move"] = float(np.median(moves[ok, 0]))
        text = (
            f"  {label:<22} consistency {score.mean_m * 1000:6.2f} mm "
            f"(overlap {score.overlap_mean:.3f}), revisit moves (median) "
            f"{row['move'] * 1000:7.1f} mm {np.degrees(np.median(moves[ok, 1])):5.2f} deg, "
            f"{np.mean(np.isinf(moves[ok, 0])):.0%} beyond reach"
        )
        if relations is not None:
            rel = relation_errors(times, poses, relations)
            far = relation_errors(times, poses, _revisits(times, relations))
            row["rel"], row["far"] = rel.trans_mean, far.trans_mean
            text += (
                f"  relations {rel.trans_mean:7.4f} m {rel.rot_mean:6.3f} deg,"
                f" revisits {far.trans_mean:7.4f} m {far.rot_mean:6.3f} deg"
            )
        text += f"  ATE vs GMapping {trajectory_error(poses, reference).rms_m:6.3f} m"
        print(text + f"  ({cpu:.1f} s cpu)", flush=True)
        rows.append(row)
    if relations is not None:
        scores = [r["score"].mean_m for r in rows]
        for key, what in (("rel", "all relations"), ("far", "revisit relations")):
            tau = kendalltau(scores, [r[key] for r in rows]).statistic
            print(f"  Kendall tau, consistency against {what}: {tau:.3f} over {len(rows)}")
        good = [r for r in rows if not r["label"].startswith("odometry")]
        tau = kendalltau([r["score"].mean_m for r in good], [r["rel"] for r in good]).statistic
        print(f"  the same without odometry alone (all relations): {tau:.3f} over {len(good)}")
        for margin in MARGINS:
            alike, moved, pairs = 0, 0, 0
            for a, b in itertools.combinations(good, 2):
                if max(a["rel"], b["rel"]) > (1 + margin) * min(a["rel"], b["rel"]):
                    pairs += 1
                    alike += (a["rel"] < b["rel"]) == (a["score"].mean_m < b["score"].mean_m)
                    moved += (a["rel"] < b["rel"]) == (a["move"] < b["move"])
            print(
                f"  pairs (odometry alone left out) whose relation errors differ by more than "
                f"{margin:.0%}: {alike} of {pairs} in the same order by consistency, "
                f"{moved} by revisit moves"
            )
    if args.stretches:
        stretches(name, rows, geometry, partners, args)


def _worst_windows(errors: np.ndarray, window: int, count: int) -> list[int]:
    """Starts of the ``count`` disjoint windows of ``window`` scans with the largest mean."""
    means = np.convolve(errors, np.ones(window) / window, mode="valid")
    taken: list[int] = []
    for start in np.argsort(-means, kind="stable"):
        if all(abs(int(start) - t) >= window for t in taken):
            taken.append(int(start))
        if len(taken) == count:
            break
    return taken


def stretches(
    name: str,
    rows: list[dict[str, Any]],
    geometry: ScanGeometry,
    partners: list[np.ndarray],
    args: argparse.Namespace,
) -> None:
    reference = rows[0]["poses"]
    ref_score: Consistency = rows[0]["score"]
    print(
        f"  stretches of {args.window} scans where ours and GMapping's disagree most "
        f"(after the ATE's alignment); consistency over the stretch's scans, ours / GMapping's:"
    )
    totals = np.zeros(3)
    ref_moves = rows[0]["moves"]
    for row in rows:
        if not row["label"].startswith("ours ") or "no loops" in row["label"]:
            continue
        ate = trajectory_error(row["poses"], reference)
        both = np.isfinite(row["moves"][:, 0]) & np.isfinite(ref_moves[:, 0])
        smaller = row["moves"][both, 0] < ref_moves[both, 0]
        print(
            f"    {row['label']}: over the {int(both.sum())} scans both place within reach, ours "
            f"needs the smaller move on {smaller.mean():.0%}; median move "
            f"{np.median(row['moves'][both, 0]) * 1000:.1f} / "
            f"{np.median(ref_moves[both, 0]) * 1000:.1f} mm, "
            f"{np.degrees(np.median(row['moves'][both, 1])):.2f} / "
            f"{np.degrees(np.median(ref_moves[both, 1])):.2f} deg"
        )
        for start in _worst_windows(ate.errors_m, args.window, args.stretches):
            part = np.zeros(len(reference), dtype=bool)
            part[start : start + args.window] = True
            ours, theirs = row["score"].mean_over(part), ref_score.mean_over(part)
            scored = part & np.isfinite(ref_score.per_scan_m)
            ours_move = np.median(row["moves"][scored, 0]) if scored.any() else np.nan
            ref_move = np.median(ref_moves[scored, 0]) if scored.any() else np.nan
            if scored.any():
                totals += (ours < theirs, ours_move < ref_move, 1)
            print(
                f"    {row['label']}: scans {start}-{start + args.window - 1}, disagreement "
                f"{ate.errors_m[part].mean():.3f} m (mean), {int(scored.sum())} scans with "
                f"partners: consistency {ours * 1000:6.2f} / {theirs * 1000:6.2f} mm, revisit "
                f"moves {ours_move * 1000:5.1f} / {ref_move * 1000:5.1f} mm"
            )
            if args.figures is not None and row["label"] == "ours 0":
                figure(
                    name,
                    start,
                    args.window,
                    row["poses"],
                    ate.alignment,
                    reference,
                    geometry,
                    partners,
                    args.figures,
                    (row["moves"], ref_moves),
                )
    print(
        f"  ours the more consistent on {int(totals[0])} of {int(totals[2])} stretches, "
        f"with the smaller revisit moves on {int(totals[1])}"
    )


def figure(  # noqa: PLR0917 - one call site, a bench's drawing
    name: str,
    start: int,
    window: int,
    ours: np.ndarray,
    alignment: np.ndarray,
    reference: np.ndarray,
    geometry: ScanGeometry,
    partners: list[np.ndarray],
    directory: Path,
    moves: tuple[np.ndarray, np.ndarray],
) -> None:
    """Left: the whole run under GMapping's poses (grey), both trajectories and, every few
    scans, ours minus GMapping's after the ATE's alignment, drawn 20 times longer, the
    stretch in red. Middle and right, 4 m across: the stretch's scan whose revisit moves
    differ most between the two trajectories (red) and its partners (blue), under ours and
    under GMapping's poses, where the red scan's placements differ most."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    placed = se2.compose(alignment, ours)
    stretch = np.arange(start, start + window)
    fig, axes = plt.subplots(1, 3, figsize=(21, 7))
    ax = axes[0]
    every = max(1, len(reference) // 3000)
    cloud = np.concatenate(
        [
            se2.transform_points(reference[k], geometry.queries[k])
            for k in range(0, len(reference), every)
        ]
    )
    ax.scatter(cloud[:, 0], cloud[:, 1], s=0.05, c="0.75", linewidths=0)
    ax.plot(reference[:, 0], reference[:, 1], "-", c="tab:green", lw=0.6, label="GMapping")
    ax.plot(placed[:, 0], placed[:, 1], "-", c="tab:purple", lw=0.6, label="ours, aligned")
    arrows = np.arange(0, len(reference), max(1, len(reference) // 150))
    d = placed[arrows, :2] - reference[arrows, :2]
    ax.quiver(
        reference[arrows, 0],
        reference[arrows, 1],
        d[:, 0] * 20,
        d[:, 1] * 20,
        angles="xy",
        scale_units="xy",
        scale=1,
        width=0.002,
        color="k",
    )
    ax.plot(reference[stretch, 0], reference[stretch, 1], "r-", lw=2, label="the stretch")
    ax.set_aspect("equal")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(f"{name}: ours minus GMapping's, x20 (arrows); scans {start}-{start + window - 1}")
    both = [k for k in stretch if np.isfinite(moves[0][k, 0]) and np.isfinite(moves[1][k, 0])]
    if both:
        # the scan whose two placements its partners judge most differently
        k = max(both, key=lambda j: abs(moves[0][j, 0] - moves[1][j, 0]))
        mates = partners[k]
        # centred where the two placements differ most among the red scan's points that lie
        # on a blue outline under either
        views = []
        for poses in (placed, reference):
            cloud = np.concatenate(
                [se2.transform_points(poses[j], geometry.outlines[j]) for j in mates]
            )
            mine = se2.transform_points(poses[k], geometry.queries[k])
            views.append((mine, cKDTree(cloud).query(mine)[0]))
        shared = (views[0][1] < 0.2) | (views[1][1] < 0.2)
        shift = np.abs(views[0][1] - views[1][1]) * shared
        at = int(np.argmax(shift))
        reach = 2.0
        for ax, poses, title, move, view in (
            (axes[1], placed, "ours (seed 0), aligned", moves[0][k], views[0]),
            (axes[2], reference, "GMapping's corrected poses", moves[1][k], views[1]),
        ):
            centre = view[0][at]  # the same point of the red scan, as each places it
            for group, colour, size in ((mates, "tab:blue", 2.0), (np.array([k]), "tab:red", 4.0)):
                pts = np.concatenate(
                    [se2.transform_points(poses[j], geometry.outlines[j]) for j in group]
                )
                ax.scatter(pts[:, 0], pts[:, 1], s=size, c=colour, linewidths=0)
            ax.set_xlim(centre[0] - reach, centre[0] + reach)
            ax.set_ylim(centre[1] - reach, centre[1] + reach)
            ax.set_aspect("equal")
            ax.set_title(
                f"{title}: scan {k} (red) on scans {', '.join(str(j) for j in mates)} (blue)\n"
                f"moves onto them by {move[0] * 1000:.0f} mm, {np.degrees(move[1]):.2f} deg",
                fontsize=9,
            )
    fig.tight_layout()
    directory.mkdir(parents=True, exist_ok=True)
    out = directory / f"{name}_stretch_{start}.png"
    fig.savefig(out, dpi=100)
    plt.close(fig)
    print(f"      figure: {out}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="intel,fr079,acapulco")
    parser.add_argument("--seeds", default="0,1,2,3,4")
    parser.add_argument("--poses", type=Path, default=None, help="keep/reuse our SLAM's poses")
    parser.add_argument("--extra", action="append", default=[], metavar="LABEL=DIR")
    parser.add_argument(
        "--gate", type=Path, default=None, help="ours from bench/gate.py --keep DIR instead"
    )
    parser.add_argument("--no-loops", action="store_true", help="ours without loop closures")
    parser.add_argument("--stretches", type=int, default=0)
    parser.add_argument("--window", type=int, default=25)
    parser.add_argument("--figures", type=Path, default=None)
    parser.add_argument("--min-travel", type=float, default=MIN_TRAVEL_M, help="a revisit's")
    parser.add_argument("--radius-scale", type=float, default=1.0, help="of a revisit's radius")
    parser.add_argument("--truncate", type=float, default=TRUNCATE_M, help="a point's distance")
    args = parser.parse_args()
    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.WARNING))
    for name in args.logs.split(","):
        bench_log(name, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
