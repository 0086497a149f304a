"""What the twins' speed does to the demo: the demo's mission at several speeds, scored.

``baromap demo`` plays a ten-minute simulated mission on the device twins faster than real
time, with the real baromapd recording it. The daemon stamps on the host's clock, so the
recording is the mission compressed by the speed. This runs the demo's live part (twins,
baromapd, baromap watch) at each speed, builds the maps, and prints against the twins' truth:

- the recording: scans per metre driven and per simulated second, odometry per simulated
  second and its longest gap, stamp errors (laser, odometry) in simulated milliseconds;
- the live detector (causal): rides found, missed, false; height error; decision delay in
  simulated seconds; with the detector scaled to the speed (what the demo does) or not;
- post-run (build-maps): floor height error, per-floor map precision against the true plans,
  and how well the floors line up at the lobby (one frame for the building).

    python bench/demo.py [--speeds 2,4,6,8] [--minutes 10] [--unscaled]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from baromap import logs
from baromap.cli.demo_live import Additions, run_live
from baromap.cli.demo_mission import DEFAULT_MINUTES, Mission
from baromap.evaluation.floor_live import live_detection
from baromap.evaluation.map_files import score_outputs
from baromap.evaluation.twin_truth import HostClock, sim_timeline, truth_series
from baromap.floors import apply_corrections
from baromap.floors.evaluation import score
from baromap.mapping.build import build_maps
from baromap.messages import FloorEvent
from baromap.recording import read_messages, topics
from baromap.sim.scenario import make_scenario
from baromap.sim.twins.truth import FrameTruth, read_truth_log


def _stamp_errors_ms(stamps: np.ndarray, truth_unix: np.ndarray) -> np.ndarray:
    """Each stamp minus the nearest true instant (ns -> ms)."""
    i = np.clip(np.searchsorted(truth_unix, stamps), 1, len(truth_unix) - 1)
    before, after = stamps - truth_unix[i - 1], stamps - truth_unix[i]
    out: np.ndarray = np.where(np.abs(before) < np.abs(after), before, after) / 1e6
    return out


def measure(mission: Mission, work: Path, scale_detector: bool) -> dict[str, float]:
    out = work / f"x{mission.speed:g}{'' if scale_detector else '-unscaled'}"
    live = run_live(mission, out, lambda _: None, Additions(scale_detector=scale_detector))
    (recording,) = live.recordings
    started = time.monotonic()
    build = build_maps(recording, out / "maps")
    build_s = time.monotonic() - started
    records: list[FrameTruth] = read_truth_log(live.truth_log)
    clock = HostClock.of_recording(recording)
    timeline = sim_timeline(records, clock)
    scenario = make_scenario(
        mission.seed, floors=mission.floors, minutes=mission.minutes, route=mission.route
    )
    truth = truth_series(scenario, timeline)
    floor_truth = truth.floor_truth()
    scans = build.run.scans.t_ns
    odom = np.array([r.message.t_ns for r in read_messages(recording, [topics.ODOM])])
    span = timeline.sim_s_at([scans[0], scans[-1]])
    odom_sim = timeline.sim_s_at(odom)
    figures: dict[str, float] = {
        "live_wall_s": live.wall_s,
        "build_s": build_s,
        "scans_per_m": len(scans) / truth.distance_m(),
        "scans_per_sim_s": len(scans) / float(span[1] - span[0]),
        "odom_per_sim_s": len(odom) / float(odom_sim[-1] - odom_sim[0]),
        "odom_gap_sim_s": float(np.max(np.diff(odom_sim))),
    }
    for device, stamps in (("lms200", scans), ("p3at", odom)):
        true_unix = np.sort(clock.unix_ns([r.t_mono_ns for r in records if r.device == device]))
        err = np.abs(_stamp_errors_ms(stamps, true_unix)) * mission.speed
        figures[f"{device}_err_p50_ms"] = float(np.percentile(err, 50))
        figures[f"{device}_err_p99_ms"] = float(np.percentile(err, 99))
    published = [
        r.message
        for r in read_messages(recording, [topics.FLOOR_EVENT])
        if isinstance(r.message, FloorEvent)
    ]
    events = apply_corrections(published)
    post = build.segmentation.detection
    live_score = score(live_detection(published, post), floor_truth)
    post_score = score(post, floor_truth)
    assert floor_truth.heights_m is not None
    heights = floor_truth.heights_m
    by_time = sorted(floor_truth.transitions, key=lambda t: t.t_begin_ns)
    delta_errors = [
        abs(e.delta_m - (heights[t.to_floor] - heights[t.from_floor]))
        for e, t in zip(events, by_time, strict=False)
    ]
    figures |= {
        "rides": live_score.true,
        "live_found": live_score.found,
        "live_false": live_score.false,
        "live_delta_err_m": max(delta_errors, default=float("nan")),
        "live_delay_sim_s": live_score.median_delay_s * mission.speed,
        "post_height_err_m": post_score.height_error_m or float("nan"),
    }
    maps = score_outputs(out / "maps", scenario.building, truth.t_ns, truth.xyt, truth.floor)
    figures |= {
        "map_occ_min": min(m.occupied_precision for m in maps),
        "map_building_occ_min": min(m.building_occupied_precision for m in maps),
        "lobby_m_max": max(m.lobby_error_m for m in maps),
        "lobby_deg_max": max(m.lobby_error_deg for m in maps),
        "loops": len(build.slam.loop_edges),
    }
    return figures


ROWS = (
    ("live part, wall s", "live_wall_s", "{:.0f}"),
    ("build-maps, wall s", "build_s", "{:.1f}"),
    ("scans per metre driven", "scans_per_m", "{:.0f}"),
    ("scans per simulated s", "scans_per_sim_s", "{:.1f}"),
    ("odometry per simulated s", "odom_per_sim_s", "{:.1f}"),
    ("longest odometry gap, simulated s", "odom_gap_sim_s", "{:.2f}"),
    ("laser stamp error p50 / p99, sim ms", ("lms200_err_p50_ms", "lms200_err_p99_ms"), "{:.0f}"),
    ("odometry stamp error p50 / p99, sim ms", ("p3at_err_p50_ms", "p3at_err_p99_ms"), "{:.0f}"),
    ("live: rides found / false (of rides)", ("live_found", "live_false", "rides"), "{:.0f}"),
    ("live: worst ride height error, m", "live_delta_err_m", "{:.2f}"),
    ("live: median decision delay, simulated s", "live_delay_sim_s", "{:.1f}"),
    ("post-run: worst floor height error, m", "post_height_err_m", "{:.2f}"),
    ("post-run: worst map, walls within 10 cm (own fit)", "map_occ_min", "{:.3f}"),
    ("post-run: worst map, walls within 10 cm (one frame)", "map_building_occ_min", "{:.3f}"),
    ("post-run: floors at the lobby, worst m / deg", ("lobby_m_max", "lobby_deg_max"), "{:.2f}"),
    ("post-run: loop closures", "loops", "{:.0f}"),
)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--speeds", default="2,4,6,8")
    parser.add_argument("--minutes", type=float, default=DEFAULT_MINUTES)
    parser.add_argument(
        "--unscaled", action="store_true", help="also run each speed with the detector's defaults"
    )
    args = parser.parse_args()
    logs.configure("console", "WARNING")
    speeds = [float(s) for s in args.speeds.split(",")]
    load = os.getloadavg()[0]
    columns: list[tuple[str, dict[str, float]]] = []
    with tempfile.TemporaryDirectory(prefix="baromap-bench-demo-") as tmp:
        for speed in speeds:
            mission = Mission(speed=speed, minutes=args.minutes)
            for scaled in (True, False) if args.unscaled else (True,):
                label = f"x{speed:g}" + ("" if scaled else " default")
                print(f"running the mission at {label} ...", flush=True)
                columns.append((label, measure(mission, Path(tmp), scaled)))
    print(
        f"\nthe demo's mission ({args.minutes:g} simulated minutes) at each speed; machine: "
        f"{os.cpu_count()} cores, load average {load:.1f} at start, {os.getloadavg()[0]:.1f} at end"
    )
    print(f"{'':52s}" + "".join(f"{label:>16s}" for label, _ in columns))
    for title, keys, fmt in ROWS:
        names = keys if isinstance(keys, tuple) else (keys,)
        cells = [" / ".join(fmt.format(f[k]) for k in names) for _, f in columns]
        print(f"{title:52s}" + "".join(f"{c:>16s}" for c in cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
