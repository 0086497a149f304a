"""Mapping bench: the public laser logs and the simulated 46-minute six-floor run, scored and
timed against issue 14's bar.

    .venv/bin/python bench/mapping.py [--logs intel,fr079,acapulco] [--log-seeds 0,1,2,3,4]
                                      [--odometry default|strong|varied|exact]
                                      [--sim-seeds 0,1,2]
                                      [--minutes M] [--skip-logs] [--skip-sim] [--keep DIR]
                                      [--log-file NAME=PATH[,RELATIONS] ...] [--draws K]
                                      [--runs K] [--workers N] [--slam-resolution M]
                                      (--logs also takes bigloop: a synthetic 434 m loop)

Public logs (../shared/data/laser, or $BAROMAP_SHARED_DATA/laser): for each seed, odometry
synthesised from the GMapping-corrected poses (5 % scale, 2 deg/m heading drift, seeded noise),
SLAM over every scan, and beside it odometry alone: Kuemmerle relation errors where the log has
relations (Intel, Freiburg 079), absolute trajectory error against the corrected poses after a
rigid 2D alignment (all three), and the revisit consistency of the SLAM's poses and of the
corrected ones (baromap.mapping.revisits: how well each agrees with the scans where the
robot came back, no reference needed; lower is better). Bar: Intel relations <= 0.025 m and
<= 0.4 deg, ATE <= 0.05 m on Freiburg 079 and <= 0.10 m on Acapulco, for every seed.

Harder inputs, so the front end is not tuned to three logs (the logs kept outside the
repository are sparse: about one scan per metre, turns of up to 80 degrees between scans):
``NAME/N`` keeps every N-th scan of a log (``fr079/10``: about one scan per metre), with
odometry synthesised over those steps; ``NAME[a:b]`` (or ``NAME/N[a:b]``) takes scans a to b
of it first, e.g. a part before the robot comes back anywhere (``fr079[0:967]``), where only
the front end and the odometry calibration hold the map; ``--odometry strong`` uses a worse
error model of other signs (laser_logs.STRONG_ODOMETRY), ``--odometry varied`` a model drawn
per seed from a family of the default's size with random signs (laser_logs.varied_odometry),
printed under the seed's figures beside what the SLAM's calibration learnt of it;
``--odometry exact`` feeds the corrected poses themselves (no error); ``--slam-resolution
M`` maps the logs with the SLAM's cell (its fields' cell and sigma, its voxel filter) at M. Under
each seed's row its shape: the ATE left after a similarity (one scale besides the rigid
motion) and the size of our trajectory against the reference's. The harder inputs'
figures are printed without a verdict: the bar is issue 14's, on the logs as published with
the default model.

A synthetic input with a truth, ``bigloop`` (baromap.sim.big_loop; written once into
~/.cache/baromap or $BAROMAP_CACHE, no data directory needed): a corridor ring of 60-120 m
a side driven once round and 40 m on, a scan every half metre, its true poses as the
corrected ones, scored like the logs (``bigloop/3``, ``--odometry strong``, ...): the first
revisit after hundreds of metres of drift, which the public logs never make. Under every
seed's row: the loop closures' attempts (wide: branch and bound over metres), the refused
(implausible, ambiguous, unframed: the map reaches past the window on one side only and
the correction is beyond the capped window), those kept against a one-sided map until the
visit ends and how many of them were taken (none where a closure framed on both sides came
after), the accepted, and the largest correction one made (the front end's drift at the
revisit).

One run's figure is one draw of a spread: the SLAM's discrete choices (which candidate a
search keeps, which closure passes its threshold) flip under changes of the input far below any
sensor's noise. ``--draws K`` runs every seed K times, the odometry of draws 1..K-1 perturbed by
half a micrometre (``laser_logs.DRAW_PERTURBATION``: the rounding of a log printed to six
decimals), and prints each seed's spread (min-median-max) under its row and, beside the
verdict, the worst figures over every seed's draws; the verdict itself is on draw 0, the
odometry as synthesised.

Each seed (and each draw) is mapped ``--runs K`` times (default 1), runs 2.. with the odometry
moved by a micrometre, and the run whose revisits agree best with the scans is kept
(baromap.mapping.restarts; no reference is used to choose): a sparse log's wrong turn that the
closures did not put right is one draw, not the log's figure. ``--runs 1`` maps once; a log
costs K times its run's CPU. A line under the seed's row says which run was kept. ``--workers
N`` (default: the machine's CPUs) makes runs 2.. in other processes while the first is made:
the same runs, bit for bit, about two thirds of the time on two CPUs (the time column is the
wall time). The simulated run is built as ``baromap build-maps`` builds it, once.

Any other CARMEN log with corrected poses (e.g. the PLE collection's ``*-corrected.log.gz``)
runs through the same code: ``--log-file edmonton=/data/edmonton-corrected.log.gz --logs
edmonton,edmonton/2`` (with ``,RELATIONS`` a relations file beside it); its figures are printed
without a verdict. Without ``--logs``, the logs given by ``--log-file`` are the ones run
(``--log-file freiburg-101=/data/freiburg-101-corrected.log.gz`` alone runs that log).

Simulated run: for each seed, records it (``baromap sim record``), then runs ``build-maps`` in
a child process (its own peak memory, ru_maxrss, plus that of the build's painter process) and
prints the run's duration over the wall time beside the wall time, the CPU time of both
processes (the figure the machine's load does not inflate), then scores the maps against the
true plans and path (baromap.evaluation.mapping). Bar: >= 100x real time on 2 cores, <= 1 GB;
the whole building under one rigid transform within 0.05 m RMS and 0.20 m of the true path,
every floor's walls (occupied cells within 10 cm of a true wall) >= 0.95 under that transform.
The machine's load is printed beside every time: a busy machine slows the ratio, not the maps.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
LASER = Path(os.environ.get("BAROMAP_SHARED_DATA", REPO.parent / "shared" / "data")) / "laser"

#: Issue 14's bar.
INTEL_TRANS_M = 0.025
INTEL_ROT_DEG = 0.4
ATE_BAR_M = {"fr079": 0.05, "acapulco": 0.10}
REAL_TIME_RATIO = 100.0
PEAK_MB = 1024.0


#: The logs issue 14's bar is on, run when neither --logs nor --log-file says otherwise.
PUBLISHED_LOGS = "intel,fr079,acapulco"
#: Runs of the SLAM per log seed, the best agreeing with its scans kept (--runs), as
#: build-maps maps by default: once. Three runs on the gate's sparse cases (fr079/10, its slip
#: and pauses variants, intel/2; seed 0) kept the first run every time, at 2.1-2.5 times its
#: CPU (docs/mapping-gate.md); a log as sparse as fr079/30 can still gain from --runs 3.
LOG_RUNS = 1


def _quiet() -> None:
    import logging

    import structlog

    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.WARNING))


def _load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.1f} (5 min {five:.1f}) on {os.cpu_count()} cpus"


def child_build(recording: str, out: str) -> None:
    """Runs in a fresh process so ru_maxrss is the build's own peak."""
    _quiet()
    from baromap.evaluation.mapping import evaluate_recording
    from baromap.mapping.build import build_maps

    start = time.perf_counter()
    cpu = time.process_time()
    result = build_maps(recording, out)
    wall = time.perf_counter() - start
    cpu = time.process_time() - cpu
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    # the build's second process (build.py's painter) has been joined: its CPU and peak
    painter = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = result.run.scans.t_ns
    duration_s = float(t[-1] - t[0]) / 1e9
    report = evaluate_recording(result, recording)
    print(
        json.dumps(
            {
                "wall_s": wall,
                "cpu_s": cpu,
                "painter_cpu_s": painter.ru_utime + painter.ru_stime,
                "duration_s": duration_s,
                "peak_mb": peak_mb,
                "painter_peak_mb": painter.ru_maxrss / 1024,
                "load": _load(),
                "timings": result.timings_s,
                "stats": result.slam.stats,
                "report": report.lines(),
                "rms": report.trajectory_rms_m,
                "max": report.trajectory_max_m,
                "passed_building": report.passed_building(),
                "passed": report.passed(),
            }
        )
    )


def _stat(value: float) -> str:
    """A SLAM stat as printed: counts as integers, the rest (a score, NaN where there was
    nothing to score) as they are."""
    return str(int(value)) if float(value).is_integer() else f"{value:.1f}"


def bench_sim(seed: int, minutes: float, keep: Path | None) -> bool:
    work = keep or Path(tempfile.mkdtemp(prefix="baromap-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    run = work / f"sim{seed}.mcap"
    start = time.perf_counter()
    subprocess.run(
        [
            sys.executable,
            "-m",
            "baromap.cli",
            "--log-level",
            "WARNING",
            "sim",
            "record",
            "-o",
            str(run),
            "--minutes",
            str(minutes),
            "--floors",
            "6",
            "--seed",
            str(seed),
            "--force",
        ],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    took = time.perf_counter() - start
    print(f"seed {seed}: recorded {minutes:g} simulated minutes in {took:.1f} s")
    out = subprocess.run(
        [sys.executable, __file__, "--child-build", str(run), str(work / f"maps{seed}")],
        check=True,
        capture_output=True,
        text=True,
    )
    data = json.loads(out.stdout.strip().splitlines()[-1])
    ratio = data["duration_s"] / data["wall_s"]
    # both processes' peaks count against the memory bar: they are alive together
    peak = data["peak_mb"] + data["painter_peak_mb"]
    fast = ratio >= REAL_TIME_RATIO and peak <= PEAK_MB
    print(
        f"  build-maps: {ratio:.0f}x real time ({data['duration_s']:.0f} s of run in "
        f"{data['wall_s']:.1f} s wall), peak {peak:.0f} MB "
        f"[bar >= {REAL_TIME_RATIO:.0f}x, <= {PEAK_MB:.0f} MB: {'met' if fast else 'NOT met'}]; "
        f"{data['load']}"
    )
    cpu = data["cpu_s"] + data["painter_cpu_s"]
    print(
        f"  cpu (load-independent): {cpu:.1f} s = {data['cpu_s']:.1f} s main process + "
        f"{data['painter_cpu_s']:.1f} s painter; run duration over main-process cpu "
        f"{data['duration_s'] / data['cpu_s']:.0f}x; peaks {data['peak_mb']:.0f} MB main + "
        f"{data['painter_peak_mb']:.0f} MB painter"
    )
    print("  stages: " + ", ".join(f"{k} {v:.1f} s" for k, v in data["timings"].items()))
    print("  " + ", ".join(f"{k} {_stat(v)}" for k, v in data["stats"].items()))
    for line in data["report"]:
        print("  " + line)
    print(
        f"  building under one transform: {data['rms']:.3f} m RMS, max {data['max']:.3f} m, "
        f"walls >= 0.95 on every floor [bar: {'met' if data['passed_building'] else 'NOT met'}]; "
        f"per-floor bar (maps, lobby, heights, no cross-floor closure): "
        f"{'met' if data['passed'] else 'NOT met'}"
    )
    return bool(data["passed_building"]) and fast


def _spread(values: list[float], digits: int) -> str:
    low, mid, high = min(values), float(np.median(values)), max(values)
    return f"{low:.{digits}f}-{mid:.{digits}f}-{high:.{digits}f}"


def bench_logs(
    specs: list[str],
    seeds: list[int],
    *,
    odometry: str = "default",
    draws: int = 1,
    runs: int = 1,
    workers: int = 1,
    slam_resolution: float | None = None,
) -> bool:
    _quiet()
    from baromap.mapping.slam.settings import SlamConfig

    config = SlamConfig() if slam_resolution is None else SlamConfig(resolution_m=slam_resolution)
    from baromap.evaluation.laser_logs import (
        LOGS,
        PreparedLog,
        describe_odometry,
        odometry_model,
        parse_log_spec,
        run_prepared,
    )
    from baromap.evaluation.trajectory import similarity_error

    ok = True
    for shown in specs:
        spec = parse_log_spec(shown)
        name = spec.name
        # the bar applies to the public logs as published, with the default odometry model
        judged = spec.published and odometry == "default" and LOGS[name].world is None
        name_shown = shown if odometry == "default" else f"{shown} ({odometry} odometry)"
        print(f"{name_shown}: {'seed':>4}  {'odometry alone':>34}  {'SLAM':>34}  {'time':>6}")
        rel_t, rel_r, ates, cons = [], [], [], []
        # per seed, every draw's ATE and relation errors (draw 0 first)
        drawn: list[tuple[list[float], list[float], list[float]]] = []
        # the scans, relations and the corrected poses' revisit score are every seed's: once
        prepared = PreparedLog(LASER, name, scans=spec.scans, stride=spec.stride)
        for seed in seeds:
            model = odometry_model(odometry, seed)
            rep = run_prepared(
                prepared,
                seed,
                config=config,
                odometry=model,
                score_consistency=True,
                runs=runs,
                workers=workers,
            )
            cells = []
            for label, rel, ate in (
                ("odometry", rep.odometry_relations, rep.odometry_ate),
                ("slam", rep.slam_relations, rep.slam_ate),
            ):
                text = f"ATE {ate.rms_m:7.3f} m"
                if rel is not None:
                    text += f", rel {rel.trans_mean:6.4f} m {rel.rot_mean:5.3f} deg"
                cells.append(text)
                if label == "slam":
                    ates.append(ate.rms_m)
                    if rel is not None:
                        rel_t.append(rel.trans_mean)
                        rel_r.append(rel.rot_mean)
            if (
                rep.slam_consistency is not None
                and rep.reference_consistency is not None
                and np.isfinite(rep.slam_consistency.mean_m)  # a part may hold no revisit
            ):
                cons.append((rep.slam_consistency.mean_m, rep.reference_consistency.mean_m))
            print(
                f"{'':{len(name_shown)}}  {seed:>4}  {cells[0]:>34}  {cells[1]:>34}  "
                f"{rep.seconds:5.1f} s"
            )
            st = {k: int(v) for k, v in rep.result.stats.items() if k.startswith("loop")}
            print(
                f"{'':{len(name_shown)}}        loops: {st.get('loop_attempts', 0)} attempts "
                f"({st.get('loop_wide_attempts', 0)} wide), refused "
                f"{st.get('loop_implausible', 0)} implausible, {st.get('loop_ambiguous', 0)} "
                f"ambiguous, {st.get('loop_unframed', 0)} unframed; "
                f"{st.get('loop_beyond_drift', 0)} beyond the drift proposed "
                f"({st.get('loop_followed', 0)} confirmed where they put the robot, "
                f"{st.get('loop_groups_one_scan', 0)} by a second submap of the same scan), "
                f"{st.get('loop_deferred', 0)} kept one-sided, "
                f"{st.get('loop_deferred_taken', 0)} of them taken; {st.get('loops', 0)} "
                f"accepted, largest correction {st.get('loop_max_correction_mm', 0) / 1000:.2f} m"
            )
            sim, scale = similarity_error(rep.result.scan_poses, prepared.reference)
            print(
                f"{'':{len(name_shown)}}        shape: ATE after a similarity {sim:.3f} m, ours "
                f"{100.0 * (1.0 / scale - 1.0):+.2f} % in size against the reference"
            )
            if runs > 1:
                made, kept = int(rep.result.stats["runs"]), int(rep.result.stats["run_kept"])
                procs = int(rep.result.stats["run_processes"])
                text = (
                    f"{made} of {runs} in {procs} process{'es' if procs > 1 else ''}, "
                    f"kept run {kept + 1} (its revisits {rep.result.stats['revisits_mm']:.1f} mm)"
                    if made > 1
                    else f"1 of {runs}: no revisit to choose by"
                )
                print(f"{'':{len(name_shown)}}        runs: {text}")
            if draws > 1:
                d_ate, d_t, d_r = [ates[-1]], rel_t[-1:], rel_r[-1:]
                for draw in range(1, draws):
                    more = run_prepared(
                        prepared,
                        seed,
                        config=config,
                        odometry=model,
                        draw=draw,
                        runs=runs,
                        workers=workers,
                    )
                    d_ate.append(more.slam_ate.rms_m)
                    if more.slam_relations is not None:
                        d_t.append(more.slam_relations.trans_mean)
                        d_r.append(more.slam_relations.rot_mean)
                drawn.append((d_ate, d_t, d_r))
                text = f"ATE {_spread(d_ate, 3)} m"
                if d_t:
                    text += f", rel {_spread(d_t, 4)} m {_spread(d_r, 3)} deg"
                print(f"{'':{len(name_shown)}}        {draws} draws (min-median-max): {text}")
            if odometry == "varied":
                # the drawn model, and what the SLAM's odometry calibration learnt of it
                dist, turn, creep = rep.result.odometry_correction
                t_dist, t_turn, t_creep = model.correction()
                print(
                    f"{'':{len(name_shown)}}        drawn: {describe_odometry(model)}; learnt "
                    f"distance {dist:.4f} (true {t_dist:.4f}), turn {turn:+.4f} (true "
                    f"{t_turn:+.4f}), creep {math.degrees(creep):+.2f} deg/m (true "
                    f"{math.degrees(t_creep):+.2f})"
                )
        verdict = []
        if name == "intel" and judged:
            met = max(rel_t) <= INTEL_TRANS_M and max(rel_r) <= INTEL_ROT_DEG
            verdict.append(
                f"relations worst {max(rel_t):.4f} m, {max(rel_r):.3f} deg (bar {INTEL_TRANS_M} m,"
                f" {INTEL_ROT_DEG} deg: {'met' if met else 'NOT met'})"
            )
            ok &= met
        if name in ATE_BAR_M and judged:
            met = max(ates) <= ATE_BAR_M[name]
            state = "met" if met else "NOT met"
            verdict.append(f"ATE worst {max(ates):.3f} m (bar {ATE_BAR_M[name]} m: {state})")
            ok &= met
        if rel_t and not (name == "intel" and judged):
            verdict.append(f"relations mean {np.mean(rel_t):.4f} m, {np.mean(rel_r):.3f} deg")
        if rep.reference_relations is not None:
            ref = rep.reference_relations
            verdict.append(
                f"the ATE's reference (corrected poses) itself on the relations "
                f"{ref.trans_mean:.4f} m, {ref.rot_mean:.3f} deg"
            )
        if not judged:
            verdict.append(f"ATE worst {max(ates):.3f} m (no bar: a harder input)")
        elif name not in ATE_BAR_M and name != "intel":
            verdict.append(f"ATE worst {max(ates):.3f} m (no bar: a log given by --log-file)")
        verdict.append(f"ATE mean {np.mean(ates):.3f} m")
        if drawn:
            worst = [max(d_ate) for d_ate, _, _ in drawn]
            verdict.append(
                f"over {draws} draws the worst seed's ATE {max(worst):.3f} m, the mean of every "
                f"draw {np.mean([v for d_ate, _, _ in drawn for v in d_ate]):.3f} m"
            )
            if all(d_t for _, d_t, _ in drawn):
                verdict.append(
                    f"relations worst over the draws {max(max(d_t) for _, d_t, _ in drawn):.4f} m,"
                    f" {max(max(d_r) for _, _, d_r in drawn):.3f} deg"
                )
        if cons:
            ours, ref = np.array(cons).T * 1000
            verdict.append(
                f"revisit consistency {ours.min():.1f}-{ours.max():.1f} mm, the corrected "
                f"poses' {ref[0]:.1f} mm (lower: the scans agree better; docs/mapping.md)"
            )
        print(f"{'':{len(name_shown)}}  " + "; ".join(verdict) + f"; {_load()}")
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"logs' peak memory {peak_mb:.0f} MB (this process: imports plus the runs above)")
    helpers = min(workers, runs) - 1  # runs 2.. shared among at most this many
    if helpers > 0:
        worker_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        print(
            f"the restarts' worker processes: up to {helpers}, the largest's peak "
            f"{worker_mb:.0f} MB (forked: what it shares with this process counts in both)"
        )
    return ok


def _ints(text: str) -> list[int]:
    return [int(v) for v in text.split(",") if v]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--logs",
        default=None,
        help="comma-separated: intel, fr079, acapulco (public CARMEN logs) or bigloop (a "
        "synthetic corridor ring of 60-120 m a side with a truth: the first revisit after "
        "hundreds of metres); NAME/N keeps every N-th scan, NAME[a:b] scans a to b "
        f"(default: {PUBLISHED_LOGS}, or the logs of --log-file when it is given)",
    )
    parser.add_argument("--log-seeds", default="0,1,2,3,4")
    parser.add_argument(
        "--odometry", default="default", choices=("default", "strong", "varied", "exact")
    )
    parser.add_argument(
        "--slam-resolution",
        type=float,
        default=None,
        metavar="M",
        help="the SLAM's cell on the logs (SlamConfig.resolution_m)",
    )
    parser.add_argument("--sim-seeds", default="0,1,2")
    parser.add_argument("--minutes", type=float, default=46.0)
    parser.add_argument("--skip-logs", action="store_true")
    parser.add_argument("--skip-sim", action="store_true")
    parser.add_argument("--keep", type=Path, default=None, help="keep the runs and maps here")
    parser.add_argument(
        "--log-file",
        action="append",
        default=[],
        metavar="NAME=PATH[,RELATIONS]",
        help="a CARMEN log with corrected poses, then named in --logs",
    )
    parser.add_argument(
        "--draws",
        type=int,
        default=1,
        metavar="K",
        help="run every log seed K times, draws 1.. with the odometry perturbed by half a "
        "micrometre, and print the spread (default 1: the odometry as synthesised only)",
    )
    parser.add_argument(
        "--runs",
        type=int,
        default=LOG_RUNS,
        metavar="K",
        help="map every log seed K times, runs 2.. with the odometry moved by a micrometre, "
        f"and keep the run whose revisits agree best with the scans (default {LOG_RUNS}; "
        "baromap.mapping.restarts)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=os.cpu_count() or 1,
        metavar="N",
        help="processes to make a seed's runs in, this one among them: the same runs, sooner "
        "(default: the machine's CPUs, here %(default)s)",
    )
    parser.add_argument("--child-build", nargs=2, metavar=("RUN", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.draws < 1:
        parser.error("--draws: at least 1")
    if args.runs < 1:
        parser.error("--runs: at least 1")
    if args.workers < 1:
        parser.error("--workers: at least 1")
    if args.child_build:
        child_build(*args.child_build)
        return 0
    ok = True
    if not args.skip_sim:
        for seed in _ints(args.sim_seeds):
            ok &= bench_sim(seed, args.minutes, args.keep)
    if not args.skip_logs:
        from baromap.errors import ConfigError
        from baromap.evaluation.laser_logs import LOGS, parse_log_spec, register_log

        given = []
        for text in args.log_file:
            name, _, paths = text.partition("=")
            log_path, _, relations = paths.partition(",")
            try:
                register_log(name, log_path, relations or None)
            except ConfigError as exc:
                parser.error(f"--log-file {text}: {exc}")
            given.append(name)
        # a log given by path is meant to be run: without --logs, those are the inputs
        specs = (args.logs or ",".join(given) or PUBLISHED_LOGS).split(",")
        if not LASER.is_dir():
            # the synthetic logs and those of --log-file (absolute paths) need no data directory
            known = [(s, LOGS[parse_log_spec(s).name]) for s in specs]
            kept = [
                s for s, log in known if log.world is not None or Path(log.log_file).is_absolute()
            ]
            print(f"laser logs not found at {LASER}: skipped {', '.join(set(specs) - set(kept))}")
            specs = kept
        if specs:
            ok &= bench_logs(
                specs,
                _ints(args.log_seeds),
                odometry=args.odometry,
                draws=args.draws,
                runs=args.runs,
                workers=args.workers,
                slam_resolution=args.slam_resolution,
            )
    # figures are printed either way; the exit status says whether every target was met
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
