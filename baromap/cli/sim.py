"""``baromap sim``: simulated devices on pseudo-terminals, and ``baromap sim record``.

register() stays cheap; the simulator (numpy, scipy, the codecs) is imported by the command.
"""

from __future__ import annotations

import argparse
from typing import Any

from baromap.errors import ConfigError


def _common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    parser.add_argument("--floors", type=int, default=6, help="storeys (default 6)")
    parser.add_argument(
        "--drift",
        type=float,
        default=1.5,
        metavar="HPA_PER_H",
        help="largest weather drift rate (default 1.5 hPa/h)",
    )
    parser.add_argument(
        "--minutes", type=float, default=46.0, help="length of the simulated run (default 46)"
    )
    parser.add_argument(
        "--route",
        default=None,
        help="floors to visit, 0-based, comma separated (default: the paper's 4,5,3,2,1,0,2)",
    )


def register(subparsers: Any) -> None:
    sim = subparsers.add_parser(
        "sim",
        help="simulated LMS200, P3-AT and barometer on pseudo-terminals",
        description="Start the simulated devices on pseudo-terminals and print their paths; "
        "runs until Ctrl-C. `baromap sim record` writes a simulated run to MCAP instead.",
    )
    _common(sim)
    sim.add_argument("--speed", type=float, default=1.0, help="time factor (default 1x)")
    sim.add_argument(
        "--link-dir",
        default=None,
        help="also create stable symlinks lms200, p3at, baro in this directory",
    )
    sim.add_argument("--json", action="store_true", help="print the paths as one JSON object")
    sim.add_argument(
        "--twins",
        default=None,
        metavar="FILE",
        help="TOML file of twin settings (robot subclass, laser boot time, scheduled faults)",
    )
    sim.add_argument(
        "--truth-log",
        default=None,
        metavar="FILE",
        help="write the true acquisition instant of every frame sent, one JSON line each",
    )
    sim.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    sim.set_defaults(run=run_twins)
    actions = sim.add_subparsers(dest="sim_command", metavar="ACTION")
    rec = actions.add_parser(
        "record",
        help="write a simulated run (with truth topics) to MCAP, faster than real time",
    )
    rec.add_argument("-o", "--output", required=True, help="MCAP file to write")
    _common(rec)
    rec.add_argument("--rate", type=float, default=25.0, help="barometer rate in Hz (default 25)")
    rec.add_argument(
        "--laser-resolution",
        type=float,
        choices=(1.0, 0.5),
        default=1.0,
        help="LMS200 angular resolution in degrees (180 deg field; default 1)",
    )
    rec.add_argument("--laser-units", choices=("mm", "cm"), default="mm")
    rec.add_argument("--laser-baud", type=int, default=38400, choices=(9600, 19200, 38400, 500000))
    rec.add_argument(
        "--robot-model",
        default=None,
        metavar="SUBCLASS",
        help="the base's subclass, which sets its odometry factors (default p3at-sh, ARCOS P3-AT)",
    )
    rec.add_argument("--force", action="store_true", help="overwrite an existing file")
    rec.set_defaults(run=run_record)


def parse_route(text: str | None) -> list[int] | None:
    if text is None:
        return None
    try:
        return [int(part) for part in text.split(",") if part.strip()]
    except ValueError as exc:
        raise ConfigError(f"--route takes comma-separated floor numbers, not {text!r}") from exc


def run_record(args: argparse.Namespace) -> int:
    from baromap.protocols.robot_models import DEFAULT_MODEL, robot_model
    from baromap.sim.laser import LaserConfig
    from baromap.sim.record import record_run

    laser = LaserConfig(
        angle_deg=180,
        resolution_cdeg=round(args.laser_resolution * 100),
        units=args.laser_units,
        baud=args.laser_baud,
    )
    summary = record_run(
        args.output,
        seed=args.seed,
        floors=args.floors,
        minutes=args.minutes,
        drift_hpa_per_h=args.drift,
        route=parse_route(args.route),
        laser=laser,
        rate_hz=args.rate,
        model=robot_model(args.robot_model) if args.robot_model else DEFAULT_MODEL,
        overwrite=args.force,
    )
    total = sum(summary.counts.values())
    print(
        f"wrote {summary.path}: {summary.simulated_s / 60:.1f} simulated minutes in "
        f"{summary.wall_s:.1f} s ({summary.simulated_s / summary.wall_s:.0f}x real time), "
        f"{total} messages"
    )
    for topic, count in sorted(summary.counts.items()):
        print(f"  {topic}: {count}")
    return 0


def run_twins(args: argparse.Namespace) -> int:
    import contextlib

    from baromap.sim.scenario import load_twin_settings
    from baromap.sim.twins.runner import SimDevices
    from baromap.sim.twins.truth import JsonlTruthWriter

    twins = load_twin_settings(args.twins) if args.twins is not None else None
    with contextlib.ExitStack() as stack:
        truth = None
        if args.truth_log is not None:
            truth = stack.enter_context(contextlib.closing(JsonlTruthWriter(args.truth_log)))
        devices = SimDevices(
            seed=args.seed,
            floors=args.floors,
            minutes=args.minutes,
            drift_hpa_per_h=args.drift,
            route=parse_route(args.route),
            speed=args.speed,
            link_dir=args.link_dir,
            twins=twins,
            truth_sink=truth,
        )
        _serve(devices, args)
    return 0


def _serve(devices: Any, args: argparse.Namespace) -> None:
    import contextlib
    import json
    import signal
    import threading

    done = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: done.set())
    try:
        with devices:
            paths = devices.paths()
            if args.json:
                print(json.dumps(paths), flush=True)
            else:
                for name, path in paths.items():
                    print(f"{name} {path}", flush=True)
            with contextlib.suppress(KeyboardInterrupt):
                done.wait(args.duration)
    finally:
        signal.signal(signal.SIGTERM, previous)
