"""The SLAM run more than once, the run whose revisits agree best with the scans kept."""

from __future__ import annotations

import multiprocessing
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from baromap.errors import ConfigError
from baromap.evaluation.laser_logs import PreparedLog, odometry_model, run_prepared
from baromap.mapping.restarts import run_slam_best_of
from baromap.mapping.revisits import ScanGeometry, consistency, revisit_partners
from baromap.mapping.slam import SlamResult

#: Seconds to minutes of CPU each: `make test` runs them, `make check` does not.
pytestmark = pytest.mark.slow


def _processes() -> int:
    """Processes two workers make runs in now: a process running other threads is not forked
    (restarts._Workers), and a test before may have left one running."""
    return 2 if threading.active_count() == 1 else 1


def test_a_run_gone_wrong_is_replaced_by_one_whose_revisits_agree_better(
    shared_data: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Freiburg 079 with every 30th scan kept (a scan every 2-3 m), default odometry, seed 14:
    the first run goes 1.54 m from GMapping's poses. The second run agrees better with its
    own scans at the revisits, is kept, and is within 0.2 m (0.141 m)."""
    import baromap.mapping.restarts as restarts
    from baromap.evaluation.trajectory import trajectory_error

    # every run made in this process and the odometry it was made from; the first run (the
    # odometry as given) is made once and handed out again when asked for again
    made: list[SlamResult] = []
    made_from: list[np.ndarray] = []
    inner = restarts.run_slam

    def run_slam(scans: object, odom: np.ndarray, *args: object, **kwargs: object) -> SlamResult:
        if made and np.array_equal(odom, made_from[0]):
            return made[0]
        made.append(inner(scans, odom, *args, **kwargs))  # type: ignore[arg-type]
        made_from.append(odom)
        return made[-1]

    monkeypatch.setattr(restarts, "run_slam", run_slam)
    log = PreparedLog(shared_data / "laser", "fr079", stride=30)
    model = odometry_model("default", 14)
    best = run_prepared(log, 14, odometry=model, runs=2)
    one = made[0]
    assert len(made) == 2
    assert trajectory_error(one.scan_poses, log.reference).rms_m > 0.3
    assert best.result.stats["runs"] == 2
    assert best.result.stats["run_kept"] == 1
    assert best.slam_ate.rms_m < 0.2
    # judged on the pairs the first run chose, as the restarts judge every run
    geometry = ScanGeometry(log.block)
    partners = revisit_partners(one.scan_poses, geometry.radius_m)
    first = consistency(geometry, one.scan_poses, partners).mean_m
    assert best.result.stats["revisits_mm"] < first * 1000
    assert best.result.stats["revisits_mm"] == pytest.approx(
        consistency(geometry, best.result.scan_poses, partners).mean_m * 1000
    )
    # the second run made in another process while the first is (handed out) here: the
    # same run
    processes = _processes()
    beside = run_prepared(log, 14, odometry=model, runs=2, workers=2)
    np.testing.assert_array_equal(beside.result.scan_poses, best.result.scan_poses)
    assert beside.result.stats.pop("run_processes") == processes
    assert best.result.stats.pop("run_processes") == 1
    assert beside.result.stats == best.result.stats
    assert multiprocessing.active_children() == []


def test_a_run_with_no_revisit_is_not_restarted(shared_data: Path) -> None:
    """Freiburg 079's first 600 scans, every tenth: a corridor driven once, no place seen
    again after a long way round, so nothing could tell two runs apart; the first is kept
    and no other is made."""
    log = PreparedLog(shared_data / "laser", "fr079", scans=slice(0, 600), stride=10)
    once = run_prepared(log, 0)
    asked = run_prepared(log, 0, runs=3)
    assert asked.result.stats["runs"] == 1
    assert np.isnan(asked.result.stats["revisits_mm"])
    np.testing.assert_array_equal(asked.result.scan_poses, once.result.scan_poses)
    # runs already started in another process are stopped, unread
    beside = run_prepared(log, 0, runs=3, workers=2)
    assert beside.result.stats["runs"] == 1
    np.testing.assert_array_equal(beside.result.scan_poses, once.result.scan_poses)
    assert multiprocessing.active_children() == []


@pytest.mark.parametrize("runs", [0, -1, 1.5, True])
def test_runs_must_be_a_whole_number_of_at_least_one(runs: object) -> None:
    empty = np.zeros((0, 3))
    none = np.zeros(0, dtype=np.int64)
    with pytest.raises(ConfigError, match="runs"):
        run_slam_best_of(None, empty, none, none, runs=runs)  # type: ignore[arg-type]


@pytest.mark.parametrize("workers", [0, -2, 2.0, False])
def test_workers_must_be_a_whole_number_of_at_least_one(workers: object) -> None:
    empty = np.zeros((0, 3))
    none = np.zeros(0, dtype=np.int64)
    with pytest.raises(ConfigError, match="workers"):
        run_slam_best_of(None, empty, none, none, runs=3, workers=workers)  # type: ignore[arg-type]


def _fake_runs(monkeypatch: pytest.MonkeyPatch, scores_mm: list[float]) -> list[int]:
    """run_slam replaced by a run whose poses say which run it was (0, 1, ... in the order
    made in this process), scored by ``scores_mm``; returns the runs made here."""
    import baromap.mapping.restarts as restarts
    from baromap.mapping.revisits import Consistency

    made: list[int] = []

    def fake_run(scans: object, odom: np.ndarray, *args: object, **kwargs: object) -> SlamResult:
        # runs 2.. see the odometry jittered: their order of making is the order asked
        run = 0 if not odom.any() else 1 + len(made) - made.count(0)
        made.append(run)
        poses = np.full((4, 3), float(run))
        graph: Any = None
        return SlamResult(np.arange(4), keyframe_poses=poses, scan_poses=poses, graph=graph)

    def fake_score(geometry: object, poses: np.ndarray, partners: object) -> Consistency:
        per_scan = np.full(4, scores_mm[int(poses[0, 0])] / 1000)
        return Consistency(per_scan_m=per_scan, overlap=np.ones(4))

    monkeypatch.setattr(restarts, "run_slam", fake_run)
    monkeypatch.setattr(restarts, "ScanGeometry", lambda scans: type("G", (), {"radius_m": 1.0}))
    monkeypatch.setattr(restarts, "revisit_partners", lambda *a, **k: [])
    monkeypatch.setattr(restarts, "consistency", fake_score)
    return made


@pytest.mark.parametrize(
    ("scores_mm", "kept"),
    [
        ([100.0, 99.0, 98.5], 0),  # within 2 %: the runs agree about equally, the first stays
        ([100.0, 97.0, 96.5], 2),  # a better run, then a better one still
        ([100.0, 97.9, 99.0], 1),
        ([100.0, 101.0, 97.5], 2),
    ],
)
def test_a_later_run_replaces_the_first_only_if_it_agrees_clearly_better(
    monkeypatch: pytest.MonkeyPatch, scores_mm: list[float], kept: int
) -> None:
    """The choice alone: each run's poses tell which run it was, each run's score is given."""
    made = _fake_runs(monkeypatch, scores_mm)
    zeros = np.zeros(4, dtype=np.int64)
    result = run_slam_best_of(None, np.zeros((4, 3)), zeros, zeros, runs=3)  # type: ignore[arg-type]
    assert made == [0, 1, 2]
    assert result.stats["run_kept"] == kept
    assert result.scan_poses[0, 0] == kept
    assert result.stats["revisits_mm"] == pytest.approx(scores_mm[kept])


def test_build_maps_refuses_no_runs_before_reading_the_recording(tmp_path: Path) -> None:
    from baromap.mapping.build import build_maps

    with pytest.raises(ConfigError, match="runs"):
        build_maps(tmp_path / "missing.mcap", tmp_path / "out", runs=0)
    assert not (tmp_path / "out").exists()


def test_a_run_its_worker_could_not_deliver_is_made_here(monkeypatch: pytest.MonkeyPatch) -> None:
    """The worker process dies before sending anything (killed, out of memory): its runs are
    made in the caller's process, and the choice is the one it would have been."""
    import baromap.mapping.restarts as restarts

    made = _fake_runs(monkeypatch, [100.0, 97.0, 96.5])
    here = os.getpid()
    inner = restarts.run_slam

    def dies_in_a_worker(*args: object, **kwargs: object) -> SlamResult:
        if os.getpid() != here:
            os._exit(3)
        return inner(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(restarts, "run_slam", dies_in_a_worker)
    zeros = np.zeros(4, dtype=np.int64)
    processes = _processes()
    result = run_slam_best_of(None, np.zeros((4, 3)), zeros, zeros, runs=3, workers=2)  # type: ignore[arg-type]
    assert made == [0, 1, 2]
    assert result.stats["run_kept"] == 2
    assert result.stats["run_processes"] == processes
    assert multiprocessing.active_children() == []


def test_without_fork_the_runs_are_made_here(monkeypatch: pytest.MonkeyPatch) -> None:
    """A platform that cannot fork (get_context("fork") raises ValueError): the runs are made
    in the caller's process, and the choice is the same."""
    import baromap.mapping.restarts as restarts

    made = _fake_runs(monkeypatch, [100.0, 97.0, 96.5])

    def no_fork(method: str) -> object:
        raise ValueError(f"cannot find context for {method!r}")

    monkeypatch.setattr(restarts, "get_context", no_fork)
    zeros = np.zeros(4, dtype=np.int64)
    result = run_slam_best_of(None, np.zeros((4, 3)), zeros, zeros, runs=3, workers=2)  # type: ignore[arg-type]
    assert made == [0, 1, 2]
    assert result.stats["run_kept"] == 2
    assert result.stats["run_processes"] == 1
