"""``sim record``: a simulated run in MCAP whose devices agree with the truth topics."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from baromap.cli.main import main
from baromap.messages import BeamFlag, LaserScan, Odometry, PressureSample, TruthFloor, TruthPose
from baromap.odometry.robot_metadata import ROBOT_METADATA, model_from_metadata
from baromap.protocols.robot_models import DEFAULT_MODEL
from baromap.recording import read_messages, read_metadata
from baromap.sim.building import make_building
from baromap.sim.laser import LaserConfig, cast
from baromap.sim.record import (
    CAR_DOOR_SEGMENT,
    METADATA_NAME,
    REFERENCE_TOPIC,
    doors_closed,
    record_run,
)
from baromap.sim.scenario import make_scenario, pressure_run

#: Seconds to minutes of CPU each: `make test` runs them, `make check` does not.
pytestmark = pytest.mark.slow

MINUTES = 4.0
ROUTE = [1, 2, 0]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "run.mcap"
    summary = record_run(path, seed=5, floors=3, minutes=MINUTES, route=ROUTE, progress=False)
    assert summary.counts["/scan"] > 0
    return path


@pytest.fixture(scope="module")
def messages(recording: Path) -> dict[str, list]:  # type: ignore[type-arg]
    out: dict[str, list] = {}  # type: ignore[type-arg]
    for rec in read_messages(recording):
        out.setdefault(rec.topic, []).append(rec.message)
    return out


def test_topics_rates_and_metadata(recording: Path, messages: dict[str, list]) -> None:  # type: ignore[type-arg]
    seconds = MINUTES * 60
    assert len(messages["/baro"]) == int(seconds * 25)
    assert len(messages[REFERENCE_TOPIC]) == int(seconds * 25)
    assert abs(len(messages["/scan"]) - seconds * LaserConfig().scan_rate_hz) <= 1
    assert len(messages["/odom"]) == int(seconds * 10)
    assert len(messages["/truth/pose"]) == len(messages["/scan"])
    assert all(isinstance(m, TruthFloor) for m in messages["/truth/floor"])
    assert "/tf" in {rec.topic for rec in read_messages(recording, topics=["/tf"])}
    meta = read_metadata(recording)[METADATA_NAME]
    assert (int(meta["seed"]), int(meta["floors"]), float(meta["minutes"])) == (5, 3, MINUTES)
    assert json.loads(meta["route"]) == ROUTE
    building = make_building(int(meta["seed"]), int(meta["floors"]))
    assert json.loads(meta["elevations_m"]) == pytest.approx(list(building.elevations_m), abs=1e-3)
    assert json.loads(meta["laser"])["angle_deg"] == 180
    assert [(t["from"], t["to"]) for t in json.loads(meta["transitions"])] == [(1, 2), (2, 0)]
    # The robot record the daemon writes: the model the host chose from the reported subclass.
    robot = read_metadata(recording)[ROBOT_METADATA]
    assert (robot["model"], robot["model_source"]) == (DEFAULT_MODEL.name, "reported")
    assert robot["reported_subclass"] == DEFAULT_MODEL.name
    assert model_from_metadata(read_metadata(recording)) == DEFAULT_MODEL


def test_messages_are_in_time_order(recording: Path) -> None:
    times = [rec.log_time_ns for rec in read_messages(recording)]
    assert times == sorted(times)


def test_baro_matches_pressure_run_through_the_wire_format(messages: dict[str, list]) -> None:  # type: ignore[type-arg]
    run = pressure_run(5, floors=3, minutes=MINUTES, route=ROUTE)
    baro: list[PressureSample] = messages["/baro"]
    got = np.array([m.pressure_pa for m in baro])
    assert np.array_equal(got, run.pressure_pa)
    assert [m.t_ns for m in baro] == run.t_ns.tolist()
    assert [m.seq for m in baro[:3]] == [0, 1, 2]
    ref = np.array([m.pressure_pa for m in messages[REFERENCE_TOPIC]])
    assert np.array_equal(ref, run.reference_pa)


def test_truth_floor_follows_the_rides(messages: dict[str, list]) -> None:  # type: ignore[type-arg]
    floors = [m.floor for m in messages["/truth/floor"]]
    changes = [f for i, f in enumerate(floors) if i == 0 or f != floors[i - 1]]
    assert changes == [1, None, 2, None, 0]


def test_scans_agree_with_the_floor_plan_at_the_true_pose(messages: dict[str, list]) -> None:  # type: ignore[type-arg]
    sc = make_scenario(5, floors=3, minutes=MINUTES, route=ROUTE)
    scans: list[LaserScan] = messages["/scan"]
    poses: list[TruthPose] = messages["/truth/pose"]
    cfg = LaserConfig()
    checked = valid_total = finite_total = 0
    worst = []
    for scan, pose in zip(scans[::7], poses[::7], strict=True):
        assert scan.t_ns == pose.t_ns
        assert scan.beam_count == 181
        assert scan.angle_min_rad == pytest.approx(-math.pi / 2)
        if pose.floor < 0:
            continue
        walls = sc.building.floors[pose.floor].walls_m
        if doors_closed(sc, np.array([(pose.t_ns - sc.start_ns) / 1e9]))[0]:
            walls = np.concatenate([walls, CAR_DOOR_SEGMENT])
        truth, _ = cast(
            walls, np.array([[pose.x_m, pose.y_m]]), np.array([pose.theta_rad]), cfg.angles_rad, 8.3
        )
        truth = truth[0]
        valid = scan.valid()
        # Nothing reported valid where the plan has no wall in range.
        assert not np.any(valid & ~np.isfinite(truth))
        assert np.all(scan.flags[~valid] & BeamFlag.error_mask())
        both = valid & np.isfinite(truth)
        if both.any():
            worst.append(np.percentile(np.abs(scan.ranges_m[both] - truth[both]), 99))
        inside = np.isfinite(truth) & (truth < 8.0)
        checked += 1
        valid_total += (valid & inside).sum()
        finite_total += inside.sum()
    assert checked > 20
    # Within the noise model: 5 mm RMS, 15 mm systematic, 1 mm units.
    assert np.median(worst) < 0.04
    assert max(worst) < 0.1
    # Dropouts are a few percent, not more.
    assert valid_total / finite_total > 0.9


def test_odometry_has_the_p3at_error_model(messages: dict[str, list]) -> None:  # type: ignore[type-arg]
    odom: list[Odometry] = messages["/odom"]
    sc = make_scenario(5, floors=3, minutes=MINUTES, route=ROUTE)
    t = (np.array([o.t_ns for o in odom]) - sc.start_ns) / 1e9
    truth = sc.truth(t)
    assert odom[0].x_m == pytest.approx(0.0, abs=0.01)
    true_path = np.hypot(np.diff(truth.x), np.diff(truth.y)).sum()
    xy = np.array([[o.x_m, o.y_m] for o in odom])
    odo_path = np.hypot(*np.diff(xy, axis=0).T).sum()
    ratio = odo_path / true_path
    assert 0.97 < ratio < 1.03
    assert ratio != pytest.approx(1.0, abs=1e-4)  # there is a scale error
    # 15-bit counters wrap, the host integrator unwraps them.
    raw = np.array([o.raw_x for o in odom])
    assert raw.max() <= 0x7FFF
    assert all(isinstance(o.raw_theta, int) for o in odom)
    # Heading drifts away from the truth but stays plausible over a few minutes.
    th = np.unwrap([o.theta_rad for o in odom])
    true_th = np.unwrap(truth.theta) - truth.theta[0]
    drift = np.abs(th - true_th)
    assert drift[-1] > math.radians(0.1)
    assert drift.max() < math.radians(30)


def test_cli_record(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cli.mcap"
    code = main(["sim", "record", "-o", str(out), "--minutes", "1", "--floors", "2", "--seed", "3"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "simulated minutes" in printed
    assert "/scan" in printed
    meta = read_metadata(out)[METADATA_NAME]
    assert meta["floors"] == "2"
    assert read_metadata(out)[ROBOT_METADATA]["model"] == "p3at-sh"
    # Refuses to overwrite without --force.
    assert main(["sim", "record", "-o", str(out), "--minutes", "1"]) == 1


def test_cli_record_an_older_base(tmp_path: Path) -> None:
    """An old P2OS P3-AT counts in 2.15 mm units: its counters run 1/0.465 times slower, and
    its recording says so, so /odom in metres is the same motion either way."""
    runs = {}
    for model in ("p3at-sh", "p3at"):
        out = tmp_path / f"{model}.mcap"
        args = ["-o", str(out), "--minutes", "2", "--floors", "2", "--robot-model", model]
        assert main(["sim", "record", *args]) == 0
        assert read_metadata(out)[ROBOT_METADATA]["model"] == model
        runs[model] = [r.message for r in read_messages(out, ["/odom"])]
    new, old = runs["p3at-sh"], runs["p3at"]
    assert [o.x_m for o in old] == pytest.approx([o.x_m for o in new], abs=0.01)
    assert [o.y_m for o in old] == pytest.approx([o.y_m for o in new], abs=0.01)
    far = max(range(len(new)), key=lambda i: abs(new[i].x_m) + abs(new[i].y_m))
    assert abs(new[far].x_m) + abs(new[far].y_m) > 0.1  # the robot did move
    assert (old[far].raw_x, old[far].raw_y) != (new[far].raw_x, new[far].raw_y)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--minutes", "nan"], "minutes must be"),
        (["--minutes", "inf"], "minutes must be"),
        (["--minutes", "1e9"], "minutes must be"),
        (["--drift", "nan"], "drift must be"),
        (["--rate", "inf"], "rate must be"),
        (["--rate", "1e-9"], "fewer than two samples"),
        (["--seed", "-5"], "seed must not be negative"),
        (["--floors", "0"], "floors must be"),
        (["--robot-model", "p9"], "unknown robot model"),
    ],
)
def test_cli_record_refuses_nonsense_in_one_line(
    args: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["sim", "record", "-o", str(tmp_path / "x.mcap"), "--minutes", "0.05", *args])
    assert code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not (tmp_path / "x.mcap").exists()
