"""``baromap demo``: the main job on the embedded default (no hardware).

The finished demo will run the simulated devices on pseudo-terminals, the real daemon
recording them, and live floor events over Zenoh. The daemon and the Zenoh publisher are not
built yet, so today the demo runs every stage that exists, on the same code paths the product
uses, and names the ones it stands in for:

1. the simulator writes a run straight to MCAP through the real device codecs (the daemon
   will record the same topics from the device twins);
2. the online floor detector is replayed over the recorded pressure one sample at a time,
   causally, and each floor event is printed when the detector decides it, beside the
   simulator's truth (Zenoh will carry these events live);
3. ``build-maps`` turns the run into one aligned map per floor and a building model.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

NOT_YET = (
    "baromapd (recording the device twins on pseudo-terminals) and live Zenoh floor state "
    "are not built yet; this demo records with the simulator and replays the online detector"
)


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("demo", help="run the main job on simulated hardware")
    parser.add_argument("--out", default="out/demo", help="output directory (default out/demo)")
    parser.add_argument("--minutes", type=float, default=46.0, help="length of the run")
    parser.add_argument("--floors", type=int, default=6, help="floors in the building")
    parser.add_argument("--seed", type=int, default=0, help="building and run seed")
    parser.set_defaults(run=run)


def _clock(t_ns: int, t0_ns: int) -> str:
    seconds = (t_ns - t0_ns) / 1e9
    return f"{int(seconds // 60):02d}:{seconds % 60:04.1f}"


def replay_floor_events(recording: Path) -> tuple[int, int]:
    """Feed the recorded pressure to the online detector in time order; print its events.

    Returns (events, true transitions) so the caller can say whether they agree.
    """
    from baromap import messages
    from baromap.floors import OnlineFloorDetector
    from baromap.recording import read_messages, topics

    detector = OnlineFloorDetector()
    truth_floor: int | None = None
    truth_changes = 0
    last_settled: int | None = None
    t0: int | None = None
    events = 0
    for rec in read_messages(recording, [topics.BARO, topics.ODOM, topics.TRUTH_FLOOR]):
        msg = rec.message
        if isinstance(msg, messages.Odometry):
            detector.update_odometry(msg)
            continue
        if isinstance(msg, messages.TruthFloor):
            if msg.floor is not None:
                if last_settled is not None and msg.floor != last_settled:
                    truth_changes += 1
                last_settled = msg.floor
            truth_floor = msg.floor
            continue
        if not isinstance(msg, messages.PressureSample):
            continue
        t0 = msg.t_ns if t0 is None else t0
        for event in detector.update(msg):
            events += 1
            truth = "riding" if truth_floor is None else f"true floor {truth_floor}"
            print(
                f"  [{_clock(event.t_ns, t0)}] floor {event.from_name} -> {event.to_name} "
                f"({event.delta_m:+.2f} m, change {_clock(event.t_start_ns, t0)}.."
                f"{_clock(event.t_end_ns, t0)}; {truth})"
            )
    for event in detector.finish():
        events += 1
        print(f"  [end] floor {event.from_name} -> {event.to_name} ({event.delta_m:+.2f} m)")
    return events, truth_changes


def run(args: argparse.Namespace) -> int:
    from baromap.mapping.build import build_maps, summary_lines
    from baromap.sim.record import record_run

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    recording = out / "run.mcap"
    started = time.perf_counter()
    print(f"baromap demo: {NOT_YET}.")

    print(f"\n1/3 simulating a {args.minutes:g}-minute run in a {args.floors}-floor building")
    summary = record_run(
        recording,
        seed=args.seed,
        floors=args.floors,
        minutes=args.minutes,
        overwrite=True,
    )
    print(
        f"  {recording}: {sum(summary.counts.values())} messages, "
        f"{summary.simulated_s / 60:.1f} simulated minutes in {summary.wall_s:.1f} s"
    )

    print("\n2/3 online floor detection, replayed sample by sample (times are run time)")
    print(
        "  detector floors are named from the start floor (called 0) in storeys; "
        "true floors are the simulator's, 0 = ground"
    )
    events, truth_changes = replay_floor_events(recording)
    print(f"  {events} floor events; the simulator's truth has {truth_changes} floor changes")

    print("\n3/3 building per-floor maps")
    maps_dir = out / "maps"
    result = build_maps(recording, maps_dir, progress=True)
    for line in summary_lines(result, maps_dir):
        print(f"  {line}")

    print(f"\ndone in {time.perf_counter() - started:.0f} s. Outputs:")
    print(f"  recording      {recording}   (open in Foxglove, or: baromap info {recording})")
    for path in sorted(result.files):
        print(f"  {path.name:14s} {path}")
    return 0
