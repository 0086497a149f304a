"""``baromap detect`` (floors in a recording, CSV or IPIN log) and ``baromap eval-floors``."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

REAL_DATA_HINT = "directory of IPIN 2023 barometer logs with floor waypoints (*.txt)"


def register(subparsers: Any) -> None:
    detect = subparsers.add_parser(
        "detect", help="detect floors and transitions from barometric pressure"
    )
    detect.add_argument(
        "input", help="recording (.mcap), CSV time_s,pressure_pa[,temp] or IPIN log"
    )
    detect.add_argument("--method", choices=("online", "paper"), default="online")
    detect.add_argument(
        "--reference",
        help="reference station pressure (CSV or recording); a recording's own "
        "/reference/pressure is used when present",
    )
    detect.add_argument(
        "--odom",
        metavar="RECORDING",
        help="the robot's odometry (/odom of a recording): a stop at a floor is a visit once "
        "the robot drove off; a recording's own /odom is used when present",
    )
    detect.add_argument(
        "--no-odom", action="store_true", help="ignore odometry (visits by dwell time only)"
    )
    _naming_arguments(detect)
    detect.add_argument("--json", action="store_true", help="print JSON instead of tables")
    detect.add_argument("--plot", metavar="PNG", help="draw raw, smoothed, rate and transitions")
    detect.set_defaults(run=run_detect)

    evaluate = subparsers.add_parser(
        "eval-floors", help="score floor detection against ground truth"
    )
    evaluate.add_argument("input", nargs="?", help="IPIN log or recording with /truth/floor")
    evaluate.add_argument("--method", choices=("online", "paper", "both"), default="both")
    evaluate.add_argument("--reference", help="reference station pressure (CSV or recording)")
    evaluate.add_argument("--json", action="store_true")
    evaluate.add_argument("--real", metavar="DIR", help=REAL_DATA_HINT)
    evaluate.add_argument(
        "--sim-seeds",
        type=int,
        default=0,
        metavar="N",
        help="also score N simulated runs (seeds FIRST..FIRST+N-1)",
    )
    evaluate.add_argument("--first-seed", type=int, default=0, metavar="FIRST")
    evaluate.add_argument(
        "--sweep",
        action="store_true",
        help="with --real: how robust the online method is to its settings on the real logs",
    )
    evaluate.add_argument("--drift", type=float, default=1.5, help="simulated drift, hPa/h")
    evaluate.add_argument("--minutes", type=float, default=46.0, help="simulated run length")
    evaluate.add_argument(
        "--use-reference",
        action="store_true",
        help="give the simulated reference station to the detectors",
    )
    evaluate.add_argument(
        "--no-odom",
        action="store_true",
        help="withhold the simulated robot's odometry (visits by dwell time only)",
    )
    evaluate.add_argument(
        "--stops",
        choices=("none", "stay", "leave"),
        default="none",
        help="simulated rides past a floor stop there: the robot stays in the car, or leaves "
        "it to make room and comes back",
    )
    evaluate.add_argument(
        "--route", metavar="F,F,...", help="simulated floors in visiting order (0 = ground)"
    )
    evaluate.set_defaults(run=run_eval)


def _naming_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--min-height",
        type=float,
        default=None,
        metavar="M",
        help="minimum transition height in metres (default 1.8)",
    )
    parser.add_argument(
        "--start-floor", metavar="NAME", help="name of the floor the run starts on (default 0)"
    )
    parser.add_argument(
        "--building",
        metavar="YAML",
        help="building.yaml of an earlier run: floors named by their height",
    )


def _config(args: argparse.Namespace) -> Any:
    from baromap.floors.building_model import load_building_model
    from baromap.floors.config import FloorDetectorConfig

    changes: dict[str, Any] = {}
    if getattr(args, "min_height", None) is not None:
        changes["min_transition_m"] = args.min_height
    if getattr(args, "building", None):
        changes["building"] = load_building_model(args.building)
    if getattr(args, "start_floor", None) is not None:
        changes["start_floor"] = args.start_floor
    return FloorDetectorConfig(**changes)


def _reference(path: str | None, fallback: Any) -> Any:
    from baromap.floors.inputs import load_reference

    series = load_reference(path) if path else fallback
    return None if series is None else (series.t_ns, series.pressure_pa)


def _odometry(args: argparse.Namespace, fallback: Any) -> Any:
    from baromap.errors import ConfigError
    from baromap.floors.inputs import load_odometry

    if args.no_odom:
        if args.odom:
            raise ConfigError("--odom and --no-odom contradict each other")
        return None
    return load_odometry(args.odom) if args.odom else fallback


def run_detect(args: argparse.Namespace) -> int:
    from baromap.floors.detection import detect_floors
    from baromap.floors.inputs import load_input

    config = _config(args)
    data = load_input(args.input)
    s = data.series
    odometry = _odometry(args, data.odometry)
    detection = detect_floors(
        s.t_ns,
        s.pressure_pa,
        s.temperature_c,
        method=args.method,
        reference=_reference(args.reference, data.reference),
        config=config,
        odometry=odometry,
    )
    if args.plot:
        from baromap.floors.plot import plot_detection

        plot_detection(detection, s.t_ns, s.pressure_pa, args.plot)
    if args.json:
        json.dump(detection.to_json(), sys.stdout, indent=2)
        print()
        return 0
    fused = "with odometry" if odometry is not None else "without odometry"
    print(f"{args.input}: {s.t_ns.size} samples, {data.kind}, method {args.method}, {fused}")
    print(f"{'floor':>5s} {'name':>8s} {'level hPa':>10s} {'elevation m':>11s} {'visits':>6s}")
    for f in detection.floors:
        print(
            f"{f.index:5d} {f.name or '-':>8s} {f.level_pa / 100:10.2f} {f.elevation_m:11.2f} "
            f"{f.visits:6d}"
        )
    print(f"{len(detection.transitions)} transitions")
    names = {f.index: f.name or str(f.index) for f in detection.floors}
    for tr in detection.transitions:
        print(
            f"  {tr.t_start_ns / 1e9:9.1f} .. {tr.t_end_ns / 1e9:9.1f} s  floor "
            f"{names[tr.from_floor]} -> {names[tr.to_floor]}  {tr.delta_m:+6.2f} m  "
            f"(decided at {tr.t_detect_ns / 1e9:.1f} s" + (", end of input)" if tr.at_end else ")")
        )
    if args.plot:
        print(f"plot: {args.plot}")
    return 0


def run_eval(args: argparse.Namespace) -> int:
    from baromap.errors import ConfigError
    from baromap.evaluation.floors import SimSettings, evaluate_case, run_report

    methods = ("online", "paper") if args.method == "both" else (args.method,)
    if args.input is None and args.real is None and args.sim_seeds <= 0:
        raise ConfigError("give an INPUT, --real DIR or --sim-seeds N")
    if args.input is not None:
        from baromap.evaluation.floors import Case
        from baromap.floors.inputs import load_input

        data = load_input(args.input)
        if data.truth is None:
            raise ConfigError(f"{args.input} carries no ground truth (POSI lines or /truth/floor)")
        s = data.series
        case = Case(
            str(args.input),
            "input",
            s.t_ns,
            s.pressure_pa,
            s.temperature_c,
            data.truth,
            _reference(args.reference, data.reference),
            None if args.no_odom else data.odometry,
        )
        results = [evaluate_case(case, m) for m in methods]
        if args.json:
            json.dump({r.method: _result_json(r) for r in results}, sys.stdout, indent=2)
            print()
            return 0
        print(HEADER)
        for result in results:
            _print_result(result, str(args.input))
    if args.sweep:
        if args.real is None:
            raise ConfigError("--sweep needs --real DIR")
        _print_sweep(args.real)
        return 0
    if args.real is None and args.sim_seeds <= 0:
        return 0
    seeds = list(range(args.first_seed, args.first_seed + max(args.sim_seeds, 0)))
    sim = SimSettings(
        drift_hpa_per_h=args.drift,
        minutes=args.minutes,
        use_reference=args.use_reference,
        use_odometry=not args.no_odom,
        stops=args.stops,
        route=_route(args.route),
    )
    print(HEADER)
    report = run_report(
        args.real, seeds, methods, sim=sim, on_result=lambda r: _print_result(r, r.name)
    )
    if seeds:
        print(
            f"simulated: {len(seeds)} seeds ({seeds[0]}-{seeds[-1]}) x {sim.minutes:g} min, "
            f"drift {sim.drift_hpa_per_h:g} hPa/h, "
            + ("reference station used" if sim.use_reference else "no reference station")
            + (", odometry used" if sim.use_odometry else ", no odometry")
            + ("" if sim.stops == "none" else f", stops on the way: {sim.stops}")
        )
        for method in methods:
            for line in _summary(method, report.totals[method]):
                print(line)
    return 0


def _route(text: str | None) -> tuple[int, ...] | None:
    from baromap.errors import ConfigError

    if text is None:
        return None
    try:
        return tuple(int(part) for part in text.split(","))
    except ValueError as exc:
        raise ConfigError(f"--route must be floor numbers separated by commas: {text!r}") from exc


HEADER = (
    f"{'case':34s} {'method':11s} {'true':>4s} {'found':>5s} {'miss':>4s} {'false':>5s} "
    f"{'dir':>4s} {'stor':>4s} {'acc%':>6s} {'delay med/max s':>16s} {'height err m':>12s}"
)


def _line(name: str, method: str, s: Any, extra: str = "", *, delays: bool = True) -> str:
    delay = f"{'-':>13s}"
    if delays and s.delays_s:
        delay = f"{s.median_delay_s:6.1f}/{s.max_delay_s:6.1f}"
    height = f"{s.height_error_m:12.2f}" if s.height_error_m is not None else f"{'-':>12s}"
    accuracy = f"{100 * s.accuracy:6.1f}" if math.isfinite(s.accuracy) else f"{'-':>6s}"
    return (
        f"{name[-34:]:34s} {method:11s} {s.true:4d} {s.found:5d} {s.missed:4d} {s.false:5d} "
        f"{s.direction_right:4d} {s.storeys_right:4d} {accuracy} {delay:>16s} {height}{extra}"
    )


def _print_result(result: Any, name: str) -> None:
    flushed = " (last at end of log)" if result.post_run.flushed else ""
    # post-run bounds are tightened with hindsight; when it was decided is a live figure
    print(_line(name, f"{result.method} post", result.post_run, flushed, delays=False))
    live = result.live
    if live is not None:
        notes = f"  {live.events} events, {live.corrections} corrections ({live.moves} moving)"
        if live.retractions:
            notes += f", {live.retractions} retractions"
        notes += ", = post-run" if live.agrees else f", DIFFERS from post-run: {live.disagreement}"
        print(_line(name, f"{result.method} live", live.score, notes))


def _summary(method: str, totals: Any) -> list[str]:
    from baromap.evaluation.floors import percentile

    post = totals.post_run
    lines = [
        f"  {method:6s} post-run: recall {100 * post.recall:5.1f} %  precision "
        f"{100 * post.precision:5.1f} %  ({post.found}/{post.true} found, {post.false} false)  "
        f"direction right {post.direction}/{post.found}  storeys right "
        f"{post.storeys}/{post.found}  mean accuracy {100 * post.mean_accuracy:5.1f} %  "
        f"worst height error {post.height_max:.2f} m"
    ]
    if totals.live_cases:
        live = totals.live
        lines.append(
            f"  {method:6s} live:     recall {100 * live.recall:5.1f} %  precision "
            f"{100 * live.precision:5.1f} %  ({live.found}/{live.true} found, {live.false} "
            f"false)  storeys right {live.storeys}/{live.found}  live-state accuracy "
            f"{100 * live.mean_accuracy:5.1f} %  {totals.events} events, "
            f"{totals.corrections} corrections ({totals.moves} moving the robot to another "
            f"floor), {totals.retractions} retractions; live = post-run on "
            f"{totals.agreeing}/{totals.live_cases} runs"
        )
        lines.append(
            f"  {method:6s} live decision delay: after the pressure settles p50 "
            f"{percentile(live.settled_delays, 50):.1f} s, p95 "
            f"{percentile(live.settled_delays, 95):.1f} s; after the car stops p50 "
            f"{percentile(live.delays, 50):.1f} s, p95 {percentile(live.delays, 95):.1f} s"
        )
        if totals.rides:
            lines.append(_ride_line(method, totals.rides))
    return lines


def _ride_line(method: str, rides: Any) -> str:
    from baromap.evaluation.floor_live import percentile, ride_delays

    delays, right, total = ride_delays(rides)
    announced = sum(r.announced for r in rides)
    withdrawn = sum(r.withdrawn for r in rides)
    return (
        f"  {method:6s} rides: ride_started after the car starts p50 "
        f"{percentile(delays, 50):.1f} s, p95 {percentile(delays, 95):.1f} s "
        f"(announced the right way for {right}/{total} true rides); {announced} announced, "
        f"{withdrawn} withdrawn"
    )


def _print_sweep(directory: str) -> None:
    from baromap.evaluation.floors import real_sweep

    result = real_sweep(directory)
    print(f"online method on {result.cases} real logs: combinations meeting the bar, per setting")
    for (key, value), (good, total) in result.passed.items():
        print(f"  {key:18s} {value:5g}: {good:4d}/{total}")


def _result_json(result: Any) -> dict[str, Any]:
    out = {"post_run": _score_json(result.post_run)}
    if result.live is not None:
        out["live"] = {
            **_score_json(result.live.score),
            "events": result.live.events,
            "corrections": result.live.corrections,
            "corrections_moving": result.live.moves,
            "retractions": result.live.retractions,
            "equals_post_run": result.live.agrees,
        }
        rides = result.live.rides
        if rides is not None:
            out["live"]["rides"] = {
                "started_delays_s": [d for d, _ in rides.started],
                "started_direction_right": [ok for _, ok in rides.started],
                "announced": rides.announced,
                "withdrawn": rides.withdrawn,
            }
    return out


def _score_json(s: Any) -> dict[str, Any]:
    return {
        "true": s.true,
        "found": s.found,
        "missed": s.missed,
        "false": s.false,
        "direction_right": s.direction_right,
        "storeys_right": s.storeys_right,
        "accuracy": s.accuracy,
        "floor_offset": s.offset,
        "delays_s": list(s.delays_s),
        "height_error_m": s.height_error_m,
        "decided_at_end_of_input": s.flushed,
    }
