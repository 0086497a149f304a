"""Silences cut into a copy of a recording: one pass equals one copy per silence; a
simulated run with its laser or its odometry silent is mapped through them."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from baromap.evaluation.mapping import evaluate_recording
from baromap.evaluation.silences import Silence, score_silence, silenced, without
from baromap.mapping.build import build_maps
from baromap.recording import read_messages
from baromap.sim.record import record_run


def test_silences_in_one_pass_are_the_copies_one_after_another(tmp_path: Path) -> None:
    """The odometry power-cycled (joined, then zeroed) and the laser silent: one pass writes
    the file that three copies made one from the other write, to the byte."""
    run = tmp_path / "run.mcap"
    record_run(run, seed=1, floors=2, minutes=1.0, progress=False)
    cuts = [
        Silence("/odom", 10, 15, counters="joined"),
        Silence("/scan", 12, 20),
        Silence("/odom", 30, 31, counters="zeroed"),
    ]
    step = run
    one_by_one = []
    for k, cut in enumerate(cuts):
        copy = tmp_path / f"copy{k}.mcap"
        one_by_one.append(
            without(step, copy, cut.topic, cut.start_s, cut.end_s, counters=cut.counters)
        )
        step = copy
    assert silenced(run, tmp_path / "once.mcap", cuts) == one_by_one
    assert min(one_by_one) > 0
    assert (tmp_path / "once.mcap").read_bytes() == step.read_bytes()
    # the base counts from zero after the zeroed cut
    records = list(read_messages(step, ["/odom"]))
    first = records[0].log_time_ns
    (after,) = [r.message for r in records if r.log_time_ns - first >= 31e9][:1]
    assert (after.x_m, after.y_m, after.theta_rad) == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)


def test_a_silence_with_counters_is_odometry_only() -> None:
    with pytest.raises(ValueError, match="only /odom has counters"):
        Silence("/scan", 1, 2, counters="zeroed")
    with pytest.raises(ValueError, match="counters must be one of"):
        Silence("/odom", 1, 2, counters="reset")


#: The part of the simulated 46-minute run (seed 0) the silences are cut into: its first four
#: rides (the last at 1647-1652 s) through five of its six floors, and a minute on the fifth.
FIRST_PART_S = 1720.0


@pytest.fixture(scope="module")
def long_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The simulated 46-minute run, seed 0, recorded once and cut to its first
    :data:`FIRST_PART_S`, for the tests that silence a device in copies of it (a 46-minute
    plan is not a shorter run's: the simulator spreads the same route over the minutes)."""
    from mcap.reader import make_reader

    folder = tmp_path_factory.mktemp("sim46")
    whole = folder / "run.mcap"
    record_run(whole, seed=0, progress=False)
    with whole.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    every_topic = sorted({channel.topic for channel in summary.channels.values()})
    part = folder / "first.mcap"
    # every topic silent from then on: the run as if it had ended there
    silenced(whole, part, [Silence(topic, FIRST_PART_S, math.inf) for topic in every_topic])
    whole.unlink()
    return part


@pytest.mark.slow
def test_a_laser_silent_for_a_minute_twice_is_driven_through(
    long_run: Path, tmp_path: Path
) -> None:
    """The simulated 46-minute run, seed 0, to 1720 s, with no scan from 600 to 660 s and from
    1500 to 1560 s while the robot drives on (a laser power-cycled by the daemon).

    The first: matched against the submaps from before the minute in a window capped at
    1.5 m, where odometry's doubt over the drive is metres, the scan after it goes wrong and
    takes its floor with it. It begins new submaps instead, and loop closure ties them back.
    The second, on the way to the lift over ground not yet mapped: the car at the next ride
    is metres and degrees from where the chain puts it, so no car closure ties the floor
    after it to the building (without the search below: 1.71 m RMS, max 5.8 m, that floor's
    lobby 5.3 m off). The car is looked for beyond the chain's window there, and the agreeing
    matches move the chain (0.033 m RMS, max 0.12 m)."""
    silent = tmp_path / "silent.mcap"
    left_out = silenced(
        long_run, silent, [Silence("/scan", 600, 660), Silence("/scan", 1500, 1560)]
    )
    assert min(left_out) > 500
    from structlog.testing import capture_logs

    with capture_logs() as logs:
        result = build_maps(silent, tmp_path / "maps")
    said = [e for e in logs if e["event"] == "laser silent"]
    assert len(said) == 1 and said[0]["stretches"] == 2
    assert said[0]["longest_s"] == pytest.approx(60.0, abs=0.5)
    assert said[0]["first_after_s"] == pytest.approx(600.0, abs=0.5)
    stats = result.slam.stats
    assert stats["front_after_gap"] == 2
    assert stats["car_rides_missed"] >= 1 and stats["car_far_matches"] >= 2
    assert stats["untied_keyframes"] == 0  # loop closures and the car tied both back
    report = evaluate_recording(result, silent)
    assert report.trajectory_rms_m < 0.1
    assert report.one_map_per_floor()
    assert max(f.lobby_error_m for f in report.floors) < 0.1


@pytest.mark.slow
def test_odometry_silent_or_counting_from_zero_is_found_again(
    long_run: Path, tmp_path: Path
) -> None:
    """The simulated 46-minute run, seed 0, to 1720 s, with the base's odometry silent three
    times while the laser goes on:

    - 600-660 s, power-cycled, its counters from zero joined at the last pose as baromapd
      records it: the motion across is lost (the robot drove 18 m and turned 161 degrees);
    - 1000-1060 s, unplugged, its counters going on;
    - 1500-1505 s, power-cycled, from zero in a frame of its own as another recorder leaves
      it (a jump the mapping joins; the robot turned 120 degrees on the spot).

    The scans inside are left out of the map; after each power cycle the chain is looked
    for in the map from before the gap. Without that search the floors after the first
    power cycle are lost (21 m RMS over the scans the odometry spoke for)."""
    from structlog.testing import capture_logs

    silent = tmp_path / "silent.mcap"
    left_out = silenced(
        long_run,
        silent,
        [
            Silence("/odom", 600, 660, counters="joined"),
            Silence("/odom", 1000, 1060),
            Silence("/odom", 1500, 1505, counters="zeroed"),
        ],
    )
    assert left_out[0] > 500 and left_out[1] > 500 and left_out[2] > 40
    with capture_logs() as logs:
        score = score_silence(silent, tmp_path / "maps")
    events = [e["event"] for e in logs]
    said = [e for e in logs if e["event"] == "odometry silent"]
    assert len(said) == 1 and said[0]["stretches"] == 3
    assert said[0]["seconds"] == pytest.approx(125.0, abs=1.0)
    assert events.count("odometry counted from zero again: joined at the pose before") == 1
    assert score.stats["odometry_gaps"] == 3
    assert score.stats["relocated"] == 2  # the power cycles, not the counters that went on
    assert score.stats["untied_keyframes"] == 0
    assert 1200 < score.blind_scans < 1400
    assert score.kept_rms_m < 0.07
    assert score.kept_max_m < 0.4
    assert score.worst_lobby_m < 0.15
    # the trajectory holds the poses the SLAM estimated, not those drawn across the gaps
    building = yaml.safe_load((tmp_path / "maps" / "building.yaml").read_text())
    tum = (tmp_path / "maps" / "trajectory.tum").read_text().splitlines()
    assert len(tum) == building["scans"] - score.blind_scans
    # and so does the path in maps.mcap: every pose drawn is one of the trajectory's
    from scipy.spatial import cKDTree

    estimated = np.array([[float(r[1]), float(r[2])] for r in map(str.split, tum)])
    (path,) = (r.message for r in read_messages(tmp_path / "maps" / "maps.mcap", ["/path"]))
    drawn = np.array([[p.position.x, p.position.y] for p in path.poses])
    assert len(drawn) > 1000
    assert cKDTree(estimated).query(drawn)[0].max() < 1e-5
