"""``baromap demo`` checked for real: what it printed, recorded and built, against the truth.

The demo plays a simulated mission on the device twins, with the real ``baromapd`` recording
them and ``baromap watch`` following over Zenoh. The simulator knows what really happened:
the twins' truth log maps every recorded time to the mission's simulated time
(:mod:`baromap.evaluation.twin_truth`), so floors, rides and maps are scored against the
building the robot drove through, and the recording against what the twins sent.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from demo_run import DEMO_TIMEOUT_S, REPO, DemoRun
from PIL import Image

from baromap import messages
from baromap.cli.main import main
from baromap.evaluation.map_files import read_outputs, score_outputs
from baromap.evaluation.twin_truth import (
    HostClock,
    SimTimeline,
    TruthSeries,
    sim_timeline,
    truth_series,
)
from baromap.floors import apply_corrections
from baromap.floors.evaluation import FloorTruth
from baromap.mapping.arrival_stamps import tighten
from baromap.recording import read_messages, read_metadata, topics
from baromap.sim.twins.truth import FrameTruth, read_truth_log

pytestmark = pytest.mark.timeout(DEMO_TIMEOUT_S + 120)

#: Channels docs/design.md promises in a daemon's recording.
DESIGN_CHANNELS = (
    topics.BARO,
    topics.SCAN,
    topics.ODOM,
    topics.TF,
    topics.TF_STATIC,
    topics.FLOOR_EVENT,
    topics.FLOOR_STATE,
    topics.DIAGNOSTICS,
)
#: A live transition's height against the truth, and a floor's height post-run (m).
LIVE_HEIGHT_TOLERANCE_M = 0.5
POST_RUN_HEIGHT_TOLERANCE_M = 0.3
#: A live event's own bounds may miss the ride by this much (simulated s): the smoothing.
EDGE_TOLERANCE_S = 5.0
#: A live event is decided at most this long after its ride ended (simulated s): the
#: detector waits for the pressure to settle and for the robot to drive off.
LIVE_DECISION_S = 60.0
#: Margin inside the recorded span where frames without a sequence number are counted (ns).
EDGE_NS = 100_000_000


@pytest.fixture(scope="module")
def truth_records(demo: DemoRun) -> list[FrameTruth]:
    return read_truth_log(demo.out / "twins-truth.jsonl")


@pytest.fixture(scope="module")
def timeline(demo: DemoRun, truth_records: list[FrameTruth]) -> SimTimeline:
    return sim_timeline(truth_records, HostClock.of_recording(demo.recording))


@pytest.fixture(scope="module")
def truth(demo: DemoRun, timeline: SimTimeline) -> TruthSeries:
    return truth_series(demo.scenario(), timeline)


@pytest.fixture(scope="module")
def floor_truth(truth: TruthSeries) -> FloorTruth:
    return truth.floor_truth()


@pytest.fixture(scope="module")
def events(demo: DemoRun) -> list[messages.FloorEvent]:
    return [
        r.message
        for r in read_messages(demo.recording, [topics.FLOOR_EVENT])
        if isinstance(r.message, messages.FloorEvent)
    ]


def test_the_demo_runs_to_its_summary(demo: DemoRun) -> None:
    assert demo.exit_code == 0, f"stdout:\n{demo.stdout[-3000:]}\nstderr:\n{demo.stderr[-3000:]}"
    text = demo.stdout
    for heading in ("1/3 baromapd", "2/3 baromapd stopped by SIGTERM (exit 0)", "3/3 build-maps"):
        assert heading in text
    for part in ("floors: 3, by height", "transitions:", "files:", "Foxglove", "maps.mcap"):
        assert part in text
    assert re.search(r"mission \d\d:\d\d of \d\d:\d\d simulated", text), "no progress shown"


def test_the_demo_leaves_no_process_behind(demo: DemoRun) -> None:
    mine = str(demo.out)
    left = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if mine in argv:
            left.append(argv)
    assert left == []


def test_the_generated_configuration_passes_the_daemons_check(
    demo: DemoRun, tmp_path: Path
) -> None:
    # a copy: a process naming the demo's folder is what the leftover-process test looks for
    config = tmp_path / "baromapd.toml"
    shutil.copyfile(demo.out / "baromapd.toml", config)
    check = subprocess.run(
        [sys.executable, "-m", "baromapd.main", "--check-config", str(config)],
        capture_output=True,
        text=True,
        cwd=REPO,
        check=False,
    )
    assert check.returncode == 0, check.stderr


def test_watch_printed_every_event_while_the_mission_went_on(
    demo: DemoRun, events: list[messages.FloorEvent], timeline: SimTimeline
) -> None:
    """``baromap watch`` (its own process, over Zenoh) printed each event the daemon recorded,
    in order, as the mission went on, and saw the robot go when the daemon stopped."""
    lines = demo.watch_lines()
    printed = [int(m.group(1)) for line in lines if (m := re.search(r"\[event (\d+)\]", line))]
    assert events, "the mission has rides, yet the daemon decided no floor change"
    assert printed == [e.event_id for e in events]
    assert "gone" in lines[-1]
    out = demo.lines
    for event in events:
        shown = next(i for i, line in enumerate(out) if f"[event {event.event_id}]" in line)
        decided_s = float(timeline.sim_s_at(event.t_ns))
        later = [
            i
            for i, line in enumerate(out)
            if (m := re.search(r"mission (\d\d):(\d\d) of", line))
            and int(m.group(1)) * 60 + int(m.group(2)) > decided_s + 30
        ]
        assert not later or shown < later[0], f"event {event.event_id} was shown late"


def test_live_floor_events_match_the_truth(
    demo: DemoRun,
    events: list[messages.FloorEvent],
    floor_truth: FloorTruth,
    timeline: SimTimeline,
) -> None:
    """One event per ride, in its time, with the right height, and names that tell the same
    floor apart from the others (the revisit gets the first visit's name)."""
    rides = floor_truth.transitions
    assert len(rides) == len(demo.scenario().transitions()) >= 2
    assert floor_truth.heights_m is not None
    current = apply_corrections(events)
    assert len(current) == len(rides), [(e.from_name, e.to_name) for e in current]
    names: dict[int, str] = {}
    for event, ride in zip(current, rides, strict=True):
        ride_s = timeline.sim_s_at([ride.t_begin_ns, ride.t_end_ns])
        event_s = timeline.sim_s_at([event.t_start_ns, event.t_end_ns, event.t_ns])
        assert event_s[0] <= ride_s[1] + EDGE_TOLERANCE_S
        assert event_s[1] >= ride_s[0] - EDGE_TOLERANCE_S
        # decided as the car stops (the robot rode in it), a moment before it stands at the
        # latest: the barometer's lag is of the car's motion too
        assert -EDGE_TOLERANCE_S < event_s[2] - ride_s[1] < LIVE_DECISION_S
        true_delta = floor_truth.heights_m[ride.to_floor] - floor_truth.heights_m[ride.from_floor]
        assert abs(event.delta_m - true_delta) < LIVE_HEIGHT_TOLERANCE_M
        for floor, name in ((ride.from_floor, event.from_name), (ride.to_floor, event.to_name)):
            assert names.setdefault(floor, name) == name
    assert len(set(names.values())) == len(names)
    # the demo configures its start floor and storey height as a user would: the live names
    # are the building's own (its floors 0, 1, 2: consecutive, whatever their heights)
    assert names == {floor: str(floor) for floor in names}


def test_post_run_floors_match_the_truth(
    demo: DemoRun, floor_truth: FloorTruth, truth: TruthSeries
) -> None:
    """building.yaml has each visited floor once, at its height; every scan of the trajectory
    sits on the floor the robot was really on."""
    model = yaml.safe_load((demo.maps / "building.yaml").read_text())
    assert floor_truth.heights_m is not None
    true_heights = sorted(floor_truth.heights_m.values())
    floors = sorted(model["floors"], key=lambda f: f["elevation_m"])
    assert len(floors) == len(true_heights)
    for f, z in zip(floors, true_heights, strict=True):
        assert abs(f["elevation_m"] - (z - true_heights[0])) < POST_RUN_HEIGHT_TOLERANCE_M
    route = demo.mission.route
    visits = {f: route.count(f) for f in route}
    by_height = {z: f for f, z in floor_truth.heights_m.items()}
    assert [f["visits"] for f in floors] == [visits[by_height[z]] for z in true_heights]
    # named as the daemon named them live (its configured start floor and storey), which are
    # the building's own names in order of height: no live name differs
    assert [f["name"] for f in floors] == [str(by_height[z]) for z in true_heights]
    assert [f.get("live_name") for f in floors] == [None] * len(floors)
    # the trajectory's z is its scan's floor: compare with where the robot really was
    _, trajectory = read_outputs(demo.maps)
    idx = np.clip(np.searchsorted(truth.t_ns, trajectory.t_ns), 0, len(truth.t_ns) - 1)
    true_floor = truth.floor[idx]
    # building.yaml keeps 3 decimals, trajectory.tum 4: a scan is on the floor whose elevation
    # is within a few mm of its z (rounding both to 2 decimals split 12.355 from 12.3545); a
    # scan in a ride lies between floors, centimetres at least from either
    elevations = np.array([f["elevation_m"] for f in floors])
    gap = np.abs(np.asarray(trajectory.z_m, dtype=float)[:, None] - elevations[None, :])
    labelled = np.where(gap.min(axis=1) < 0.005, gap.argmin(axis=1), -1)
    on_floor = (labelled >= 0) & (true_floor >= 0)
    order = [by_height[z] for z in true_heights]  # true floor of each post-run floor
    agree = np.array(
        [order[k] == t for k, t in zip(labelled[on_floor], true_floor[on_floor], strict=True)]
    )
    assert set(labelled[on_floor]) == set(range(len(floors)))
    assert agree.mean() > 0.99


def test_maps_of_floors_visited_once_match_their_plans(demo: DemoRun, truth: TruthSeries) -> None:
    scores = score_outputs(demo.maps, demo.scenario().building, truth.t_ns, truth.xyt, truth.floor)
    route = demo.mission.route
    assert sorted(s.true_floor for s in scores) == sorted(set(route))
    for s in scores:
        if route.count(s.true_floor) == 1:
            assert s.occupied_precision >= 0.9, s
            assert s.free_precision >= 0.95, s


def test_all_maps_match_their_plans_in_one_frame(demo: DemoRun, truth: TruthSeries) -> None:
    scores = score_outputs(demo.maps, demo.scenario().building, truth.t_ns, truth.xyt, truth.floor)
    for s in scores:
        assert s.occupied_precision >= 0.9, s
        assert s.building_occupied_precision >= 0.9, s
        assert s.lobby_error_m <= 0.1, s
        assert s.lobby_error_deg <= 1.0, s


def test_every_output_file_is_valid(demo: DemoRun) -> None:
    assert main(["info", str(demo.recording)]) == 0  # closed cleanly, summary readable
    meta = read_metadata(demo.recording)
    header = meta[topics.METADATA_NAME]
    assert header["robot"] == demo.mission.robot
    assert "[laser]" in header["configuration"]
    for device in ("laser", "base", "barometer"):
        assert f"baromap.device.{device}" in meta
    seen = {r.topic for r in read_messages(demo.recording)}
    assert set(DESIGN_CHANNELS) <= seen
    assert not [t for t in seen if t.startswith("/truth")]
    maps, trajectory = read_outputs(demo.maps)
    assert len(maps) == 3 and len(trajectory.t_ns) > 0
    assert bool(np.all(np.diff(trajectory.t_ns) >= 0))
    for m in maps:
        assert m.occupied.any() and m.free.any()
        with Image.open(demo.maps / f"floor_{m.index}.png") as png:
            png.verify()
    for name in ("building.png", "pressure.png"):
        with Image.open(demo.maps / name) as png:
            png.verify()
    map_topics = {r.topic for r in read_messages(demo.maps / "maps.mcap")}
    assert {f"/map/floor_{m.index}" for m in maps} <= map_topics
    model = yaml.safe_load((demo.maps / "building.yaml").read_text())
    for key in ("source", "frame", "resolution_m", "floors", "loop_closures", "scans"):
        assert key in model
    for f in model["floors"]:
        for key, kind in (("index", int), ("elevation_m", float), ("visits", int)):
            assert isinstance(f[key], kind)
        assert (demo.maps / f["map"]).is_file() and (demo.maps / f["image"]).is_file()


def test_nothing_sent_was_lost_on_the_way(demo: DemoRun, truth_records: list[FrameTruth]) -> None:
    """Every frame a twin sent while its session was up is in the recording: each barometer
    sample by its sequence number, scans and SIPs by count over the span they were recorded."""
    clock = HostClock.of_recording(demo.recording)
    baro = [
        r.message
        for r in read_messages(demo.recording, [topics.BARO])
        if isinstance(r.message, messages.PressureSample)
    ]
    recorded_seq = [m.seq for m in baro]
    sent = sorted((r.t_mono_ns, r.seq) for r in truth_records if r.device == "baro")
    first = recorded_seq[0]
    sent_seq = [s for _, s in sent]
    start = sent_seq.index(first)
    last = sent_seq.index(recorded_seq[-1], start)
    assert recorded_seq == sent_seq[start : last + 1]
    health = [
        r.message
        for r in read_messages(demo.recording, [topics.DIAGNOSTICS])
        if isinstance(r.message, messages.DeviceHealth)
    ]
    for device, session, topic in (("lms200", "laser", topics.SCAN), ("p3at", "base", topics.ODOM)):
        recorded_ns = np.array([r.message.t_ns for r in read_messages(demo.recording, [topic])])
        # a reader held up near an end of the span stamps the frames it then gets late, past
        # the span they were sent in (a 0.4 s hold-up cost 11 SIPs so, none lost): their
        # backlogs set back as build-maps sets them back
        stamps = tighten(recorded_ns).t_ns
        frames = np.sort(clock.unix_ns([r.t_mono_ns for r in truth_records if r.device == device]))
        # Inside the recorded span, as many frames as were sent. These frames carry no number,
        # and a stamp may fall a frame period from its true instant, so each end of the span
        # may count one frame either way.
        lo, hi = stamps[0] + EDGE_NS, stamps[-1] - EDGE_NS
        recorded = np.count_nonzero((stamps >= lo) & (stamps <= hi))
        sent_inside = np.count_nonzero((frames >= lo) & (frames <= hi))
        # a miss says what the session went through: under a machine's full load bytes can
        # be lost on the pty before the daemon reads them
        seen = [(h.t_ns, h.state.value, h.detail) for h in health if h.device == session]
        changes = [c for k, c in enumerate(seen) if k == 0 or c[1:] != seen[k - 1][1:]]
        last = next((dict(h.counters) for h in reversed(health) if h.device == session), {})
        assert abs(recorded - sent_inside) <= 2, (device, recorded, sent_inside, changes, last)
