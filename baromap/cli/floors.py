"""``baromap detect`` (floors in a recording, CSV or IPIN log) and ``baromap eval-floors``."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

REAL_DATA_HINT = "directory of IPIN logs (e.g. ../shared/data/baro)"


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
        "--min-height",
        type=float,
        default=None,
        metavar="M",
        help="minimum transition height in metres (default 1.8)",
    )
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
        help="also score N simulated runs (seeds 0..N-1)",
    )
    evaluate.add_argument("--first-seed", type=int, default=0)
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
    evaluate.set_defaults(run=run_eval)


def _config(args: argparse.Namespace) -> Any:
    from baromap.floors.config import FloorDetectorConfig

    if getattr(args, "min_height", None) is None:
        return FloorDetectorConfig()
    return FloorDetectorConfig(min_transition_m=args.min_height)


def _reference(path: str | None, fallback: Any) -> Any:
    from baromap.floors.inputs import load_reference

    series = load_reference(path) if path else fallback
    return None if series is None else (series.t_ns, series.pressure_pa)


def run_detect(args: argparse.Namespace) -> int:
    from baromap.floors.detection import detect_floors
    from baromap.floors.inputs import load_input

    data = load_input(args.input)
    s = data.series
    detection = detect_floors(
        s.t_ns,
        s.pressure_pa,
        s.temperature_c,
        method=args.method,
        reference=_reference(args.reference, data.reference),
        config=_config(args),
    )
    if args.plot:
        from baromap.floors.plot import plot_detection

        plot_detection(detection, s.t_ns, s.pressure_pa, args.plot)
    if args.json:
        json.dump(detection.to_json(), sys.stdout, indent=2)
        print()
        return 0
    print(f"{args.input}: {s.t_ns.size} samples, {data.kind}, method {args.method}")
    print(f"{'floor':>5s} {'level hPa':>10s} {'elevation m':>11s} {'visits':>6s}")
    for f in detection.floors:
        print(f"{f.index:5d} {f.level_pa / 100:10.2f} {f.elevation_m:11.2f} {f.visits:6d}")
    print(f"{len(detection.transitions)} transitions")
    for tr in detection.transitions:
        print(
            f"  {tr.t_start_ns / 1e9:9.1f} .. {tr.t_end_ns / 1e9:9.1f} s  floor {tr.from_floor} "
            f"-> {tr.to_floor}  {tr.delta_m:+6.2f} m  (decided at {tr.t_detect_ns / 1e9:.1f} s"
            + (", end of input)" if tr.at_end else ")")
        )
    if args.plot:
        print(f"plot: {args.plot}")
    return 0


def run_eval(args: argparse.Namespace) -> int:
    from baromap.errors import ConfigError
    from baromap.evaluation.floors import HEADER, evaluate, line, run_report

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
        )
        results = {m: evaluate(case, m)[1] for m in methods}
        if args.json:
            json.dump({m: _score_json(sc) for m, sc in results.items()}, sys.stdout, indent=2)
            print()
            return 0
        print(HEADER)
        for m, sc in results.items():
            print(line(str(args.input)[-34:], m, sc))
    if args.sweep:
        from baromap.evaluation.floors import real_sweep

        if args.real is None:
            raise ConfigError("--sweep needs --real DIR")
        real_sweep(args.real)
        return 0
    if args.real is not None or args.sim_seeds > 0:
        seeds = list(range(args.first_seed, args.first_seed + max(args.sim_seeds, 0)))
        run_report(
            args.real,
            seeds,
            methods,
            drift_hpa_per_h=args.drift,
            minutes=args.minutes,
            use_reference=args.use_reference,
            progress=sys.stderr.isatty(),
        )
    return 0


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
