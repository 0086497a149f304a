"""Revisit consistency: scans of a known world, on the true path and on paths bent by known
amounts, where which one agrees with its scans is known."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from baromap.evaluation.consistency import revisit_corrections
from baromap.mapping import se2
from baromap.mapping.revisits import (
    ScanGeometry,
    consistency,
    revisit_partners,
    travel_m,
)
from baromap.mapping.scans import ScanBlock
from baromap.sim.laser import cast

# a ring corridor round a block, 2 m wide on the long sides, with a pillar in one corner
WALLS = np.array(
    [
        [0, 0, 20, 0],
        [20, 0, 20, 12],
        [20, 12, 0, 12],
        [0, 12, 0, 0],
        [4, 4, 16, 4],
        [16, 4, 16, 8],
        [16, 8, 4, 8],
        [4, 8, 4, 4],
        [18.5, 0.5, 19.2, 0.5],
        [19.2, 0.5, 19.2, 1.2],
        [19.2, 1.2, 18.5, 1.2],
        [18.5, 1.2, 18.5, 0.5],
    ],
    dtype=np.float64,
)
ANGLES = np.radians(np.arange(-90.0, 90.0, 1.0))


def _ring_path(laps: int) -> np.ndarray:
    """Poses every 0.5 m round the corridor's middle line, ``laps`` times."""
    corners = np.array([[2, 2], [18, 2], [18, 10], [2, 10], [2, 2]], dtype=np.float64)
    poses = []
    for _ in range(laps):
        for a, b in itertools.pairwise(corners):
            heading = math.atan2(b[1] - a[1], b[0] - a[0])
            steps = round(float(np.hypot(*(b - a))) / 0.5)
            for k in range(steps):
                poses.append([*(a + (b - a) * k / steps), heading])
    return np.array(poses)


def _scans(poses: np.ndarray) -> ScanBlock:
    ranges, _ = cast(WALLS, poses[:, :2], poses[:, 2], ANGLES, 20.0)
    return ScanBlock(
        t_ns=np.arange(len(poses), dtype=np.int64),
        ranges_m=np.where(np.isfinite(ranges), ranges, np.nan).astype(np.float32),
        angles_rad=ANGLES,
        range_max_m=20.0,
        laser_offset=np.zeros(3),
    )


def _bent(poses: np.ndarray, deg_per_m: float) -> np.ndarray:
    """The same steps, each turned by a creep proportional to its length: a trajectory that
    drifts slowly in heading, as a SLAM's does between loop closures."""
    out = [poses[0]]
    for a, b in itertools.pairwise(poses):
        step = se2.between(a, b)
        step[2] += math.radians(deg_per_m) * float(np.hypot(step[0], step[1]))
        out.append(se2.compose(out[-1], step))
    return np.array(out)


@pytest.fixture(scope="module")
def ring() -> tuple[np.ndarray, ScanGeometry, list[np.ndarray]]:
    truth = _ring_path(2)
    geometry = ScanGeometry(_scans(truth))
    return truth, geometry, revisit_partners(truth, geometry.radius_m)


def test_partners_are_revisits_not_neighbours(
    ring: tuple[np.ndarray, ScanGeometry, list[np.ndarray]],
) -> None:
    truth, _, partners = ring
    travel = travel_m(truth)
    lap = len(truth) // 2
    assert all(np.all(np.abs(travel[p] - travel[i]) >= 10.0) for i, p in enumerate(partners))
    # every scan of the first lap is seen again on the second, and only there
    assert all(len(partners[i]) > 0 and np.all(partners[i] >= lap) for i in range(lap))


def test_true_path_is_the_most_consistent(
    ring: tuple[np.ndarray, ScanGeometry, list[np.ndarray]],
) -> None:
    truth, geometry, partners = ring
    scores = [
        consistency(geometry, _bent(truth, creep), partners).mean_m for creep in (0, 0.01, 0.05)
    ]
    assert scores[0] < 0.001  # exact scans: their endpoints lie on their own outlines
    assert scores[0] < scores[1] < scores[2]


def test_a_rigid_motion_of_the_whole_path_changes_nothing(
    ring: tuple[np.ndarray, ScanGeometry, list[np.ndarray]],
) -> None:
    truth, geometry, partners = ring
    bent = _bent(truth, 0.1)
    moved = se2.compose(np.array([3.0, -7.0, 0.8]), bent)
    a = consistency(geometry, bent, partners)
    b = consistency(geometry, moved, partners)
    np.testing.assert_allclose(a.per_scan_m, b.per_scan_m, atol=1e-9)


def test_one_lap_has_no_revisit_to_score() -> None:
    truth = _ring_path(1)[:40]  # 20 m down one side and round a corner: nowhere seen twice
    geometry = ScanGeometry(_scans(truth))
    score = consistency(geometry, truth, revisit_partners(truth, geometry.radius_m))
    assert score.scored == 0
    assert math.isnan(score.mean_m)


@pytest.mark.slow
def test_revisit_moves_find_the_bend(
    ring: tuple[np.ndarray, ScanGeometry, list[np.ndarray]],
) -> None:
    truth, geometry, partners = ring
    exact = revisit_corrections(geometry, truth, partners)
    assert np.nanmax(exact[:, :2]) < 1e-6
    creep = 0.01  # deg per metre: a lap of 48 m comes back turned by 0.48 deg
    bent = revisit_corrections(geometry, _bent(truth, creep), partners)
    lap_deg = creep * travel_m(truth)[len(truth) // 2]
    turn = math.degrees(float(np.nanmedian(bent[:, 1])))
    assert 0.5 * lap_deg < turn < 1.5 * lap_deg
    assert np.nanmedian(bent[:, 0]) > 0.02  # and centimetres of shift on a 20 x 12 m ring


def test_partners_stay_on_their_own_floor(
    ring: tuple[np.ndarray, ScanGeometry, list[np.ndarray]],
) -> None:
    """Two laps of one ring given as two floors: the same coordinates, not the same walls."""
    truth, geometry, partners = ring
    lap = len(truth) // 2
    floors = np.repeat([0, 1], [lap, len(truth) - lap])
    one_floor = revisit_partners(truth, geometry.radius_m, group=np.zeros(len(truth), np.int64))
    assert all(np.array_equal(a, b) for a, b in zip(one_floor, partners, strict=True))
    assert not any(len(p) for p in revisit_partners(truth, geometry.radius_m, group=floors))
    # scans on no floor (between floors) have none, and are nobody's
    between = np.where(np.arange(len(truth)) < lap, -1, 0)
    assert not any(len(p) for p in revisit_partners(truth, geometry.radius_m, group=between))
