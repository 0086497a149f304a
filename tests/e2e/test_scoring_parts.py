"""The pieces the end-to-end checks stand on: a map file read back as map_server reads it, and
recording time mapped to simulated time through a truth log."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from baromap.evaluation.map_files import read_map, read_trajectory, score_outputs
from baromap.evaluation.twin_truth import HostClock, sim_timeline
from baromap.mapping.export import write_map_server, write_tum
from baromap.mapping.occupancy import OccupancyGrid
from baromap.sim.building import make_building
from baromap.sim.twins.truth import FrameTruth


def _grid(occupied: list[tuple[int, int]], free: list[tuple[int, int]]) -> OccupancyGrid:
    log_odds = np.zeros((20, 30), dtype=np.float32)
    for r, c in occupied:
        log_odds[r, c] = 3.0
    for r, c in free:
        log_odds[r, c] = -3.0
    return OccupancyGrid(log_odds, (-1.5, 2.0), 0.1)


def test_a_map_file_reads_back_cell_for_cell_with_rows_from_the_lowest_y(tmp_path: Path) -> None:
    grid = _grid(occupied=[(0, 0), (19, 29), (3, 7)], free=[(10, 10), (0, 29)])
    _, yml = write_map_server(grid, tmp_path, "floor_0")
    back = read_map(yml, 0, 0.0)
    assert back.origin_xy == pytest.approx(grid.origin_xy)
    assert back.resolution == pytest.approx(0.1)
    assert np.array_equal(back.occupied, grid.occupied())
    assert np.array_equal(back.free, grid.free())
    # cell (row 3, col 7) is 0.3-0.4 m above and 0.7-0.8 m right of the origin corner
    (centre,) = back.cell_centres(np.isin(np.arange(600).reshape(20, 30), [3 * 30 + 7]))
    assert centre == pytest.approx((-1.5 + 0.75, 2.0 + 0.35))


def test_a_tum_trajectory_reads_back(tmp_path: Path) -> None:
    t = np.array([1_700_000_000_000_000_001, 1_700_000_000_500_000_000], dtype=np.int64)
    poses = np.array([[1.0, 2.0, 0.5], [-3.0, 4.0, -2.5]])
    write_tum(tmp_path / "t.tum", t, poses, np.array([0.0, 5.25]))
    back = read_trajectory(tmp_path / "t.tum")
    assert np.array_equal(back.t_ns, t)
    assert back.xyt[:, :2] == pytest.approx(poses[:, :2])
    assert back.xyt[:, 2] == pytest.approx(poses[:, 2], abs=1e-8)
    assert back.z_m == pytest.approx([0.0, 5.25])


def test_a_map_drawn_from_the_true_walls_scores_full_marks_and_a_turned_one_does_not(
    tmp_path: Path,
) -> None:
    """Score a map made of the plan itself (walls occupied, a patch of free space), placed by a
    trajectory that is the truth shifted and turned: the fit undoes the shift and turn."""
    building = make_building(0, 2)
    plan = building.floors[0]
    res = 0.05
    walls = plan.occupancy_truth(res)
    rows, cols = np.nonzero(walls)
    keep = (cols * res > 20) & (cols * res < 40)  # the middle of the building
    truth_xyt = np.array([[25.0 + k, 11.4, 0.0] for k in range(10)])
    offset = np.array([3.0, -2.0, math.radians(30)])
    c, s = math.cos(offset[2]), math.sin(offset[2])

    def to_map(xy: np.ndarray) -> np.ndarray:
        return (
            np.column_stack([c * xy[:, 0] - s * xy[:, 1], s * xy[:, 0] + c * xy[:, 1]]) + offset[:2]
        )

    wall_xy = np.column_stack([(cols[keep] + 0.5) * res, (rows[keep] + 0.5) * res])
    for name, turn in (("right", 0.0), ("turned", math.radians(5))):
        out = tmp_path / name
        out.mkdir()
        cs, sn = math.cos(turn), math.sin(turn)
        drawn = to_map(wall_xy) @ np.array([[cs, sn], [-sn, cs]])  # turned about the map origin
        lo = drawn.min(axis=0) - 1.0
        shape = np.ceil((drawn.max(axis=0) + 1.0 - lo) / res).astype(int)
        log_odds = np.zeros((shape[1], shape[0]), dtype=np.float32)
        ij = np.floor((drawn - lo) / res).astype(int)
        log_odds[ij[:, 1], ij[:, 0]] = 3.0
        write_map_server(OccupancyGrid(log_odds, (float(lo[0]), float(lo[1])), res), out, "floor_0")
        est = np.column_stack([to_map(truth_xyt[:, :2]), truth_xyt[:, 2] + offset[2]])
        t = np.arange(10, dtype=np.int64) * 1_000_000_000
        write_tum(out / "trajectory.tum", t, est, np.zeros(10))
        entry = "{index: 0, elevation_m: 0.0, visits: 1, map: floor_0.yaml, image: floor_0.pgm}"
        (out / "building.yaml").write_text(f"floors:\n- {entry}\n")
        (score,) = score_outputs(out, building, t, truth_xyt, np.zeros(10, dtype=np.int64))
        if name == "right":
            assert score.occupied_precision > 0.97
            assert score.lobby_error_deg < 0.1
        else:
            assert score.occupied_precision < 0.5


def test_recording_time_maps_to_simulated_time_through_the_truth_log() -> None:
    clock = HostClock(wall0_ns=1_800_000_000_000_000_000, mono0_ns=5_000_000_000)
    speed = 6.0
    records = [
        FrameTruth("lms200", k, 5_000_000_000 + k * 10_000_000, k * 0.01 * speed)
        for k in range(100)
    ]
    records += [FrameTruth("baro", k, 5_000_000_000 + k * 7_000_000, 99.0) for k in range(10)]
    timeline = sim_timeline(records, clock)
    assert timeline.speed == pytest.approx(speed)
    unix = clock.wall0_ns + 500_000_000  # half a second of recording
    assert timeline.sim_s_at([unix])[0] == pytest.approx(3.0)
    assert timeline.unix_ns_at([3.0])[0] == pytest.approx(unix, abs=1)
