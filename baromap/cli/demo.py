"""``baromap demo``: the product's real path on simulated hardware, start to finish.

1. live: the three device twins on pseudo-terminals play a short mission; the real
   ``baromapd`` (a separate process, with a generated configuration) records them and decides
   floor changes as they happen; ``baromap watch`` (another process) prints the floor events it
   receives over Zenoh, shown here as they come;
2. the daemon is stopped as systemd stops it (SIGTERM): it closes the recording;
3. ``build-maps`` turns the recording into one aligned map per floor and a building model;
4. a summary: floors with heights and names, transitions, files, how to open them.

The orchestration is in ``demo_live`` (children, order, progress), the daemon's configuration
in ``demo_config``, the mission in ``demo_mission``, the closing words in ``demo_summary``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from baromap.cli.demo_mission import DEFAULT_SPEED, MAX_SPEED, Mission

#: Width of the source column in front of live lines.
_SOURCE_WIDTH = 8


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="the whole job on simulated hardware: daemon, live floors, maps",
        description="Simulated laser, base and barometer on pseudo-terminals; the real baromapd "
        "records them while `baromap watch` prints live floor events; then build-maps.",
    )
    parser.add_argument("--out", default="out/demo", help="output directory (default out/demo)")
    parser.add_argument(
        "--speed",
        type=float,
        default=DEFAULT_SPEED,
        help=f"how much faster than real time the twins play the mission (default "
        f"{DEFAULT_SPEED:g}, at most {MAX_SPEED:g})",
    )
    parser.add_argument(
        "--keep-alive",
        action="store_true",
        help="when the mission is over, keep baromapd and its live view running until Ctrl-C, "
        "then build the maps",
    )
    parser.set_defaults(run=run)


def _say(text: str = "") -> None:
    print(text, flush=True)


def _show(item: Any) -> None:
    _say(f"  {item.source:>{_SOURCE_WIDTH}s} | {item.text}")


def describe(mission: Mission) -> str:
    floors = " -> ".join(str(f) for f in mission.route)
    revisits = len(mission.route) - len(set(mission.route))
    return (
        f"{mission.minutes:g} simulated minutes in a {mission.floors}-floor building: floors "
        f"{floors} ({len(mission.route) - 1} elevator rides, {revisits} revisit), played "
        f"{mission.speed:g}x faster than real time ({mission.wall_s:.0f} s; the daemon's "
        f"floor detector is set for that: durations / {mission.speed:g})"
    )


@contextlib.contextmanager
def _sigterm_unwinds() -> Iterator[None]:
    """SIGTERM (a CI timeout, a service manager) unwinds like Ctrl-C, so the children are
    stopped in order instead of being left running."""

    def stop(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def run(args: argparse.Namespace) -> int:
    with _sigterm_unwinds():
        return run_demo(Mission(speed=args.speed), Path(args.out), keep_alive=args.keep_alive)


def run_demo(mission: Mission, out: Path, *, keep_alive: bool = False) -> int:
    from baromap.cli.demo_live import run_live

    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    _say("baromap demo: the acquisition daemon on simulated devices, live floors, then maps")
    _say(f"mission: {describe(mission)}")
    _say(f"outputs: {out}")
    (out / "mission.json").write_text(json.dumps(mission_record(mission)), encoding="utf-8")

    _say("\n1/3 baromapd records the twins; baromap watch follows it over Zenoh")
    live = run_live(mission, out, _show, keep_alive=keep_alive)
    _say(
        f"\n2/3 baromapd stopped by SIGTERM (exit {live.daemon_exit}) after "
        f"{live.wall_s:.0f} s; configuration {live.config}"
    )
    if live.daemon_exit != 0 or len(live.recordings) != 1:
        _say(f"  expected one recording and exit 0; the daemon's log: {live.logs['baromapd']}")
        return 1
    recording = live.recordings[0]
    _say(f"  recording {recording} ({recording.stat().st_size / 1e6:.1f} MB)")

    _say("\n3/3 build-maps on the recording")
    lines = build_and_summarise(mission, recording, out / "maps", live.truth_log)
    _say(f"\ndone in {time.monotonic() - started:.0f} s")
    for line in lines:
        _say(line)
    return 0


def mission_record(mission: Mission) -> dict[str, Any]:
    """What was played, so tests and benches can rebuild the scenario (``mission.json``)."""
    return {
        "seed": mission.seed,
        "floors": mission.floors,
        "route": list(mission.route),
        "minutes": mission.minutes,
        "speed": mission.speed,
        "robot": mission.robot,
    }


def build_and_summarise(
    mission: Mission, recording: Path, maps_dir: Path, truth_log: Path
) -> list[str]:

    from baromap.building import read_building
    from baromap.cli.demo_summary import TrueRun, summary_lines
    from baromap.evaluation.map_files import score_outputs
    from baromap.evaluation.twin_truth import HostClock, sim_timeline, truth_series
    from baromap.floors import apply_corrections
    from baromap.mapping.build import build_maps
    from baromap.mapping.build import summary_lines as build_lines
    from baromap.messages import FloorEvent
    from baromap.recording import read_messages, topics
    from baromap.sim.scenario import make_scenario
    from baromap.sim.twins.truth import read_truth_log

    result = build_maps(recording, maps_dir, progress=True)
    for line in build_lines(result, maps_dir):
        _say(f"  {line}")
    building = read_building(maps_dir / "building.yaml")
    events = apply_corrections(
        r.message
        for r in read_messages(recording, [topics.FLOOR_EVENT])
        if isinstance(r.message, FloorEvent)
    )
    detection = result.segmentation.detection
    scenario = make_scenario(
        mission.seed, floors=mission.floors, minutes=mission.minutes, route=mission.route
    )
    visited = sorted(set(mission.route))
    z = [float(scenario.building.elevations_m[f]) for f in visited]
    timeline = sim_timeline(read_truth_log(truth_log), HostClock.of_recording(recording))
    series = truth_series(scenario, timeline)
    truth = TrueRun(
        elevations_m=tuple(v - z[0] for v in z),
        rides=tuple((t.from_floor, t.to_floor) for t in scenario.transitions()),
        maps=tuple(
            score_outputs(maps_dir, scenario.building, series.t_ns, series.xyt, series.floor)
        ),
    )
    return summary_lines(
        out=maps_dir,
        recording=recording,
        building=building,
        events=events,
        t0_ns=int(result.run.scans.t_ns[0]) if len(result.run.scans) else 0,
        post_run_transitions=len(detection.transitions) if detection else 0,
        truth=truth,
        files=result.files,
    )
