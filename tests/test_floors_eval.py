"""Scoring, and the bars of the floor-detection issue on real and simulated data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from baromap.cli.main import main
from baromap.errors import InputFormatError
from baromap.evaluation.floors import (
    SimSettings,
    evaluate,
    evaluate_case,
    real_cases,
    sim_case,
)
from baromap.floors import FloorDetectorConfig, decided_at
from baromap.floors.detection import FloorDetection, Transition
from baromap.floors.evaluation import (
    Score,
    score,
    truth_from_series,
    truth_from_waypoints,
    with_settle_times,
)

S = 1_000_000_000


def _detection(transitions: list[Transition], t_end_s: int = 100) -> FloorDetection:
    from baromap.floors.detection import Segment

    t = np.arange(0, t_end_s * S, S // 10, dtype=np.int64)
    segments = []
    start, floor = 0, transitions[0].from_floor if transitions else 0
    for tr in transitions:
        segments.append(Segment(start, tr.t_start_ns, floor))
        start, floor = tr.t_end_ns, tr.to_floor
    segments.append(Segment(start, int(t[-1]), floor))
    return FloorDetection("test", (), tuple(transitions), tuple(segments), t, t * 0.0, t * 0.0)


def test_waypoint_truth_windows() -> None:
    truth = truth_from_waypoints([(10 * S, 0), (20 * S, 0), (40 * S, -1), (50 * S, 1)])
    assert [(x.t_begin_ns, x.t_end_ns, x.from_floor, x.to_floor) for x in truth.transitions] == [
        (20 * S, 40 * S, 0, -1),
        (40 * S, 50 * S, -1, 1),
    ]
    floors = truth.floor_at(np.array([5, 15, 30, 45, 50, 60]) * S)
    assert np.isnan(floors[0]) and floors[1] == 0 and np.isnan(floors[2])
    assert floors[4] == 1 and np.isnan(floors[5])
    with pytest.raises(InputFormatError):
        truth_from_waypoints([])


def test_matching_counts_missed_false_direction_and_storeys() -> None:
    truth = truth_from_series(
        np.array([0, 10, 20, 30, 40, 50, 60, 99]) * S,
        [0, 0, np.nan, 2, 2, np.nan, 1, 1],
    )
    good = Transition(12 * S, 28 * S, 31 * S, 0, 2, -70.0, 6.0)
    two_storeys = Transition(42 * S, 58 * S, 62 * S, 2, 0, 70.0, -6.0)
    spurious = Transition(80 * S, 82 * S, 84 * S, 0, 1, -35.0, 3.0)
    s = score(_detection([good, two_storeys, spurious]), truth)
    assert (s.true, s.found, s.missed, s.false) == (2, 2, 0, 1)
    assert s.direction_right == 2 and s.storeys_right == 1
    assert s.delays_s == (1.0, 2.0)
    late = Transition(12 * S, 28 * S, 60 * S, 0, 2, -70.0, 6.0)
    assert score(_detection([late]), truth).found == 1  # post-run: when is no matter
    assert score(_detection([late]), truth, max_delay_s=15.0).found == 0


def test_settle_time_is_when_the_transient_has_faded() -> None:
    t = np.arange(0, 40 * S, S // 10, dtype=np.int64)
    floor = np.where(t < 20 * S, 0.0, np.where(t < 25 * S, np.nan, 1.0))
    truth = truth_from_series(t, floor)
    after = np.clip(t - 25 * S, 0, None) / S
    # a 10 Pa transient after the stop, decaying with 1 s: inside 1.2 Pa after 2.12 s
    own = np.where(t < 25 * S, 0.0, -40.0 + 10.0 * np.exp(-after))
    (settled,) = with_settle_times(truth, t, own).transitions
    assert settled.t_settled_ns == pytest.approx(27.2 * S, abs=0.15 * S)
    own[-1] += 50.0  # still moving at the end of the data: settled no earlier than that
    (late,) = with_settle_times(truth, t, own).transitions
    assert late.t_settled_ns == t[-1]


def meets_the_bar(s: Score) -> bool:
    return s.found == s.true and s.false == 0 and s.storeys_right == s.true


def test_real_logs_online_meets_the_bar_live_and_post_run(shared_data: Path) -> None:
    for case in real_cases(shared_data / "baro"):
        result = evaluate_case(case, "online")
        assert result.live is not None
        assert meets_the_bar(result.post_run), case.name
        assert meets_the_bar(result.live.score), case.name
        assert result.live.agrees, result.live.disagreement
        if case.truth.transitions:
            assert result.post_run.true >= 4  # the log with floor changes has them
        else:
            assert result.post_run.accuracy == 1.0  # the control never leaves its floor


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(20))
def test_twenty_simulated_runs_meet_the_bar(seed: int) -> None:
    """The online method on 20 seeds x 46 min, 1.5 hPa/h drift, spikes, revisits, odometry."""
    result = evaluate_case(sim_case(seed), "online")
    s = result.post_run
    assert meets_the_bar(s)
    assert s.accuracy > 0.99  # revisited floors get their old id back
    assert s.height_error_m is not None and s.height_error_m < 0.5
    assert result.live is not None and meets_the_bar(result.live.score)
    # what a consumer of the events knew equals the post-run cut of the run
    assert result.live.agrees, result.live.disagreement


@pytest.mark.slow
def test_with_the_robot_in_the_car_a_visit_is_decided_as_the_car_stops() -> None:
    """With odometry showing the robot stood in the car, the floor is decided as the car
    stops, seconds before the robot drives off, and the account is the rides the car made."""
    from baromap.floors.replay import replay
    from baromap.sim.motion import Move
    from baromap.sim.scenario import make_scenario

    config = FloorDetectorConfig()
    case = sim_case(3)
    scenario = make_scenario(3)
    detector, _, _ = replay(
        case.t_ns, case.pressure_pa, case.temperature_c, config, odometry=case.odometry
    )
    rides = np.flatnonzero(scenario.moves.kind == Move.RIDE)
    t = np.arange(0.0, scenario.duration_s, 0.05)
    truth = scenario.truth(t)
    decided = decided_at(detector.events)
    events = detector.transitions
    assert len(events) == len(rides)
    for event, ride in zip(events, rides, strict=True):
        end = float(scenario.moves.t0[ride] + scenario.moves.duration[ride])
        after = t >= end
        car = truth.x[after][0], truth.y[after][0]
        away = np.hypot(truth.x[after] - car[0], truth.y[after] - car[1]) >= config.leave_m
        drove_off = float(t[after][np.argmax(away)])
        at = (decided[event.event_id] - scenario.start_ns) / S
        # decided while the robot still stood in the car (how soon is the bench's figure)
        assert end - 1.0 < at < drove_off, (at - end, drove_off - end)
        assert event.to_name == detector.registry.name(event.to_id)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 7, 13])
def test_simulated_runs_with_drift_and_spikes(seed: int) -> None:
    _, s = evaluate(sim_case(seed, SimSettings(drift_hpa_per_h=3.0)), "online")
    assert s.true >= 4 and meets_the_bar(s)
    assert s.accuracy > 0.99  # revisited floors keep their id
    assert s.height_error_m is not None and s.height_error_m < 0.5


@pytest.mark.slow
@pytest.mark.parametrize(
    ("stops", "odometry"), [("stay", True), ("stay", False), ("leave", True), ("leave", False)]
)
def test_rides_that_stop_on_the_way(stops: str, odometry: bool) -> None:
    """A halt at a passing floor with the robot inside is part of the ride; getting out to
    make room is a visit (with odometry at once, without once it lasted min_visit_s)."""
    plain = sim_case(4)
    case = sim_case(4, SimSettings(stops=stops, use_odometry=odometry))
    # the two rides past a floor: halted (no new floor change) or a visit (two more)
    more = {"stay": 0, "leave": 2}[stops]
    assert len(case.truth.transitions) == len(plain.truth.transitions) + more
    result = evaluate_case(case, "online")
    assert result.live is not None
    assert meets_the_bar(result.post_run), result.post_run
    assert meets_the_bar(result.live.score), result.live.score
    assert result.live.agrees, result.live.disagreement


def test_eval_floors_command(shared_data: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = shared_data / "baro" / "IPIN2023_T3_TrainingTrial51_repetition02.txt"
    assert main(["eval-floors", str(log), "--method", "online", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)["online"]
    for figures in (result["post_run"], result["live"]):
        assert (figures["found"], figures["false"], figures["storeys_right"]) == (8, 0, 8)
    assert result["live"]["equals_post_run"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["eval-floors", "--real", "{missing}"], "is not a directory of IPIN logs"),
        (["eval-floors", "--real", "{empty}"], "holds no IPIN log"),
        (["eval-floors", "--real", "{empty}", "--sweep"], "holds no IPIN log"),
        (["detect", "{csv}", "--plot", "{empty}"], "cannot write the plot"),
        (["detect", "{csv}", "--plot", "{empty}/x.nosuchformat"], "cannot write the plot"),
    ],
)
def test_bad_arguments_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    """Nothing to score is an error, not an empty table with exit status 0."""
    csv = tmp_path / "p.csv"
    csv.write_text("".join(f"{k / 10},97000.0\n" for k in range(50)))
    empty = tmp_path / "empty"
    empty.mkdir()
    paths = {"missing": tmp_path / "missing", "empty": empty, "csv": csv}
    assert main([arg.format(**paths) for arg in argv]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("baromap: error: ") and message in err[0]
