"""Mapping units: rigid motions, scan matcher, pose graph, occupancy grid, file formats."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from baromap.errors import ConfigError
from baromap.mapping import se2
from baromap.mapping.errors import MappingError
from baromap.mapping.export import (
    FREE_VALUE,
    OCCUPIED_VALUE,
    UNKNOWN_VALUE,
    read_pgm,
    write_map_server,
    write_tum,
)
from baromap.mapping.occupancy import build_grid
from baromap.mapping.odometry_calibration import OdometryCalibration
from baromap.mapping.pose_graph import Edge, PoseGraph
from baromap.mapping.relations import Relations, relation_errors
from baromap.mapping.scan_matcher import (
    LikelihoodField,
    SearchWindow,
    branch_and_bound_search,
    correlative_search,
    lowest_between,
    match,
    score_at,
)
from baromap.mapping.scans import ScanBlock
from baromap.mapping.segmentation import label_scans, moving_scans
from baromap.mapping.slam import (
    BETWEEN_FLOORS,
    MATCH_COV_SCALE,
    edge_covariance,
    match_information,
    place_on_ridge,
    scan_poses,
    spread_information,
)

# an L-shaped room with a pillar: walls as segments (x0, y0, x1, y1)
ROOM = np.array(
    [
        [0, 0, 10, 0],
        [10, 0, 10, 4],
        [10, 4, 4, 4],
        [4, 4, 4, 8],
        [4, 8, 0, 8],
        [0, 8, 0, 0],
        [6, 1.5, 7, 1.5],
        [7, 1.5, 7, 2.2],
        [7, 2.2, 6, 2.2],
        [6, 2.2, 6, 1.5],
    ],
    dtype=np.float64,
)
ANGLES = np.radians(np.arange(-90, 90, 1.0))


def cast(pose: np.ndarray, walls: np.ndarray = ROOM, angles: np.ndarray = ANGLES) -> np.ndarray:
    """Ranges from ``pose`` to the nearest wall along each beam (NaN when none)."""
    ang = pose[2] + angles
    d = np.stack([np.cos(ang), np.sin(ang)], axis=1)[:, None, :]
    a = walls[None, :, :2]
    e = (walls[:, 2:] - walls[:, :2])[None, :, :]
    o = pose[None, None, :2]
    denom = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((a - o)[..., 0] * e[..., 1] - (a - o)[..., 1] * e[..., 0]) / denom
        u = ((a - o)[..., 0] * d[..., 1] - (a - o)[..., 1] * d[..., 0]) / denom
    t = np.where((t > 0) & (u >= 0) & (u <= 1), t, np.inf)
    r = t.min(axis=1)
    return np.where(np.isfinite(r), r, np.nan)


def block(poses: list[np.ndarray]) -> ScanBlock:
    ranges = np.array([cast(p) for p in poses], dtype=np.float32)
    return ScanBlock(
        t_ns=np.arange(len(poses), dtype=np.int64),
        ranges_m=ranges,
        angles_rad=ANGLES,
        range_max_m=30.0,
        laser_offset=np.zeros(3),
    )


poses_st = st.tuples(
    st.floats(-50, 50), st.floats(-50, 50), st.floats(-math.pi + 1e-6, math.pi - 1e-6)
).map(np.array)


@given(poses_st, poses_st)
def test_between_inverts_compose(a: np.ndarray, b: np.ndarray) -> None:
    np.testing.assert_allclose(se2.between(a, se2.compose(a, b)), b, atol=1e-8)
    np.testing.assert_allclose(se2.compose(a, se2.inverse(a)), np.zeros(3), atol=1e-8)


@given(poses_st)
def test_transform_points_matches_compose(a: np.ndarray) -> None:
    pts = np.array([[1.0, 2.0], [-3.0, 0.5]])
    moved = se2.transform_points(a, pts)
    for p, m in zip(pts, moved, strict=True):
        np.testing.assert_allclose(se2.compose(a, [p[0], p[1], 0.0])[:2], m, atol=1e-9)


@pytest.mark.parametrize(
    "offset",
    [
        (0.12, -0.08, math.radians(3.0)),
        (-0.25, 0.2, math.radians(-5.0)),
        (0.0, 0.0, 0.0),
        (0.21, 0.17, math.radians(5.5)),
    ],
)
def test_scan_matcher_recovers_known_offset(offset: tuple[float, float, float]) -> None:
    truth = np.array([2.5, 2.0, 0.3])
    ref_poses = [np.array([2.0, 2.0, 0.0]), np.array([3.0, 1.5, 1.2])]
    refs = block(ref_poses)
    world = np.concatenate(
        [se2.transform_points(p, refs.endpoints(k, 30.0)) for k, p in enumerate(ref_poses)]
    )
    field = LikelihoodField.from_points(world, 0.05, 0.06)
    scan = block([truth]).endpoints(0, 30.0)
    guess = se2.compose(truth, np.array(offset))
    window = SearchWindow(0.3, math.radians(6), math.radians(0.5))
    result = match(field, scan, guess, window)
    assert np.hypot(*(result.pose[:2] - truth[:2])) < 0.02
    assert abs(se2.wrap(result.pose[2] - truth[2])) < math.radians(0.3)
    assert result.score > 0.8


def test_wide_multiresolution_search_finds_a_far_offset() -> None:
    truth = np.array([2.5, 2.0, 0.3])
    world = se2.transform_points(truth, block([truth]).endpoints(0, 30.0))
    field = LikelihoodField.from_points(world, 0.05, 0.06)
    window = SearchWindow(1.5, math.radians(20), math.radians(1.0), coarse_step_cells=4)
    guess = se2.compose(truth, np.array([0.9, -0.7, math.radians(12)]))
    result = match(
        field, block([truth]).endpoints(0, 30.0), guess, window, coarse_field=field.pooled(4)
    )
    assert np.hypot(*(result.pose[:2] - truth[:2])) < 0.03
    assert abs(se2.wrap(result.pose[2] - truth[2])) < math.radians(0.5)


@given(
    st.integers(min_value=1, max_value=23),
    st.integers(min_value=1, max_value=23),
    st.sampled_from([2, 3, 4]),
    st.integers(min_value=0, max_value=2**16),
)
def test_a_pooled_field_bounds_every_shift_of_up_to_half_its_step(
    height: int, width: int, step: int, seed: int
) -> None:
    """The coarse search is exact only if the pooled field is an upper bound: each coarse
    cell at least the largest fine value within half a step of where it looks."""
    data = np.random.default_rng(seed).random((height, width), dtype=np.float32)
    data[[0, -1], :] = 0.0
    data[:, [0, -1]] = 0.0
    fine = LikelihoodField(data=data, origin_xy=(0.3, -0.2), resolution=0.05)
    coarse = fine.pooled(step)
    for row in range(height):
        for col in range(width):
            xy = np.array([[0.3 + 0.05 * col, -0.2 + 0.05 * row]])
            u, v = coarse.cell_coords(xy)
            crow, ccol = int(np.rint(v[0])), int(np.rint(u[0]))
            lo_r, lo_c = max(0, row - step // 2), max(0, col - step // 2)
            near = data[lo_r : row + step // 2 + 1, lo_c : col + step // 2 + 1].max()
            assert coarse.data[crow, ccol] >= near


@given(st.integers(min_value=0, max_value=2**16), st.integers(min_value=1, max_value=50))
def test_a_field_stamped_in_parts_is_the_field_stamped_at_once(seed: int, chunk: int) -> None:
    """A whole run's points are stamped a few thousand at a time (memory): the field must not
    depend on where the parts split, overlapping kernels and duplicate points included."""
    from baromap.mapping import scan_matcher

    rng = np.random.default_rng(seed)
    points = rng.uniform(0.0, 2.0, (int(rng.integers(1, 120)), 2))
    points = np.vstack([points, points[: len(points) // 3]])
    whole = np.zeros((50, 50), dtype=np.float32)
    scan_matcher._stamp_part(whole, (-0.2, -0.2), 0.05, 0.05, points)
    parts = np.zeros_like(whole)
    original = scan_matcher.STAMP_CHUNK
    try:
        scan_matcher.STAMP_CHUNK = chunk
        scan_matcher.stamp(parts, (-0.2, -0.2), 0.05, 0.05, points)
    finally:
        scan_matcher.STAMP_CHUNK = original
    assert np.array_equal(parts, whole) and whole.max() > 0.7


@given(st.integers(min_value=0, max_value=2**16), st.integers(min_value=1, max_value=4000))
def test_a_lattice_scored_in_blocks_of_angles_is_the_lattice_scored_at_once(
    seed: int, cells: int
) -> None:
    """A wide front-end window is scored a block of angles at a time (memory: scored whole,
    one window took 2 GB): the scores must not depend on where the blocks split, with one
    centre for all angles or one per angle."""
    from baromap.mapping import scan_matcher

    rng = np.random.default_rng(seed)
    field = LikelihoodField.from_points(rng.uniform(0.0, 4.0, (200, 2)), 0.05, 0.05)
    points = rng.uniform(0.5, 3.5, (int(rng.integers(1, 40)), 2)) - 2.0
    angles = np.linspace(-0.5, 0.5, int(rng.integers(1, 30)))
    offsets = np.arange(-3, 4, dtype=np.int64)
    one_centre = np.array([2.0, 2.0])
    per_angle = 2.0 + rng.uniform(-0.1, 0.1, (len(angles), 2))
    original = scan_matcher.LATTICE_BLOCK_CELLS
    try:
        scan_matcher.LATTICE_BLOCK_CELLS = 1 << 40
        whole = [
            scan_matcher._score_grid(field, points, c, angles, offsets)
            for c in (one_centre, per_angle)
        ]
        scan_matcher.LATTICE_BLOCK_CELLS = cells
        blocks = [
            scan_matcher._score_grid(field, points, c, angles, offsets)
            for c in (one_centre, per_angle)
        ]
    finally:
        scan_matcher.LATTICE_BLOCK_CELLS = original
    for w, b in zip(whole, blocks, strict=True):
        assert w.shape == (len(angles), 7, 7)
        assert np.array_equal(w, b)
    assert whole[0].max() > 0


def test_branch_and_bound_finds_an_offset_of_metres() -> None:
    """A loop closure after a long stretch without one: the guess is metres and degrees off,
    further than the lattice search's window (LOOP_MAX_M) reaches."""
    truth = np.array([2.5, 2.0, 0.3])
    world = se2.transform_points(truth, block([truth]).endpoints(0, 30.0))
    field = LikelihoodField.from_points(world, 0.05, 0.05)
    scan = block([truth]).endpoints(0, 30.0)
    guess = se2.compose(truth, np.array([2.6, -1.9, math.radians(-14)]))
    window = SearchWindow(4.0, math.radians(20), math.radians(0.5))
    result = match(field, scan, guess, window, wide=True)
    assert np.hypot(*(result.pose[:2] - truth[:2])) < 0.03
    assert abs(se2.wrap(result.pose[2] - truth[2])) < math.radians(0.5)
    assert result.score > 0.8


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_branch_and_bound_finds_the_lattice_optimum(seed: int) -> None:
    """Its bounds are bounds: with the budget to finish, it ends on the pose an exhaustive
    search of the same lattice finds (a loose bound would prune the optimum away)."""
    rng = np.random.default_rng(seed)
    truth = np.array([2.5, 2.0, 0.3])
    refs = [np.array([2.0, 2.0, 0.0]), np.array([3.0, 1.5, 1.2])]
    world = np.concatenate([se2.transform_points(p, block([p]).endpoints(0, 30.0)) for p in refs])
    field = LikelihoodField.from_points(world, 0.05, 0.05)
    scan = block([truth]).endpoints(0, 30.0)[::3]
    guess = se2.compose(truth, np.array([*rng.uniform(-0.6, 0.6, 2), rng.uniform(-0.1, 0.1)]))
    window = SearchWindow(0.8, math.radians(8), math.radians(1.0))
    exhaustive = correlative_search(field, scan, guess, window)
    found = branch_and_bound_search(field, scan, guess, window, budget=10**6)
    assert found.score == pytest.approx(exhaustive.score, abs=1e-6)
    assert found.pose == pytest.approx(exhaustive.pose, abs=1e-9)


def test_a_branch_and_bound_node_scores_as_the_whole_lattice_does() -> None:
    """The search's per-node scorer keeps each heading's rotated scan and prior; its scores
    and penalties are those of the lattice functions to the bit, at every level's field, or
    the search would no longer be the lattice's (the test above, up to its tolerance)."""
    from baromap.mapping import scan_matcher

    rng = np.random.default_rng(4)
    refs = [np.array([2.0, 2.0, 0.0]), np.array([3.0, 1.5, 1.2])]
    world = np.concatenate([se2.transform_points(p, block([p]).endpoints(0, 30.0)) for p in refs])
    field = LikelihoodField.from_points(world, 0.05, 0.05)
    scan = block([np.array([2.5, 2.0, 0.3])]).endpoints(0, 30.0)[::3]
    angles = 0.3 + np.radians(np.arange(-6, 7, 1.5))
    prior = scan_matcher.Prior(np.array([2.4, 2.1, 0.28]), 0.3, 0.05, 0.04)
    nodes = scan_matcher._NodeScorer(field, scan, angles, prior)
    for step in (4, 1):
        level = scan_matcher._bound_field(field, step)
        offsets = np.arange(-2, 3) * step
        for _ in range(20):
            a = int(rng.integers(len(angles)))
            x, y = (float(v) for v in rng.uniform(1.0, 4.0, 2))
            xs, ys = x + offsets * 0.05, y + offsets * 0.05
            whole = scan_matcher._score_grid(
                level, scan, np.array([x, y]), angles[a : a + 1], offsets
            )
            assert np.array_equal(nodes.scores(level, a, x, y, offsets), whole[0])
            penalty = scan_matcher._prior_penalty(prior, angles[a : a + 1], xs, ys)
            assert np.array_equal(nodes.penalty(a, xs, ys), np.asarray(penalty)[0])


def _square_world() -> tuple[np.ndarray, PoseGraph]:
    rng = np.random.default_rng(1)
    truth = [np.zeros(3)]
    for k in range(40):
        turn = math.pi / 2 if k % 10 == 9 else 0.0
        truth.append(se2.compose(truth[-1], [1.0, 0.0, turn]))
    truth_arr = np.array(truth)
    graph = PoseGraph()
    graph.add_node(truth_arr[0])
    info = np.diag([400.0, 400.0, 1000.0])
    for k in range(1, len(truth_arr)):
        z = se2.between(truth_arr[k - 1], truth_arr[k]) + rng.normal(0, [0.03, 0.03, 0.02])
        graph.add_node(se2.compose(graph.poses[-1], z))
        graph.add_edge(Edge(k - 1, k, z, info))
    for a, b in [(0, 40), (5, 35), (2, 22), (12, 32)]:
        graph.add_edge(
            Edge(a, b, se2.between(truth_arr[a], truth_arr[b]), info * 4, "loop", robust_c=3.0)
        )
    return truth_arr, graph


def test_pose_graph_closes_the_loop() -> None:
    truth, graph = _square_world()
    before = np.abs(graph.poses[:, :2] - truth[:, :2]).max()
    graph.optimize()
    after = np.abs(graph.poses[:, :2] - truth[:, :2]).max()
    assert before > 0.5
    assert after < 0.2


def test_wrong_closure_cannot_wreck_the_map() -> None:
    _, good = _square_world()
    _, bad = _square_world()
    bad.add_edge(
        Edge(
            3,
            30,
            np.array([2.0, 1.0, 1.0]),
            np.diag([1600.0, 1600.0, 4000.0]),
            "loop",
            robust_c=3.0,
        )
    )
    good.optimize()
    bad.optimize()
    assert np.abs(bad.poses[:, :2] - good.poses[:, :2]).max() < 0.05
    _, chi2 = bad.edge_errors()
    assert chi2[-1] > 1000  # the wrong closure is left unsatisfied


def test_without_kernel_the_wrong_closure_does_bend_the_map() -> None:
    """The control for the test above: the kernel is what saves the map."""
    _, good = _square_world()
    _, bad = _square_world()
    bad.add_edge(Edge(3, 30, np.array([2.0, 1.0, 1.0]), np.diag([1600.0, 1600.0, 4000.0])))
    good.optimize()
    bad.optimize()
    assert np.abs(bad.poses[:, :2] - good.poses[:, :2]).max() > 0.5


def test_the_parts_of_a_pose_graph_are_what_the_edges_kept_join() -> None:
    """Left out, the step across a gap cuts the chain in two; a closure across it, or one
    from a later part back to the first, joins them again. Part 0 is node 0's."""
    graph = PoseGraph()
    for _ in range(8):
        graph.add_node(np.zeros(3))
    info = np.eye(3)
    for i in range(7):
        graph.add_edge(Edge(i, i + 1, np.array([1.0, 0.0, 0.0]), info, "odometry"))
    gap = np.zeros(graph.edge_count, dtype=bool)
    gap[2] = gap[5] = True  # the steps into nodes 3 and 6
    assert graph.parts().tolist() == [0] * 8
    assert graph.parts(gap).tolist() == [0, 0, 0, 1, 1, 1, 2, 2]
    graph.add_edge(Edge(7, 4, np.array([-3.0, 0.0, 0.0]), info, "loop"))
    assert graph.parts(np.append(gap, False)).tolist() == [0, 0, 0, 1, 1, 1, 1, 1]
    graph.add_edge(Edge(1, 5, np.array([4.0, 0.0, 0.0]), info, "loop"))
    assert graph.parts(np.append(gap, [False, False])).tolist() == [0] * 8
    with pytest.raises(MappingError):
        graph.parts(gap)  # a mask of another graph's edges


def test_priors_fix_the_frame_without_pinning_the_first_node() -> None:
    """Priors that place every node in the map's frame fix the frame themselves: solved with
    no anchor, the first node goes where its own prior and its edges put it, rather than
    staying where it stood (the first keyframe held off its own map, see slam._refine)."""
    truth = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    start = truth + np.array([0.1, -0.05, 0.02])  # all off by the same, node 0 too

    def solved(anchor: int | None) -> np.ndarray:
        graph = PoseGraph()
        for pose in start:
            graph.add_node(pose)
        for k in (1, 2):
            z = se2.between(truth[k - 1], truth[k])
            graph.add_edge(Edge(k - 1, k, z, np.diag([100.0, 100.0, 1000.0])))
        graph.set_priors(
            np.arange(3), truth, np.repeat(np.diag([400.0, 400.0, 4000.0])[None], 3, 0)
        )
        graph.optimize(iterations=10, anchor=anchor)
        return graph.poses

    free = solved(None)
    assert free == pytest.approx(truth, abs=1e-6)
    pinned = solved(0)
    assert pinned[0] == pytest.approx(start[0], abs=1e-6)  # the control: the anchor holds it


def test_grid_ray_casting_marks_walls_free_and_unknown() -> None:
    # the robot drives a metre east, then looks back west: every cell is seen a few times
    poses = np.array([[x, 3.02, h] for h in (0.0, math.pi) for x in np.linspace(1.5, 2.5, 6)])
    scans = block(list(poses))
    grid = build_grid(scans, np.arange(len(poses)), poses, resolution=0.05)
    xs, ys = grid.cell_centers()

    def cell(x: float, y: float) -> tuple[int, int]:
        return int(np.argmin(np.abs(ys - y))), int(np.argmin(np.abs(xs - x)))

    occupied, free = grid.occupied(), grid.free()
    assert occupied[cell(9.99, 3.02)] or occupied[cell(10.01, 3.02)]  # east wall ahead
    assert occupied[cell(0.01, 3.02)] or occupied[cell(-0.01, 3.02)]  # west wall behind
    assert free[cell(5.0, 3.02)] and free[cell(1.0, 3.02)]
    assert not free[cell(6.5, 1.85)]  # inside the pillar: never seen
    assert not occupied[cell(12.0, 3.0)] and not free[cell(12.0, 3.0)]
    # the north wall of the east wing (y = 4, seen at a grazing angle): occupied where hit
    rows, cols = np.nonzero(occupied)
    on_wall = (np.abs(ys[rows] - 4.0) < 0.05) & (xs[cols] > 5.0) & (xs[cols] < 9.0)
    assert len(np.unique(cols[on_wall])) > 0.25 * (4.0 / grid.resolution)
    near_wall = (np.abs(ys[rows] - 4.0) < 0.5) & (xs[cols] > 5.0) & (xs[cols] < 9.0)
    assert on_wall.sum() >= 0.9 * near_wall.sum()


def test_map_server_files(tmp_path: Path) -> None:
    pose = np.array([2.0, 2.0, 0.0])
    grid = build_grid(block([pose]), np.array([0]), pose[None, :], resolution=0.1)
    pgm, yml = write_map_server(grid, tmp_path, "floor_0")
    meta = yaml.safe_load(yml.read_text())
    assert set(meta) == {
        "image",
        "resolution",
        "origin",
        "negate",
        "occupied_thresh",
        "free_thresh",
        "mode",
    }
    assert meta["image"] == "floor_0.pgm" and meta["resolution"] == 0.1
    assert meta["origin"] == [
        pytest.approx(grid.origin_xy[0]),
        pytest.approx(grid.origin_xy[1]),
        0.0,
    ]
    assert pgm.read_bytes().startswith(b"P5\n")
    image = read_pgm(pgm)
    assert image.shape == grid.shape
    assert set(np.unique(image)) <= {FREE_VALUE, OCCUPIED_VALUE, UNKNOWN_VALUE}
    # first image row is the top of the map (highest y)
    np.testing.assert_array_equal(image[-1] == OCCUPIED_VALUE, grid.occupied()[0])


def test_tum_format(tmp_path: Path) -> None:
    path = tmp_path / "t.tum"
    write_tum(
        path,
        np.array([1_500_000_001, 2_000_000_000]),
        np.array([[1, 2, 0], [3, 4, math.pi / 2]]),
        np.array([0.0, 3.5]),
    )
    lines = path.read_text().splitlines()
    assert lines[0].split()[0] == "1.500000001"
    fields = [float(v) for v in lines[1].split()]
    assert fields[1:4] == [3.0, 4.0, 3.5]
    assert fields[6] == pytest.approx(math.sin(math.pi / 4))
    assert fields[7] == pytest.approx(math.cos(math.pi / 4))


def test_relation_errors() -> None:
    times = np.array([10, 20, 30], dtype=np.int64) * 10**9
    poses = np.array([[0, 0, 0], [1, 0, 0], [1, 1, math.pi / 2]], dtype=np.float64)
    rel = Relations(
        t1_ns=np.array([10, 20, 15]) * 10**9,
        t2_ns=np.array([20, 30, 30]) * 10**9,
        motion=np.array([[1.0, 0.0, 0.0], [0.0, 1.1, math.radians(89)], [0, 0, 0]]),
    )
    err = relation_errors(times, poses, rel)
    assert err.used == 2 and err.unused == 1
    np.testing.assert_allclose(err.trans_m, [0.0, math.hypot(0.1, 0.0)], atol=0.02)
    np.testing.assert_allclose(err.rot_deg, [0.0, 1.0], atol=1e-9)


def test_pose_error_does_not_cancel_as_the_robot_turns() -> None:
    from baromap.evaluation.trajectory import mean_pose_error

    # the robot turns round on the spot; its estimate is 8 cm east and 0.5 deg off throughout
    true = np.array([[30.0, 11.4, h] for h in np.linspace(-math.pi, math.pi, 36, endpoint=False)])
    estimated = true + np.array([0.08, 0.0, math.radians(0.5)])
    distance, degrees = mean_pose_error(estimated, true)
    assert distance == pytest.approx(0.08)
    assert degrees == pytest.approx(0.5)
    # the old measure (errors in each pose's own frame, then averaged) saw almost nothing
    local = se2.between(true, estimated)
    assert math.hypot(local[:, 0].mean(), local[:, 1].mean()) < 0.01
    # errors in opposite directions do not cancel either
    spread = true + np.where(np.arange(36)[:, None] % 2 == 0, 1.0, -1.0) * [0.05, 0.0, 0.01]
    assert mean_pose_error(spread, true) == pytest.approx((0.05, math.degrees(0.01)))


def test_sim_bar_needs_one_map_per_visited_floor() -> None:
    import dataclasses

    from baromap.evaluation.mapping import FloorScore, SimReport

    perfect = FloorScore(0, 0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0)
    floors = [dataclasses.replace(perfect, floor=k, true_floor=k) for k in range(3)]
    report = SimReport(floors, 0, 10, 1.0, np.zeros(3), true_floors=(0, 1, 2))
    assert report.passed()
    merged = SimReport(floors[:2], 0, 10, 1.0, np.zeros(3), true_floors=(0, 1, 2))
    assert not merged.passed()  # a floor merged into another has no map of its own
    split = SimReport([*floors, floors[2]], 0, 10, 1.0, np.zeros(3), true_floors=(0, 1, 2))
    assert not split.passed()
    assert report.passed_in_one_frame()
    turned = [*floors[:2], dataclasses.replace(floors[2], building_occupied_precision=0.6)]
    loose = SimReport(turned, 0, 10, 1.0, np.zeros(3), true_floors=(0, 1, 2))
    assert loose.passed() and not loose.passed_in_one_frame()


def test_label_scans_by_segments() -> None:
    t = np.array([0, 5, 10, 15, 20, 25, 30, 35], dtype=np.int64)
    floor, visit = label_scans(t, [(2, 12, 0), (18, 28, 1), (32, 40, 0)], guard_s=0.0)
    assert floor.tolist() == [0, 0, 0, BETWEEN_FLOORS, 1, 1, BETWEEN_FLOORS, 0]
    assert visit.tolist() == [0, 0, 0, -1, 1, 1, -1, 2]


def test_label_scans_keeps_a_guard_around_transitions_only() -> None:
    s = 1_000_000_000
    t = np.array([0, 9, 11, 19, 21, 29, 31, 60], dtype=np.int64) * s
    floor, _ = label_scans(t, [(5 * s, 12 * s, 0), (18 * s, 32 * s, 1)], guard_s=2.0)
    # the run's own start and end are no transition: no guard there
    assert floor.tolist() == [0, 0, BETWEEN_FLOORS, BETWEEN_FLOORS, 1, 1, 1, 1]


def test_transition_guard_stops_where_the_robot_moved() -> None:
    """A recording sped up sixfold: the robot turns in the car a second before the ride and
    drives out half a second after it; those scans stay on their floors whatever the guard."""
    s = 1_000_000_000
    t = np.array([0, 8, 9, 10, 10.5, 13, 13.5, 14, 20], dtype=np.float64) * s
    odom = np.zeros((len(t), 3))
    odom[1:3, 2] = [0.5, 1.0]  # turning in the car
    odom[3:6, 2] = 1.0  # standing still: the ride (11-13 s), door time around it
    odom[6:, 2] = 1.0
    odom[6:, 0] = [0.3, 0.6, 3.0]  # driving out
    segments = [(0, 11 * s, 0), (13 * s, 30 * s, 1)]
    moving = moving_scans(odom)
    assert moving.tolist() == [True, True, True, False, False, False, True, True, True]
    floor, _ = label_scans(t.astype(np.int64), segments, guard_s=3.0, moving=moving)
    assert floor.tolist() == [0, 0, 0, BETWEEN_FLOORS, BETWEEN_FLOORS, BETWEEN_FLOORS, 1, 1, 1]
    # without the odometry the guard in seconds takes the turn and the drive out too
    floor, _ = label_scans(t.astype(np.int64), segments, guard_s=3.0)
    assert floor.tolist() == [0, 0, BETWEEN_FLOORS, *[BETWEEN_FLOORS] * 5, 1]


@pytest.mark.parametrize(
    "record",
    [
        {"laser_offset": "0.1 zero 0"},
        {"laser_offset": "0.1 0.2"},
        {"laser_mount": '{"x_m": NaN}'},
        {"laser_mount": "[1, 2"},
    ],
)
def test_bad_laser_mount_metadata_is_an_input_error(record: dict[str, str]) -> None:
    """A mount read wrongly would shift every beam; say so rather than map with zeros."""
    from baromap.errors import InputFormatError
    from baromap.mapping.run_data import laser_offset_from_metadata

    assert laser_offset_from_metadata({"x": {"laser_offset": "0.1 0 0.5"}}).tolist() == [
        0.1,
        0.0,
        0.5,
    ]
    with pytest.raises(InputFormatError):
        laser_offset_from_metadata({"x": record})


def test_odometric_travel_counts_the_drive_between_scans_not_only_where_it_ended() -> None:
    """Two scans 40 s apart, the laser silent between: the robot drove a 2 m square, turning
    left at each corner, then a quarter turn right and back. Where it ended says 0 m and 0
    degrees; the drive was 8 m and 540 degrees of turning, the doubt odometry carries."""
    from baromap.mapping.run_data import odometric_travel

    corners = [(0, 0, 0), (2, 0, 0), (2, 0, 90), (2, 2, 90), (2, 2, 180), (0, 2, 180)]
    corners += [(0, 2, 270), (0, 0, 270), (0, 0, 360), (0, 0, 270), (0, 0, 360)]
    poses = np.array([(x, y, math.radians(t)) for x, y, t in corners], dtype=np.float64)
    poses[:, 2] = (poses[:, 2] + math.pi) % (2 * math.pi) - math.pi  # as odometry wraps it
    t = np.arange(len(poses), dtype=np.int64) * 4_000_000_000
    at = odometric_travel(t, poses, np.array([0, t[-1], t[-1] + 10**9], dtype=np.int64))
    assert at[0].tolist() == [0.0, 0.0]
    assert at[1, 0] == pytest.approx(8.0)
    assert math.degrees(at[1, 1]) == pytest.approx(540.0)
    assert at[2].tolist() == at[1].tolist()  # held after the stream's end
    halfway = odometric_travel(t, poses, np.array([2_000_000_000], dtype=np.int64))
    assert halfway[0, 0] == pytest.approx(1.0)
    none = odometric_travel(t[:1], poses[:1], t)
    assert none.shape == (len(t), 2) and not none.any()


def test_odometry_blind_marks_the_scans_inside_a_gap_in_the_odometry() -> None:
    """Odometry at 10 Hz with 5 s missing, scans at 4 Hz: the scans inside the gap, and
    those more than a second past the stream's end, are the ones it said nothing about; a
    gap of two samples is not one, and no stream at all leaves every scan blind."""
    from baromap.mapping.run_data import odometry_blind

    odom = np.arange(0, 20_000_000_000, 100_000_000, dtype=np.int64)
    odom = odom[(odom < 5_000_000_000) | (odom >= 10_000_000_000)]
    odom = odom[(odom < 12_000_000_000) | (odom >= 12_200_000_000)]  # a sample lost
    scans = np.arange(0, 22_000_000_000, 250_000_000, dtype=np.int64)
    blind = odometry_blind(odom, scans)
    inside = (scans > 4_900_000_000) & (scans < 10_000_000_000)
    late = scans > 19_900_000_000 + 1_000_000_000
    assert blind.tolist() == (inside | late).tolist()
    assert odometry_blind(np.zeros(0, dtype=np.int64), scans).all()


def test_odometry_that_counts_from_zero_again_is_joined_at_the_pose_before() -> None:
    """A base driving a circle at 0.5 m/s, 10 Hz, silent from 20 to 23 s and then counting
    from zero in a frame of its own (power-cycled): the stream after the gap goes on from
    the pose before it, every step as it was; a 3-s gap with the counters going on, and
    one moving only as far as a base drives, are left alone; after a minute's gap, back at
    the origin is a restart however near it was."""
    from baromap.mapping import se2
    from baromap.mapping.run_data import join_odometry_tracks

    t = np.arange(0, 40_000_000_000, 100_000_000, dtype=np.int64)
    t = t[(t < 20_000_000_000) | (t >= 23_000_000_000)]
    s = t / 1e9
    truth = np.stack([5 * np.sin(0.1 * s), 5 - 5 * np.cos(0.1 * s), se2.wrap(0.1 * s)], axis=1)
    after = s >= 23
    restarted = truth.copy()
    restarted[after] = se2.between(truth[after][0], truth[after])
    joined, times = join_odometry_tracks(t, restarted)
    assert times == 1
    assert np.allclose(joined[~after], truth[~after])
    assert np.allclose(joined[after][0], truth[~after][-1])
    steps = se2.between(joined[:-1], joined[1:])
    across = np.flatnonzero(after)[0] - 1
    assert np.allclose(np.delete(steps, across, axis=0), [0.05, 0.0, 0.01], atol=1e-3)
    same, none = join_odometry_tracks(t, truth)
    assert none == 0 and np.array_equal(same, truth)
    nearby = truth.copy()
    nearby[after, 0] += 4.0  # 4 m in 3 s: not beyond what a base drives, so taken as driven
    assert join_odometry_tracks(t, nearby)[1] == 0
    # a minute's gap, 9 m from the origin: within reach, but back at (0, 0, 0) it restarted
    late = np.concatenate([t[~after], t[after] + 60_000_000_000])
    assert join_odometry_tracks(late, restarted)[1] == 1
    assert join_odometry_tracks(late, truth)[1] == 0


def test_a_recording_whose_recorder_joined_the_tracks_keeps_its_odometry_as_recorded() -> None:
    """The demo's twins play six times faster than real time: the base drives 3.6 m in a
    recording second, and a one-second stall of the host looks like a restart by the rule
    for recordings that were not joined. baromapd says in its header that it joined the
    base's restarts itself, and then the odometry is taken as recorded; without the header
    the same stream is joined."""
    from baromap.mapping.run_data import RunSeries, run_data
    from baromap.messages import LaserScan
    from baromap.recording import OdometrySeries, PressureSeries, topics

    t = np.arange(0, 20_000_000_000, 100_000_000, dtype=np.int64)
    t = t[(t < 10_000_000_000) | (t >= 11_200_000_000)]  # the host stalled 1.2 s
    x = 3.6 * t.astype(np.float64) / 1e9  # the robot drove on: 4.7 m across the stall
    zero = np.zeros(len(t))
    counts = np.zeros(len(t), dtype=np.int64)
    odometry = OdometrySeries(t, x, zero, zero, zero + 3.6, zero, counts, counts, counts)
    none = PressureSeries(np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0))
    ranges = np.full(181, 5.0, dtype=np.float32)
    flags = np.zeros(181, dtype=np.uint16)
    scans = ScanBlock.from_messages(
        [LaserScan(int(s), -np.pi / 2, np.pi / 180, 30.0, ranges, flags) for s in t[::5]],
        np.zeros(3),
    )
    series = RunSeries(none, odometry, none)
    header = {"robot": "demo", topics.ODOMETRY_TRACKS_KEY: topics.ODOMETRY_TRACKS_JOINED}
    recorded = run_data(scans, {topics.METADATA_NAME: header}, series)
    assert np.array_equal(recorded.odometry_poses[:, 0], x)
    foreign = run_data(scans, {topics.METADATA_NAME: {"robot": "demo"}}, series)
    assert foreign.odometry_poses[-1, 0] < x[-1] - 4.0  # taken for a restart


def _sparse_run(
    gaps_s: list[float], poses: np.ndarray, metadata: dict[str, dict[str, str]] | None = None
):  # type: ignore[no-untyped-def]
    """A run logged as many public logs are: one odometry pose with each scan, the scans
    ``gaps_s`` apart, ``poses`` the odometry at each."""
    from baromap.mapping.run_data import RunSeries, run_data
    from baromap.messages import LaserScan
    from baromap.recording import OdometrySeries, PressureSeries

    t = (np.concatenate([[0.0], np.cumsum(gaps_s)]) * 1e9).astype(np.int64) + 10**9
    zero = np.zeros(len(t))
    counts = np.zeros(len(t), dtype=np.int64)
    x, y, theta = poses.T
    odometry = OdometrySeries(t, x, y, theta, zero, zero, counts, counts, counts)
    none = PressureSeries(np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0))
    ranges = np.full(181, 5.0, dtype=np.float32)
    flags = np.zeros(181, dtype=np.uint16)
    scans = ScanBlock.from_messages(
        [LaserScan(int(s), -np.pi / 2, np.pi / 180, 30.0, ranges, flags) for s in t], np.zeros(3)
    )
    return run_data(scans, metadata or {}, RunSeries(none, odometry, none))


def test_a_pause_is_not_a_break() -> None:
    """Scans 2-3 s apart with the odometry logged at each, and pauses of 20-40 s where the
    robot waited (a throttled logger, a lift): odometry is cumulative, so no scan is one it
    said nothing about, nothing is joined, and no step is a break."""
    from structlog.testing import capture_logs

    gaps = [2.5] * 30
    gaps[5], gaps[12], gaps[20] = 40.0, 25.0, 38.0
    x = np.concatenate([[0.0], np.cumsum(np.full(30, 0.8))])
    poses = np.stack([x, 0.1 * x, np.zeros(31)], axis=1)
    with capture_logs() as logs:
        run = _sparse_run(gaps, poses)
    assert not run.blind.any() and not run.breaks.any()
    assert np.allclose(run.odom, poses)
    assert not [e for e in logs if e["log_level"] == "warning"]


def test_a_base_that_counts_from_zero_again_after_a_pause_is_a_break() -> None:
    """The same log with the base power-cycled in the 40 s pause: back at the origin is the
    evidence (a pause alone is none). The step to the next scan is a break; the odometry after
    it goes on from the pose before. A move no base drives in the time is one too, unless the
    times are no clock (stamps made from the scan order)."""
    gaps = [2.5] * 30
    gaps[5] = 40.0
    x = np.concatenate([[0.0], np.cumsum(np.full(30, 0.8))])
    poses = np.stack([x, np.zeros(31), np.zeros(31)], axis=1)
    reset = poses.copy()
    reset[6:, 0] -= reset[6, 0]
    run = _sparse_run(gaps, reset)
    assert np.flatnonzero(run.breaks).tolist() == [6]
    assert not run.blind.any()
    assert run.odom[6, 0] == pytest.approx(poses[5, 0])
    jump = poses.copy()
    jump[20:, 0] += 30.0  # 30 m in 2.5 s
    assert np.flatnonzero(_sparse_run(gaps, jump).breaks).tolist() == [20]
    no_clock = {"baromap.carmen": {"stamps": "scan order"}}
    assert not _sparse_run(gaps, jump, no_clock).breaks.any()
    assert np.flatnonzero(_sparse_run(gaps, reset, no_clock).breaks).tolist() == [6]


def test_odometry_calibration_learns_the_systematic_errors_where_scans_pin_the_motion() -> None:
    """Steps read 3 % long, turns 4 % long and creeping 1 deg/m; matches measure the true
    step with 1 cm / 0.2 deg noise, except in a corridor, where the match only repeats
    odometry along the travel and says so by its covariance: the corridor must not count, nor
    must a wrong match however sure of itself."""
    rng = np.random.default_rng(7)
    cal = OdometryCalibration()
    assert np.allclose(cal.correct(np.array([1.0, 0.0, 0.5])), [1.0, 0.0, 0.5])  # unknown yet
    pinned = np.diag([0.01**2, 0.01**2, math.radians(0.2) ** 2])
    corridor = np.diag([1.0, 0.01**2, math.radians(0.2) ** 2])
    for i in range(400):
        true = np.array([rng.uniform(0.3, 1.0), rng.normal(0, 0.02), rng.normal(0, 0.6)])
        read = np.array(
            [true[0] * 1.03, true[1] * 1.03, true[2] * 1.04 + math.radians(1.0) * 1.03 * true[0]]
        )
        in_corridor = i % 2 == 1
        cov = corridor if in_corridor else pinned
        matched = true + rng.multivariate_normal(np.zeros(3), pinned)
        if in_corridor:
            matched[0] = read[0]  # the match slid to wherever odometry put it
        cal.observe(read, matched, cov)
        if i % 50 == 49:  # now and then a wrong match, sure of itself: a door further, turned
            cal.observe(read, matched + np.array([0.8, 0.0, math.radians(30.0)]), pinned)
    assert cal.rejected == 8
    c = cal.scale()
    a, b = cal.turn_terms()
    assert c == pytest.approx(1 / 1.03, abs=0.002)
    assert a == pytest.approx(1 / 1.04 - 1, abs=0.005)
    assert math.degrees(b) == pytest.approx(-1.0 / 1.04, abs=0.1)
    step = cal.correct(np.array([1.03, 0.0, 1.04 * 0.3 + math.radians(1.0) * 1.03]))
    assert step == pytest.approx([1.0, 0.0, 0.3], abs=0.01)


@pytest.mark.parametrize("turn_error", [0.4, -0.3])
def test_odometry_calibration_learns_a_skid_steer_bases_large_turn_error(
    turn_error: float,
) -> None:
    """A four-wheel skid-steer base (the P3-AT) slips sideways as it turns, so its encoders
    read turns long by as much as its tyres and the floor make it: tens of percent where its
    turn was calibrated on another floor. That is a calibration to learn, not a broken
    odometry: learnt whole, not stopped at 20 %; and a base that reads turns 30 % short too."""
    rng = np.random.default_rng(3)
    cal = OdometryCalibration()
    pinned = np.diag([0.01**2, 0.01**2, math.radians(0.2) ** 2])
    for _ in range(300):
        true = np.array([rng.uniform(0.3, 1.0), rng.normal(0, 0.02), rng.normal(0, 0.3)])
        read = true * np.array([1.0, 1.0, 1.0 + turn_error])
        cal.observe(read, true + rng.multivariate_normal(np.zeros(3), pinned), pinned)
    a, _ = cal.turn_terms()
    assert a == pytest.approx(1 / (1 + turn_error) - 1, abs=0.01)
    assert cal.correct(read)[2] == pytest.approx(true[2], abs=math.radians(0.5))


def test_an_error_models_correction_undoes_it() -> None:
    """What a perfect calibration learns of a model (distance factor, turn factor - 1, creep
    per odometric metre), applied as the SLAM applies it, gives back the true steps: checked
    on noiseless odometry synthesised by models of every sign."""
    from baromap.evaluation.laser_logs import varied_odometry
    from baromap.odometry.synthesis import synthesize_odometry

    rng = np.random.default_rng(5)
    steps = np.column_stack(
        [rng.uniform(0.2, 1.5, 60), rng.normal(0, 0.05, 60), rng.normal(0, 0.6, 60)]
    )
    truth = np.zeros((61, 3))
    for i, step in enumerate(steps):
        truth[i + 1] = se2.compose(truth[i], step)
    for seed in range(4):
        # the drawn model's systematic part alone: its correction must undo it exactly
        model = dataclasses.replace(
            varied_odometry(seed),
            sigma_trans_per_m=0.0,
            sigma_side_per_m=0.0,
            sigma_rot_per_m=0.0,
            sigma_rot_per_rad=0.0,
        )
        odom = synthesize_odometry(truth, seed, model)
        c, a, b = model.correction()
        for i in range(60):
            read = se2.between(odom[i], odom[i + 1])
            travel = math.hypot(read[0], read[1])
            undone = np.array([read[0] * c, read[1] * c, read[2] * (1 + a) + b * travel])
            assert undone == pytest.approx(se2.between(truth[i], truth[i + 1]), abs=1e-9)


def test_varied_odometry_is_drawn_per_seed_within_its_family() -> None:
    """Each seed draws its own model, the same every time; magnitudes within the family's
    ranges and noise within half to one and a half times the default's; over a few seeds
    every systematic term takes both signs."""
    from baromap.evaluation import laser_logs
    from baromap.odometry.errors import OdometryErrorModel

    default = OdometryErrorModel()
    models = [laser_logs.varied_odometry(seed) for seed in range(12)]
    assert laser_logs.varied_odometry(3) == models[3]
    assert len({m.scale for m in models}) == len(models)
    for m in models:
        assert laser_logs.VARIED_SCALE[0] <= abs(m.scale) <= laser_logs.VARIED_SCALE[1]
        assert abs(m.rotation_scale) <= laser_logs.VARIED_ROTATION_SCALE[1]
        low, high = laser_logs.VARIED_CREEP_RAD_PER_M
        assert low <= abs(m.drift_rad_per_m) <= high
        for name in ("sigma_trans_per_m", "sigma_side_per_m", "sigma_rot_per_m"):
            assert 0.5 <= getattr(m, name) / getattr(default, name) <= 1.5
    for name in ("scale", "rotation_scale", "drift_rad_per_m"):
        signs = {math.copysign(1.0, getattr(m, name)) for m in models}
        assert signs == {-1.0, 1.0}
    assert laser_logs.odometry_model("varied", 3) == models[3]
    assert laser_logs.odometry_model("strong", 3) is laser_logs.STRONG_ODOMETRY
    with pytest.raises(ConfigError):
        laser_logs.odometry_model("weak", 0)
    with pytest.raises(ConfigError):
        laser_logs.varied_odometry(-1)


@pytest.mark.parametrize(
    ("text", "name", "stride", "scans"),
    [
        ("fr079", "fr079", 1, None),
        ("intel/3", "intel", 3, None),
        ("fr079[0:967]", "fr079", 1, slice(0, 967)),
        ("acapulco/2[168:822]", "acapulco", 2, slice(168, 822)),
        ("intel[100:]", "intel", 1, slice(100, None)),
    ],
)
def test_log_specs_name_a_log_its_part_and_stride(
    text: str, name: str, stride: int, scans: slice | None
) -> None:
    from baromap.evaluation.laser_logs import LogSpec, parse_log_spec

    spec = parse_log_spec(text)
    assert spec == LogSpec(name, stride, scans)
    assert spec.published == (text == "fr079")


@pytest.mark.parametrize("text", ["lab", "intel/0", "intel/x", "intel[1:2", "intel[a:b]", ""])
def test_a_bad_log_spec_is_a_config_error(text: str) -> None:
    from baromap.evaluation.laser_logs import parse_log_spec

    with pytest.raises(ConfigError):
        parse_log_spec(text)


def test_a_draw_moves_odometry_by_under_a_micrometre_and_repeats() -> None:
    from baromap.evaluation.laser_logs import DRAW_PERTURBATION, perturbed

    odom = np.random.default_rng(0).normal(0.0, 10.0, (50, 3))
    assert perturbed(odom, 3, 0) is odom
    first = perturbed(odom, 3, 1)
    assert np.all(np.abs(first - odom) <= DRAW_PERTURBATION)
    assert np.any(first != odom)
    np.testing.assert_array_equal(first, perturbed(odom, 3, 1))
    assert not np.array_equal(first, perturbed(odom, 3, 2))
    assert not np.array_equal(first, perturbed(odom, 4, 1))


@pytest.mark.slow
def test_front_end_holds_on_a_sparse_log(shared_data: Path) -> None:
    """The first 300 scans of the Intel log, every third kept: 100 scans over 179 m, a scan
    every 2.2 m (median; up to 3.1 m) and turns of up to 125 degrees between scans, sparser
    than the logs issue 14 keeps outside the repository (a scan a metre, turns up to 80
    degrees). Its scans overlap their submap little, so correct matches score low; a front
    end that refuses them drives on odometry and the map falls apart (metres of error)."""
    from baromap.evaluation.laser_logs import run_log

    report = run_log(shared_data / "laser", "intel", seed=0, scans=slice(0, 300), stride=3)
    assert report.scans == 100
    # centimetres, not metres: the map agrees with GMapping's (which saw every scan)
    assert report.slam_ate.rms_m < 0.15
    assert report.odometry_ate.rms_m > 50 * report.slam_ate.rms_m


def _robot_behind_the_laser(source: Path, target: Path, mount: tuple[float, float, float]) -> None:
    """``source``'s CARMEN log with each FLASER line's robot pose moved so that the laser
    pose is the robot pose (+) ``mount``: the same scans, taken by a laser mounted off the
    robot's centre, the reference and odometry the robot's."""
    import gzip

    mx, my, mt = mount
    with gzip.open(source, "rt") as src, gzip.open(target, "wt") as dst:
        for line in src:
            tokens = line.split()
            if tokens and tokens[0] == "FLASER":
                k = 2 + int(tokens[1])
                lx, ly, lt = (float(v) for v in tokens[k : k + 3])
                rt = lt - mt
                c, s = math.cos(rt), math.sin(rt)
                robot = (lx - (c * mx - s * my), ly - (s * mx + c * my), rt)
                tokens[k + 3 : k + 6] = [f"{v:.6f}" for v in robot]
                dst.write(" ".join(tokens) + "\n")
            else:
                dst.write(line)


@pytest.mark.slow
def test_a_log_whose_laser_sits_off_the_robot_centre_maps_the_robot(
    shared_data: Path, tmp_path: Path
) -> None:
    """Our three logs carry the laser pose as the robot pose; a Pioneer's laser sits
    decimetres ahead of the axle, and a log that says so (the FLASER's two poses differ) has
    its reference poses and odometry at the robot's centre while the scans are the laser's.
    Matched as if taken at the centre, every turn in place becomes a sideways step of the
    scans that odometry denies. The first 450 Intel scans, every second kept, with the robot
    0.3 m behind the laser: 0.27 / 0.38 / 1.93 m ATE on seeds 0-2 before the bench took the
    mounting from the log, 0.038 / 0.038 / 0.045 m after (0.041 / 0.058 / 0.039 m as read)."""
    from baromap.evaluation.laser_logs import LOGS, PreparedLog, run_prepared

    mount = (0.3, 0.05, 0.0)
    name = LOGS["intel"].log_file
    _robot_behind_the_laser(shared_data / "laser" / name, tmp_path / name, mount)
    part = slice(0, 450)
    mounted = PreparedLog(tmp_path, "intel", scans=part, stride=2)
    assert np.allclose(mounted.block.laser_offset, mount, atol=1e-5)
    centred = PreparedLog(shared_data / "laser", "intel", scans=part, stride=2)
    assert np.allclose(centred.block.laser_offset, 0.0)
    on_mount = run_prepared(mounted, 0).slam_ate.rms_m
    as_read = run_prepared(centred, 0).slam_ate.rms_m
    assert on_mount < max(0.1, 2 * as_read)


@pytest.mark.slow
def test_a_log_of_a_short_range_laser_maps_without_its_no_return_code_as_walls(
    shared_data: Path, tmp_path: Path
) -> None:
    """An LMS in its 8 m mode prints 8.183 m for every beam that reaches past 8 m. Mapped as
    walls, the code is an arc that moves with the robot; flagged, a scan in Acapulco's hall
    keeps a few points of one wall, a fit of rank one. The first 300 Acapulco scans so
    rewritten, seed 0: 3.86 m ATE with the code as walls, 0.36 m now (0.24 m as published)."""
    import gzip

    from baromap.evaluation.laser_logs import LOGS, PreparedLog, run_prepared

    name = LOGS["acapulco"].log_file
    with gzip.open(shared_data / "laser" / name, "rt") as src:
        lines = src.readlines()
    with gzip.open(tmp_path / name, "wt") as dst:
        for line in lines:
            tokens = line.split()
            if tokens and tokens[0] == "FLASER":
                n = int(tokens[1])
                tokens[2 : 2 + n] = ["8.183" if float(v) >= 8.183 else v for v in tokens[2 : 2 + n]]
                dst.write(" ".join(tokens) + "\n")
            else:
                dst.write(line)
    part = slice(0, 300)
    short = PreparedLog(tmp_path, "acapulco", scans=part)
    assert short.block.range_max_m < 8.183
    assert run_prepared(short, 0).slam_ate.rms_m < 1.0


@pytest.mark.slow
def test_a_laser_that_sees_nothing_for_a_while_is_driven_through_on_odometry(
    shared_data: Path, tmp_path: Path
) -> None:
    """Thirty Intel scans (about 20 m) with no return on any beam, the laser blinded: the
    submap the front end then matches against holds no point. An empty submap scores
    nothing, so the matches are refused as any poor one is, the stretch is driven on
    odometry, and the scans after it are placed again (the first 300 scans, seed 0: 0.041 m
    ATE; 0.046 m with the scans intact)."""
    import gzip

    from baromap.evaluation.laser_logs import LOGS, PreparedLog, run_prepared

    name = LOGS["intel"].log_file
    with gzip.open(shared_data / "laser" / name, "rt") as src:
        lines = src.readlines()
    scan = 0
    with gzip.open(tmp_path / name, "wt") as dst:
        for line in lines:
            tokens = line.split()
            out = line
            if tokens and tokens[0] == "FLASER":
                if 100 <= scan < 130:
                    n = int(tokens[1])
                    tokens[2 : 2 + n] = ["81.91"] * n
                    out = " ".join(tokens) + "\n"
                scan += 1
            dst.write(out)
    relations = LOGS["intel"].relations_file
    assert relations is not None
    (tmp_path / relations).write_bytes((shared_data / "laser" / relations).read_bytes())
    blinded = PreparedLog(tmp_path, "intel", scans=slice(0, 300))
    assert np.isnan(blinded.block.ranges_m[100:130]).all()
    report = run_prepared(blinded, 0)
    assert report.slam_ate.rms_m < 0.1
    assert report.result.stats["front_skipped"] >= 25


def test_relations_in_another_time_base_are_said_to_match_nothing(
    shared_data: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Intel's corrected log as published does not carry the relations' stamps (the abstime
    copy does): given both, the bench scores by ATE alone and says why (the importer says
    separately that the log's odometry stamps near zero were replaced)."""
    from structlog.testing import capture_logs

    from baromap.evaluation import laser_logs

    monkeypatch.setattr(laser_logs, "LOGS", dict(laser_logs.LOGS))
    laser = shared_data / "laser"
    laser_logs.register_log(
        "unstamped", laser / "intel-corrected.log.gz", laser / "intel.relations"
    )
    with capture_logs() as logs:
        log = laser_logs.PreparedLog(laser, "unstamped")
    assert log.relations is None
    (warning,) = [e for e in logs if e["log_level"] == "warning" and "relations" in e]
    assert warning["relations"] > 2000 and "no relation" in warning["event"]


def test_a_log_from_outside_the_data_directory_runs_by_name(
    shared_data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The logs issue 14 keeps outside the repository run through the same code as ours:
    registered by path under a name, then named as ours are (strides and parts too)."""
    import shutil

    from baromap.evaluation import laser_logs

    monkeypatch.setattr(laser_logs, "LOGS", dict(laser_logs.LOGS))
    copy = tmp_path / "elsewhere.log.gz"
    shutil.copy(shared_data / "laser" / laser_logs.LOGS["intel"].log_file, copy)
    laser_logs.register_log("elsewhere", copy)
    spec = laser_logs.parse_log_spec("elsewhere/3[0:300]")
    ours = laser_logs.PreparedLog(shared_data / "laser", "intel", scans=spec.scans, stride=3)
    # the data directory given is not where the registered log is: its own path is used
    theirs = laser_logs.PreparedLog(tmp_path / "absent", spec.name, scans=spec.scans, stride=3)
    assert np.array_equal(theirs.reference, ours.reference)
    assert np.array_equal(theirs.block.ranges_m, ours.block.ranges_m, equal_nan=True)
    # named as its file is: the PLE collection's names hold dashes
    laser_logs.register_log("freiburg-101.v2", copy)
    assert laser_logs.parse_log_spec("freiburg-101.v2/2").stride == 2
    for name, path in (("elsewhere", copy), ("no/slash", copy), ("gone", tmp_path / "x.log")):
        with pytest.raises(ConfigError):
            laser_logs.register_log(name, path)
    with pytest.raises(ConfigError):
        laser_logs.register_log("with_relations", copy, tmp_path / "missing.relations")


@pytest.mark.slow
def test_loops_close_on_a_sparse_log_after_metres_of_drift(shared_data: Path) -> None:
    """The last half of the Acapulco log, every third scan kept: 137 scans, a scan every 3 m.
    Its revisits score 0.3-0.55 against the few scans around the revisited place (under the
    loop threshold) and come back with metres of drift (beyond the loop window's 2 m): with
    neither a group of agreeing closures taken below the threshold nor a wider search, the
    map ran apart (0.66-1.10 m ATE on seeds 0-2, 0.74 m on seed 0; 0.16-0.32 m with them)."""
    from baromap.evaluation.laser_logs import run_log

    report = run_log(shared_data / "laser", "acapulco", seed=0, scans=slice(450, 861), stride=3)
    assert report.scans == 137
    stats = report.result.stats
    assert stats["loop_groups"] > 0
    assert stats["loop_wide_attempts"] > 0
    assert report.slam_ate.rms_m < 0.4


@pytest.mark.slow
def test_front_end_holds_through_turns_of_a_sparse_log(shared_data: Path) -> None:
    """The second half of Freiburg 079, every 30th scan kept: 80 scans, 2-3 m and turns of
    100-170 degrees between scans. Looking back after such a turn, a scan overlaps the
    submap of the last metres too little to match, and odometry is degrees off over the
    turn: without the retry against the last 20 m this piece ran apart on seed 2 (0.74 m;
    0.83 m before the loop changes too; 0.20 m with it)."""
    from baromap.evaluation.laser_logs import run_log

    report = run_log(shared_data / "laser", "fr079", seed=2, scans=slice(2400, 4791), stride=30)
    assert report.scans == 80
    assert report.result.stats["front_retried"] > 0
    assert report.slam_ate.rms_m < 0.4


def _check_thinned_log_run(
    shared_data: Path,
    name: str,
    stride: int,
    odometry: tuple[str, int],
    *,
    scans: int,
    stat: str,
    ate_below: float,
) -> None:
    """A real log with every ``stride``-th scan kept and odometry of a family drawn by a
    seed: the run keeps ``scans`` scans, uses the mechanism that ``stat`` counts, and ends
    within ``ate_below`` of GMapping's poses."""
    from baromap.evaluation.laser_logs import odometry_model, run_log

    family, seed = odometry
    report = run_log(
        shared_data / "laser", name, seed=seed, stride=stride, odometry=odometry_model(family, seed)
    )
    assert report.scans == scans
    assert report.result.stats[stat] > 0
    assert report.slam_ate.rms_m < ate_below


@pytest.mark.slow
def test_a_sparse_scan_that_fits_along_a_ridge_is_matched_not_left_to_odometry(
    shared_data: Path,
) -> None:
    """Acapulco, every second scan kept (2 m apart in open halls), odometry of the varied
    family, seed 0, up to 20 keyframes past keyframe 99. Keyframe 99's scan fits equally well
    anywhere over 0.3 m: the search's best and runner-up scored 0.576 and 0.581, both within
    0.17 m and 0.7 degrees of GMapping's pose. Refused as ambiguous, the keyframe stood where
    odometry put it, 4 degrees off after a turn of 24, the next scans matched against it, and
    the run stayed turned (0.67 m ATE over these 120 scans; 0.96 m over the whole log). Taken
    as one ridge (the score stays up between the two), its covariance reaching the runner-up
    and the keyframe placed on the ridge where odometry likes it best: the step within half a
    degree, 0.40 m ATE over these scans (0.18 m over the whole log, whose later loops close).

    The odometry is the whole log's, cut to the part: the part's own would be another draw."""
    from baromap.evaluation.laser_logs import PreparedLog, odometry_model
    from baromap.evaluation.trajectory import trajectory_error
    from baromap.mapping.slam import run_slam
    from baromap.odometry.synthesis import synthesize_odometry

    laser = shared_data / "laser"
    whole = PreparedLog(laser, "acapulco", stride=2)
    part = PreparedLog(laser, "acapulco", scans=slice(0, 240), stride=2)
    odom = synthesize_odometry(whole.reference, 0, odometry_model("varied", 0))[: len(part.times)]
    zeros = np.zeros(len(part.times), dtype=np.int64)
    result = run_slam(part.block, odom, zeros, zeros)
    assert result.stats["front_ridges"] > 0
    before, ridge = result.keyframes[98], result.keyframes[99]
    step = se2.between(result.scan_poses[before], result.scan_poses[ridge])
    true_step = se2.between(part.reference[before], part.reference[ridge])
    assert abs(math.degrees(se2.wrap(step[2] - true_step[2]))) < 1.5
    assert trajectory_error(result.scan_poses, part.reference).rms_m < 0.5


@pytest.mark.slow
def test_a_closure_beyond_the_drift_model_puts_a_wrong_front_end_turn_right(
    shared_data: Path,
) -> None:
    """Freiburg 079, every 30th scan kept: 160 scans, 2-3 m and turns of up to 170 degrees
    between scans. After such a turn the front end can take a match degrees off (seed 0:
    keyframe 131 12 degrees off, where corrected odometry was 2 degrees off), a jump no drift
    model foresees. The closures that would put it right, a few metres later, lie beyond the
    drift model; dropped, the rest of the run stays turned (seed 8: 1.55 m ATE). Such a
    closure is proposed, to be taken when a second one agrees, where the chain it corrects
    holds a step the front end could not vouch for (seed 8: 0.14 m)."""
    from baromap.evaluation.laser_logs import run_log

    report = run_log(shared_data / "laser", "fr079", seed=8, stride=30)
    assert report.scans == 160
    assert report.slam_ate.rms_m < 0.3
    assert report.result.stats["loop_beyond_drift"] > 0


@pytest.mark.slow
def test_one_scan_matching_two_submaps_beyond_the_drift_model_confirms_itself(
    shared_data: Path,
) -> None:
    """The same input, odometry of the varied family, seed 0: a keyframe finds one
    correction against two submaps, beyond the drift model and scoring as loops, and the
    two closures confirm each other (0.112 m ATE; 0.122 m with them left waiting).

    The input it was made for, seed 1, no longer needs it since a closure counts once in the
    graph (0.204 m, none taken): there the front end left the run 22 degrees off after turns
    of 111 and 165 degrees, and keyframe 151's two closures, left waiting while the next
    keyframes searched around the turned estimate, ended the run 2 m off (0.63 m ATE)."""
    _check_thinned_log_run(
        shared_data,
        "fr079",
        30,
        ("varied", 0),
        scans=160,
        stat="loop_groups_one_scan",
        ate_below=0.3,
    )


@pytest.mark.slow
def test_a_closure_beyond_the_drift_model_is_looked_for_again_where_it_puts_the_robot(
    shared_data: Path,
) -> None:
    """The Intel log, every fourth scan, odometry of the strong family, seed 7. Keyframe 169
    matched submap 21 at 0.556, a correction of 6.6 degrees, beyond the drift model, and
    proposed it; keyframe 170, searched around its estimate (a window of 4 degrees), could
    not confirm it (0.36 and 0.10). Searched where the proposal puts it, it matches submap 19
    at 0.69, 0.04 m from the truth, and both are taken: 0.155 m ATE, 0.319 m without."""
    _check_thinned_log_run(
        shared_data, "intel", 4, ("strong", 7), scans=228, stat="loop_followed", ate_below=0.25
    )


@pytest.mark.slow
def test_a_front_end_match_odometry_cannot_explain_yields_in_the_last_solve(
    shared_data: Path,
) -> None:
    """The Intel log, every fourth scan kept: 228 scans, 2-4 m apart, turns of up to 130
    degrees. On seed 2 the front end took keyframe 144 turned by 19.5 degrees after a turn of
    125 (corrected odometry was 5 degrees off) and keyframes along corridors 0.7-1 m along
    (odometry 0.03-0.15 m off); the next keyframes' matches put the robot back, so two match
    edges held each wrong pose against odometry and the closures (0.258 m ATE, 1.04 m max).
    Doubted in the last solve (a robust kernel on the matches that disagree with corrected
    odometry beyond both their uncertainties), they yield: 0.081 m (max 0.29 m)."""
    from baromap.evaluation.laser_logs import run_log

    report = run_log(shared_data / "laser", "intel", seed=2, stride=4)
    assert report.scans == 228
    assert report.result.stats["matches_doubted"] > 0
    assert report.slam_ate.rms_m < 0.15
    assert report.slam_ate.max_m < 0.5


def test_odometry_calibration_learns_the_creep_along_corridors_with_noisy_odometry() -> None:
    """A run of long corridors: straight half-metre steps, a corner every 20 m, odometry 5 %
    long, creeping 2.5 deg/m with 0.5 deg of noise a step, matches to 0.2 deg. Fitted on the
    odometric turn (whose noise on a straight step is exactly what is left to explain), a fit
    takes the noise for a turn error and learns about half the creep (1.16 deg/m of the 2.38
    per odometric metre); fitted on the matched turn it learns all of it."""
    rng = np.random.default_rng(5)
    cal = OdometryCalibration()
    pinned = np.diag([0.01**2, 0.01**2, math.radians(0.2) ** 2])
    creep = math.radians(2.5)
    for i in range(600):
        corner = i % 40 == 39
        turn = rng.choice([-1.0, 1.0]) * math.pi / 2 if corner else rng.normal(0, math.radians(0.5))
        true = np.array([rng.uniform(0.4, 0.6), rng.normal(0.0, 0.01), turn])
        noise = rng.normal(0.0, math.radians(0.5))
        read = np.array([true[0] * 1.05, true[1] * 1.05, true[2] + creep * true[0] + noise])
        cal.observe(read, true + rng.multivariate_normal(np.zeros(3), pinned), pinned)
    a, b = cal.turn_terms()
    assert a == pytest.approx(0.0, abs=0.01)
    assert math.degrees(b) == pytest.approx(-2.5 / 1.05, abs=0.1)


def test_odometry_calibration_is_near_the_truth_after_its_first_few_samples() -> None:
    """Sparse steps (0.5-2.5 m, turns of tens of degrees), odometry 3 % long in turn and
    creeping 1.5 deg/m with a degree of noise per metre or radian, matches to 0.3 deg: after
    10 and 20 samples the corrected heading of a 1.5 m, 46 deg step, over 40 runs. Uncorrected
    it is 3.6 deg off. Samples weighted by the match's variance alone pass a few early ones
    for a sure fit (1.48 deg RMS, 3.6 max after 10 samples; 0.73, 3.6 after 20); weighted by
    their whole variance and shrunk towards no error, 0.68, 1.77 and 0.46, 1.04."""
    pinned = np.diag([0.01**2, 0.01**2, math.radians(0.3) ** 2])
    errors: dict[int, list[float]] = {10: [], 20: []}
    for run in range(40):
        rng = np.random.default_rng(run)
        cal = OdometryCalibration()
        for i in range(20):
            true = np.array([rng.uniform(0.5, 2.5), rng.normal(0.0, 0.05), rng.normal(0, 0.8)])
            noise = rng.normal(0.0, math.radians(1.0) * math.sqrt(true[0] + abs(true[2])))
            read = np.array(
                [
                    true[0] * 1.04,
                    true[1] * 1.04,
                    true[2] * 1.03 + math.radians(1.5) * true[0] + noise,
                ]
            )
            cal.observe(read, true + rng.multivariate_normal(np.zeros(3), pinned), pinned)
            if i + 1 in errors:
                step = cal.correct(
                    np.array([1.5 * 1.04, 0.0, 0.8 * 1.03 + math.radians(1.5) * 1.5])
                )
                errors[i + 1].append(math.degrees(step[2] - 0.8))
    for n, rms_deg, max_deg in ((10, 1.0, 2.5), (20, 0.6, 1.5)):
        e = np.array(errors[n])
        assert float(np.sqrt(np.mean(e**2))) < rms_deg, n
        assert float(np.abs(e).max()) < max_deg, n


def test_odometry_noise_is_what_the_matched_steps_show_not_the_wrong_matches() -> None:
    """Residuals of corrected odometry that grow as a random walk in distance and in turn
    (1 cm per square-root metre, 1 deg per square-root radian, a 0.1 deg floor), and 5 % of
    wrong matches 20 cm and 5 degrees off: the fit finds the walk, not the outliers."""
    from baromap.mapping.odometry_calibration import fit_noise

    rng = np.random.default_rng(3)
    n = 3000
    travel = rng.uniform(0.0, 0.6, n)
    turn = np.where(rng.random(n) < 0.3, rng.uniform(-0.5, 0.5, n), 0.0)
    var_xy = 0.01**2 * travel
    var_theta = math.radians(0.1) ** 2 + math.radians(1.0) ** 2 * np.abs(turn)
    residuals = np.stack(
        [
            rng.normal(0.0, np.sqrt(var_xy)),
            rng.normal(0.0, np.sqrt(var_xy)),
            rng.normal(0.0, np.sqrt(var_theta)),
        ],
        axis=1,
    )
    wrong = rng.random(n) < 0.05
    residuals[wrong] += [0.2, 0.0, math.radians(5.0)]
    noise = fit_noise(residuals, travel, turn)
    xy, theta = noise.sigmas(0.5, 0.0)
    assert xy == pytest.approx(0.01 * math.sqrt(0.5), rel=0.15)
    assert math.degrees(theta) == pytest.approx(0.1, rel=0.2)
    _, theta = noise.sigmas(0.0, 0.4)
    assert math.degrees(theta) == pytest.approx(math.sqrt(0.1**2 + 0.4), rel=0.15)


def test_odometry_noise_of_many_steps_is_that_of_each() -> None:
    """The vectorised sigmas (the registration's pull, one per scan) are the scalar ones."""
    from baromap.mapping.odometry_calibration import OdometryNoise

    noise = OdometryNoise(xy=(1e-6, 2e-4, 0.0), theta=(0.0, 1e-5, 3e-4))
    travel = np.array([0.0, 0.1, 0.25, 0.0])
    turn = np.array([0.0, 0.0, -0.2, 0.4])
    many_xy, many_theta = noise.sigmas_many(travel, turn)
    for k in range(len(travel)):
        xy, theta = noise.sigmas(float(travel[k]), float(turn[k]))
        assert many_xy[k] == pytest.approx(xy)
        assert many_theta[k] == pytest.approx(theta)
    assert many_theta[0] > 0  # the floor, where the fit says nothing


def test_registration_pull_decides_along_a_corridor_and_weighs_as_its_sigmas_say() -> None:
    """A scan between two long walls, started 6 cm along, 4 cm across and 1 degree off its
    true pose: along the corridor only the pull decides, and the pose stays where it
    started; across and in heading the scan and the pull meet as two Gaussians do, so odometry
    with a 2 cm, 0.5 deg sigma leaves the scan within millimetres of the walls and a
    quarter of its heading error, four times wider sigmas let the walls decide, and four times
    narrower ones hold it near where it started."""
    from baromap.mapping.refine import Pull, refine_batch

    wall_x = np.arange(-10.0, 10.0, 0.02)
    walls = np.concatenate(
        [np.stack([wall_x, np.full_like(wall_x, y)], axis=1) for y in (-1.0, 1.0)]
    )
    field = LikelihoodField.from_points(walls, 0.05, 0.05)
    beams = np.radians(np.arange(-90.0, 90.0, 3.0))
    beams = beams[np.abs(np.sin(beams)) > 0.2]
    r = 1.0 / np.abs(np.sin(beams))
    scan = np.stack([r * np.cos(beams), r * np.sin(beams)], axis=1)
    owner = np.zeros(len(scan), dtype=np.int64)
    start = np.array([[0.06, 0.04, math.radians(1.0)]])

    def refined(factor: float) -> np.ndarray:
        pull = Pull(np.array([0.02 * factor]), np.array([math.radians(0.5) * factor]))
        out = refine_batch(field, scan, owner, start, pull)
        assert out.usable[0]
        assert out.poses[0, 0] == pytest.approx(0.06, abs=0.005)
        return out.poses[0]

    pose = refined(1.0)
    assert abs(pose[1]) < 0.005
    assert abs(math.degrees(pose[2])) < 0.3
    wide = refined(4.0)
    assert abs(wide[1]) < 0.003
    assert abs(math.degrees(wide[2])) < 0.1
    narrow = refined(0.25)
    assert narrow[1] > 0.02
    assert math.degrees(narrow[2]) > 0.6


def test_every_keyframe_scan_takes_its_keyframe_pose_the_last_one_too() -> None:
    """Scans between keyframes follow odometry with the graph's correction spread along the
    stretch; a keyframe's own scan is the keyframe. The run's last scan is a keyframe (the
    last of its visit), and it must not follow odometry from the keyframe before it: on a
    sparse log that is a metre of uncorrected odometry, degrees off."""
    rng = np.random.default_rng(3)
    steps = np.column_stack([np.full(12, 0.3), np.zeros(12), rng.normal(0.0, 0.05, 12)])
    odom = [np.zeros(3)]
    for step in steps:
        odom.append(se2.compose(odom[-1], step))
    odom_arr = np.array(odom)
    kf_scan = np.array([0, 4, 8, 12])
    kf_poses = odom_arr[kf_scan] + np.array(
        [[0.0, 0.0, 0.0], [0.05, 0.1, 0.02], [0.1, 0.2, 0.04], [0.2, 0.1, 0.06]]
    )
    poses = scan_poses(odom_arr, kf_scan, kf_poses)
    assert poses[kf_scan] == pytest.approx(kf_poses, abs=1e-9)


def test_scans_after_a_silence_follow_odometry_back_from_the_keyframe_after_it() -> None:
    """A step the graph turned by 160 degrees (a power-cycled base turned on the spot while
    its odometry was silent): the scans between its keyframes taken after the silence
    follow odometry back from the keyframe after it, the one before it odometry from the
    keyframe before; spreading the turn along the stretch would put them up to 1.6 m off.
    Other scans get the graph's correction spread along their stretch."""
    odom = np.array([[0.1 * i, 0.0, 0.0] for i in range(12)])
    kf_scan = np.array([0, 4, 8, 11])
    kf_poses = odom[kf_scan].copy()
    kf_poses[2:] = se2.compose(np.array([0.0, 3.0, math.radians(160.0)]), odom[kf_scan[2:]])
    side = np.zeros(len(odom), dtype=np.int8)
    side[5], side[6:8] = -1, 1  # the silence between scans 5 and 6
    spread = scan_poses(odom, kf_scan, kf_poses)
    poses = scan_poses(odom, kf_scan, kf_poses, silence=side)
    truth = se2.compose(np.array([0.0, 3.0, math.radians(160.0)]), odom[6:8])
    assert poses[6:8] == pytest.approx(truth, abs=1e-9)
    assert poses[5] == pytest.approx(odom[5], abs=1e-9)
    assert np.hypot(*(spread[5:8, :2] - np.vstack([odom[5:6], truth])[:, :2]).T).max() > 1.5
    assert np.delete(poses, [5, 6, 7], axis=0) == pytest.approx(
        np.delete(spread, [5, 6, 7], axis=0), abs=1e-12
    )


def test_edge_scatter_is_the_real_error_over_the_claimed_one() -> None:
    """Match edges that claim 4 cm and 1 deg but err 1 cm and 0.25 deg (a sixteenth of the
    variance they claim), among odometry edges that claim their real error, with 5 % of the
    matches wrong by 30 cm: the scatter of each kind is what its edges show against the
    poses, and scaling by it makes the matches claim their real error."""
    rng = np.random.default_rng(5)
    n = 2000
    poses = np.cumsum(rng.normal(0.0, [0.4, 0.4, 0.3], (n, 3)), axis=0)
    graph = PoseGraph()
    for pose in poses:
        graph.add_node(pose)
    claims = {"odometry": (0.02, math.radians(0.5)), "match": (0.04, math.radians(1.0))}
    real = {"odometry": (0.02, math.radians(0.5)), "match": (0.01, math.radians(0.25))}
    for kind, (sxy, stheta) in claims.items():
        rxy, rt = real[kind]
        for k in range(1, n):
            noise = rng.normal(0.0, [rxy, rxy, rt])
            if kind == "match" and rng.random() < 0.05:
                noise[0] += 0.3
            z = se2.between(poses[k - 1], poses[k]) + noise
            graph.add_edge(Edge(k - 1, k, z, np.diag([sxy**-2, sxy**-2, stheta**-2]), kind))
    count, odometry = graph.scatter("odometry")
    assert count == n - 1
    assert odometry == pytest.approx(1.0, rel=0.1)
    _, matches = graph.scatter("match")
    assert matches == pytest.approx(1 / 16, rel=0.15)
    graph.scale_information("match", 1.0 / matches)
    assert graph.scatter("match")[1] == pytest.approx(1.0, rel=1e-9)
    assert graph.scatter("odometry")[1] == odometry
    assert graph.scatter("loop") == (0, 1.0)


@pytest.mark.slow
def test_a_log_read_once_scores_every_seed_as_a_log_read_for_each(shared_data: Path) -> None:
    """The bench reads a log and scores the corrected poses' revisits once for all seeds: a
    seed run on the prepared log reports what a run reading the log itself reports, and the
    second seed reuses the first one's revisit scoring rather than making it again."""
    from baromap.evaluation.laser_logs import PreparedLog, run_log, run_prepared

    laser = shared_data / "laser"
    part = slice(0, 60)
    prepared = PreparedLog(laser, "acapulco", scans=part, stride=2)
    first = run_prepared(prepared, 1, score_consistency=True)
    second = run_prepared(prepared, 2, score_consistency=True)
    alone = run_log(laser, "acapulco", 2, scans=part, stride=2, score_consistency=True)
    assert second.scans == alone.scans == 30
    assert second.result.scan_poses == pytest.approx(alone.result.scan_poses, abs=1e-12)
    assert second.slam_ate.rms_m == pytest.approx(alone.slam_ate.rms_m, abs=1e-12)
    assert first.slam_consistency is not None and second.slam_consistency is not None
    assert alone.slam_consistency is not None and alone.reference_consistency is not None
    assert second.reference_consistency is first.reference_consistency  # made once
    assert second.reference_consistency.mean_m == pytest.approx(
        alone.reference_consistency.mean_m, abs=1e-12
    )
    assert second.slam_consistency.mean_m == pytest.approx(alone.slam_consistency.mean_m, abs=1e-12)
    assert first.slam_ate.rms_m != second.slam_ate.rms_m  # two seeds, two runs


@pytest.mark.slow
def test_the_intel_log_cut_just_after_its_first_return_to_the_start_closes_that_loop(
    shared_data: Path,
) -> None:
    """The Intel log's first 109 scans: round the lab (71 m) and 3 m past where it began, no
    closure before. The revisit can only be matched against the run's first metres, a map
    framed on one side; refused outright, the loop stays open (0.169 m ATE; seeds 1 and 2:
    0.137, 0.102 m); kept until the run ends and then taken: 0.086 m."""
    from baromap.evaluation.laser_logs import run_log

    report = run_log(shared_data / "laser", "intel", seed=0, scans=slice(0, 109))
    assert report.result.stats["loop_deferred_taken"] >= 2
    assert report.slam_ate.rms_m < 0.12


@given(
    st.lists(st.floats(-1e3, 1e3), min_size=9, max_size=9),
    st.integers(0, 3),
)
def test_match_information_holds_for_a_scan_that_measured_little(
    values: list[float], rank: int
) -> None:
    """A rank-deficient fit (a few points along one wall) must not raise or poison the graph."""
    a = np.array(values).reshape(3, 3)
    a[:, rank:] = 0.0  # information of rank <= rank
    h = a @ a.T
    info = match_information(h, 0.05, 0.01)
    assert np.all(np.isfinite(info))
    assert np.allclose(info, info.T)
    eig = np.linalg.eigvalsh(info)
    assert eig.min() >= -1e-6 * max(eig.max(), 1.0)
    # never more than the floor alone allows
    assert eig.max() <= (1 / 0.01**2) * (1 + 1e-9)
    # its covariance, wanted by the odometry calibration and the doubt of matches, is finite
    cov = edge_covariance(info)
    assert np.all(np.isfinite(cov))
    if np.linalg.cond(h) < 1e8:
        floor = np.diag([0.05**2, 0.05**2, 0.01**2])
        direct = np.linalg.inv(np.linalg.inv(h) * MATCH_COV_SCALE + floor)
        assert np.allclose(info, direct, rtol=1e-6, atol=1e-9 * np.abs(direct).max())
        if np.linalg.eigvalsh(direct)[0] > 1e-3:  # every direction measured: inverted as it is
            assert np.allclose(cov, np.linalg.inv(direct), rtol=1e-6, atol=1e-9)


def _posts(xs: np.ndarray) -> np.ndarray:
    """Points of small square posts (20 cm) centred on (x, 1) for each x: a fence."""
    ring = np.array([[u, v] for u in np.linspace(-0.1, 0.1, 5) for v in (-0.1, 0.1)])
    ring = np.concatenate([ring, ring[:, ::-1]])
    return np.concatenate([ring + np.array([x, 1.0]) for x in xs])


def test_two_answers_are_one_ridge_along_a_wall_and_two_peaks_along_a_fence() -> None:
    """A scan of a plain wall fits anywhere along it: the search's best and its runner-up are
    ends of one ridge, every pose between them scoring as well. A scan of a fence of posts a
    metre apart fits every metre: two peaks, the poses between them missing every post."""
    window = SearchWindow(1.3, math.radians(3.0), math.radians(1.0))
    wall = np.column_stack([np.linspace(-8.0, 8.0, 801), np.ones(801)])
    fence = _posts(np.arange(-8.0, 8.5, 1.0))
    for world, seen, valley in (
        (wall, wall[(wall[:, 0] > -2) & (wall[:, 0] < 2)], False),
        (fence, _posts(np.arange(-2.0, 2.5, 1.0)), True),
    ):
        field = LikelihoodField.from_points(world, 0.05, 0.05)
        found = correlative_search(field, seen, np.array([0.02, 0.0, 0.0]), window)
        assert found.runner_up_pose is not None
        assert found.runner_up >= 0.97 * found.score  # ambiguous, by the front end's test
        ends = min(score_at(field, seen, found.pose), score_at(field, seen, found.runner_up_pose))
        between = lowest_between(field, seen, found.pose, found.runner_up_pose)
        if valley:
            assert abs(abs(found.runner_up_pose[0] - found.pose[0]) - 1.0) < 0.1
            assert between < 0.5 * ends
        else:
            assert between > 0.95 * ends


def test_a_search_with_no_distinct_answer_reports_no_runner_up_pose() -> None:
    """A window too small to hold two poses 0.3 m or 5 degrees apart has no runner-up."""
    field = LikelihoodField.from_points(_posts(np.array([0.0])), 0.05, 0.05)
    window = SearchWindow(0.1, math.radians(2.0), math.radians(1.0))
    found = correlative_search(field, _posts(np.array([0.0])), np.zeros(3), window)
    assert found.runner_up_pose is None
    assert found.runner_up == 0.0


@given(
    st.lists(st.floats(-30, 30), min_size=9, max_size=9),
    st.lists(st.floats(-1, 1), min_size=3, max_size=3),
    st.integers(1, 3),
)
def test_a_spread_widens_a_match_along_it_and_keeps_it_across(
    values: list[float], spread: list[float], rank: int
) -> None:
    """The information of the covariance ``inv(H) + d d^T``, computed without inverting H (a
    scan that measured one direction only has a singular H)."""
    a = np.array(values).reshape(3, 3)
    a[:, rank:] = 0.0
    h = a @ a.T + (np.eye(3) if rank == 3 else 0.0)
    d = np.array(spread)
    out = spread_information(h, d)
    assert np.allclose(out, out.T)
    assert np.linalg.eigvalsh(out).min() >= -1e-6 * max(1.0, float(np.abs(h).max()))
    # never more information than before, in any direction
    assert np.linalg.eigvalsh(h - out).min() >= -1e-6 * max(1.0, float(np.abs(h).max()))
    if rank == 3:
        direct = np.linalg.inv(np.linalg.inv(h) + np.outer(d, d))
        assert np.allclose(out, direct, rtol=1e-6, atol=1e-8 * float(np.abs(h).max()))
    # a direction u with u . H d = 0 pairs with no part of the spread: it keeps all it had
    hd = h @ d
    u = np.cross(hd, np.eye(3)[int(np.argmin(np.abs(hd)))])
    assert np.isclose(
        u @ out @ u, u @ h @ u, rtol=1e-6, atol=1e-6 * max(1.0, float(np.abs(h).max()))
    )


@given(
    st.lists(st.floats(-2, 2), min_size=3, max_size=3),
    st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3),
    st.lists(st.floats(-2, 2), min_size=3, max_size=3),
    st.floats(0.0, 1.0),
)
def test_a_keyframe_on_a_ridge_stands_between_its_ends_nearest_odometry(
    best: list[float], spread: list[float], guess: list[float], t: float
) -> None:
    """The ridge was seen between the search's best and its runner-up only: the keyframe is
    placed on that segment, and where odometry already stands on it, there."""
    b, d, g = np.array(best), np.array(spread), np.array(guess)
    info = np.diag([1 / 0.1**2, 1 / 0.1**2, 1 / math.radians(3.0) ** 2])
    placed = place_on_ridge(g, info, b, d)
    along = placed - b
    along[2] = se2.wrap(along[2])
    if float(d @ d) > 1e-12:
        s = float(along @ d / (d @ d))
        assert -1e-9 <= s <= 1 + 1e-9
        assert np.allclose(along, s * d, atol=1e-9)
    if float(d @ info @ d) > 1e-9:
        on = b + t * d
        on[2] = se2.wrap(on[2])
        assert np.allclose(se2.wrap(place_on_ridge(on, info, b, d) - on), 0.0, atol=1e-9)


def test_a_scan_its_floor_does_not_confirm_is_kept_out_of_the_grid() -> None:
    from baromap.mapping.build import floor_scans, grid_scans
    from baromap.mapping.slam import run_slam

    # along the L-room's long arm and back, odometry exact; one scan between keyframes sees
    # the inside of a 2 m box (the elevator car, or a stamp that paired it with the wrong
    # odometry): nothing of the room
    xs = np.concatenate([np.linspace(1.0, 9.0, 120), np.linspace(9.0, 1.0, 120)])
    thetas = np.concatenate([np.zeros(120), np.full(120, math.pi)])
    poses = np.column_stack([xs, np.full(240, 1.0), thetas])
    scans = block(list(poses))
    box = np.array([[-1, -1, 1, -1], [1, -1, 1, 1], [1, 1, -1, 1], [-1, 1, -1, -1]], float)
    odd = 62  # between keyframes 56 and 64, where the grid takes every other scan
    scans.ranges_m[odd] = cast(np.zeros(3), box)
    one = np.zeros(240, dtype=np.int64)
    result = run_slam(scans, poses, one, one)
    assert odd not in set(result.keyframes.tolist())
    registered = result.scan_registered
    assert registered[result.keyframes].all()
    assert not registered[odd]
    assert registered.mean() > 0.9  # the room's own scans are placed by the map
    everywhere = np.ones(240, dtype=bool)
    assert odd in grid_scans(result.scan_poses, everywhere)  # spaced as the grid would take it
    grid = floor_scans(result, everywhere)
    assert odd not in grid
    assert len(grid) >= len(grid_scans(result.scan_poses, everywhere)) - 2
