"""The simulated world: building, route, motion and the barometer part of a run."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from baromap.errors import ConfigError
from baromap.sim import building as bld
from baromap.sim.atmosphere import height_m, hydrostatic_pa
from baromap.sim.motion import Move, trapezoid_duration, trapezoid_progress
from baromap.sim.route import check_route, default_route
from baromap.sim.scenario import ROBOT_SENSOR_HEIGHT_M, make_scenario, pressure_run


@pytest.fixture(scope="module")
def building() -> bld.Building:
    return bld.make_building(0)


def test_building_contract(building: bld.Building) -> None:
    assert len(building.floors) == 6
    for i, plan in enumerate(building.floors):
        assert plan.index == i
        assert plan.walls_m.dtype == np.float64
        assert plan.walls_m.ndim == 2
        assert plan.walls_m.shape[1] == 4
        assert len(plan.walls_m) > 100
        assert plan.is_free(building.elevator_xy).all()
        assert plan.is_free(building.lobby_xy).all()
    assert building.floors[0].kind == "ground"
    assert len({p.kind for p in building.floors[1:]}) >= 3


def test_storeys_are_uneven_with_a_tall_ground_floor_and_a_mezzanine_gap(
    building: bld.Building,
) -> None:
    storeys = np.diff(building.elevations_m)
    assert (storeys > 3.0).all()
    assert storeys[0] >= 5.0
    assert storeys[0] > np.median(storeys)
    assert building.mezzanine_m is not None
    gap = int(np.argmax(storeys))
    assert storeys[gap] > 6.0
    lower, upper = building.elevations_m[gap], building.elevations_m[gap + 1]
    assert lower < building.mezzanine_m < upper


def test_floors_differ_and_the_ground_floor_is_open(building: bld.Building) -> None:
    grids = [p.occupancy_truth(0.2) for p in building.floors]
    for a, b in itertools.combinations(range(len(grids)), 2):
        differ = np.logical_xor(grids[a], grids[b]).mean()
        assert differ > 0.01, (a, b)
    # The ground floor's largest free region spans most of the footprint.
    labels, _ = ndimage.label(building.floors[0].free_raster)
    biggest = np.bincount(labels.ravel())[1:].max() * bld.RASTER_M**2
    assert biggest > 0.6 * bld.FOOTPRINT_M[0] * bld.FOOTPRINT_M[1]
    upper, _ = ndimage.label(building.floors[1].free_raster)
    assert np.bincount(upper.ravel())[1:].max() * bld.RASTER_M**2 < biggest


@pytest.mark.slow
def test_building_is_deterministic_per_seed() -> None:
    a = bld.make_building.__wrapped__(3)
    b = bld.make_building.__wrapped__(3)
    c = bld.make_building.__wrapped__(4)
    assert all(
        np.array_equal(x.walls_m, y.walls_m) for x, y in zip(a.floors, b.floors, strict=True)
    )
    assert not all(
        x.walls_m.shape == y.walls_m.shape and np.array_equal(x.walls_m, y.walls_m)
        for x, y in zip(a.floors, c.floors, strict=True)
    )


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(8))
def test_every_nav_edge_keeps_clear_of_walls_and_everything_is_reachable(seed: int) -> None:
    building = bld.make_building(seed)
    for plan in building.floors:
        clearance = ndimage.distance_transform_edt(plan.free_raster) * bld.RASTER_M
        segs = np.hstack(
            [plan.nav.nodes[plan.nav.edges[:, 0]], plan.nav.nodes[plan.nav.edges[:, 1]]]
        )
        pts = bld.segment_points(segs, 0.05)
        rows = (pts[:, 1] / bld.RASTER_M).astype(int)
        cols = (pts[:, 0] / bld.RASTER_M).astype(int)
        assert clearance[rows, cols].min() >= bld.NAV_CLEARANCE_M
        # All room waypoints connect to the lobby (no edge was dropped as unsafe).
        labels = _components(len(plan.nav.nodes), plan.nav.edges)
        lobby = labels[plan.lobby_node]
        assert labels[plan.elevator_node] == lobby
        for room in plan.rooms:
            assert all(labels[w] == lobby for w in room.waypoints), room.name


def _components(n: int, edges: np.ndarray) -> np.ndarray:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    g = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    return connected_components(g, directed=False)[1]


def test_occupancy_truth_marks_wall_faces_only(building: bld.Building) -> None:
    plan = building.floors[2]
    grid = plan.occupancy_truth(0.05, origin_xy=(-1.0, -1.0))
    assert grid.shape == (math.ceil(25 / 0.05) + 1, math.ceil(61 / 0.05) + 1)
    x1, y1, x2, y2 = plan.walls_m[len(plan.walls_m) // 2]
    mid = ((x1 + x2) / 2, (y1 + y2) / 2)
    assert grid[int((mid[1] + 1.0) / 0.05), int((mid[0] + 1.0) / 0.05)]
    assert not grid[
        int((building.lobby_xy[1] + 1.0) / 0.05), int((building.lobby_xy[0] + 1.0) / 0.05)
    ]
    small = plan.occupancy_truth(0.1, origin_xy=(0.0, 0.0), shape=(10, 10))
    assert small.shape == (10, 10)
    with pytest.raises(ConfigError):
        plan.occupancy_truth(0.0)


def test_trapezoid_profile_is_consistent() -> None:
    for d, v, a in [(10.0, 0.5, 0.3), (0.2, 0.5, 0.3), (math.pi, 0.7, 1.7)]:
        total = trapezoid_duration(d, v, a)
        tau = np.linspace(0, total, 2001)
        s, speed = trapezoid_progress(
            tau, np.full_like(tau, d), np.full_like(tau, v), np.full_like(tau, a)
        )
        assert s[0] == 0.0
        assert s[-1] == pytest.approx(d)
        assert speed.max() <= v + 1e-9
        assert np.all(np.diff(s) >= -1e-12)
        # Speed is the derivative of distance.
        assert np.allclose(np.gradient(s, tau), speed, atol=a * (tau[1] - tau[0]) * 2)


@pytest.fixture(scope="module")
def scenario():  # type: ignore[no-untyped-def]
    return make_scenario(0)


def test_default_route_is_the_papers_with_a_revisit(scenario) -> None:  # type: ignore[no-untyped-def]
    assert scenario.route == (4, 5, 3, 2, 1, 0, 2)
    for floors in range(2, 12):  # the paper's order generalised: every floor, one revisit
        route = check_route(default_route(floors), floors)
        assert set(route) == set(range(floors)) and len(route) == floors + 1
    hops = [(t.from_floor, t.to_floor) for t in scenario.transitions()]
    assert hops == list(itertools.pairwise(scenario.route))
    assert scenario.moves.end_s == pytest.approx(46 * 60)


def test_rides_last_10_to_40_s_including_doors(scenario) -> None:  # type: ignore[no-untyped-def]
    m = scenario.moves
    for i in np.nonzero(m.kind == Move.RIDE)[0]:
        assert m.kind[i - 1] == Move.WAIT
        assert m.kind[i + 1] == Move.WAIT
        total = m.duration[i - 1] + m.duration[i] + m.duration[i + 1]
        assert 10.0 <= total <= 40.0


def test_robot_stays_in_free_space_at_realistic_speeds(scenario) -> None:  # type: ignore[no-untyped-def]
    t = np.arange(0, scenario.duration_s, 0.25)
    truth = scenario.truth(t)
    for f, plan in enumerate(scenario.building.floors):
        on = truth.floor == f
        assert plan.is_free(np.column_stack([truth.x[on], truth.y[on]])).all()
    assert truth.v.max() <= 0.6 + 1e-9
    driving = truth.v[truth.move == Move.DRIVE]
    assert 0.3 < np.percentile(driving, 90) <= 0.6
    # Turning happens in place: never drive and turn at once.
    assert not np.any((truth.v > 0) & (truth.omega != 0))
    # Elevator rides are the only vertical motion, and only at the elevator.
    moving = truth.vz != 0
    assert np.allclose(truth.x[moving], scenario.building.elevator_xy[0])
    # The route visits every floor and returns to one.
    assert set(truth.floor[truth.floor >= 0].tolist()) == set(range(6))


def test_custom_routes_and_bad_routes() -> None:
    sc = make_scenario(1, floors=3, minutes=8.0, route=[0, 2, 1])
    assert [(t.from_floor, t.to_floor) for t in sc.transitions()] == [(0, 2), (2, 1)]
    for bad in ([], [0, 0], [0, 7]):
        with pytest.raises(ConfigError):
            make_scenario(1, floors=3, route=bad)
    with pytest.raises(ConfigError):
        make_scenario(1, floors=0)
    with pytest.raises(ConfigError):
        make_scenario(1, minutes=0)


@pytest.fixture(scope="module")
def run():  # type: ignore[no-untyped-def]
    return pressure_run(0)


def test_pressure_run_contract(run) -> None:  # type: ignore[no-untyped-def]
    n = 46 * 60 * 25
    assert run.t_ns.dtype == np.int64
    for name in ("pressure_pa", "temperature_c", "truth_z_m", "reference_pa"):
        assert getattr(run, name).shape == (n,)
    assert run.truth_floor.dtype.kind == "i"
    assert np.all(np.diff(run.t_ns) == 40_000_000)
    assert len(run.transitions) == 6
    riding = run.truth_floor == -1
    for tr in run.transitions:
        inside = (run.t_ns > tr.t_start_ns) & (run.t_ns < tr.t_end_ns)
        assert riding[inside].all()
    assert riding.sum() == sum(
        ((run.t_ns > tr.t_start_ns) & (run.t_ns < tr.t_end_ns)).sum() for tr in run.transitions
    )
    again = pressure_run(0)
    assert np.array_equal(again.pressure_pa, run.pressure_pa)
    other = pressure_run(1)
    assert not np.array_equal(other.pressure_pa[:100], run.pressure_pa[:100])


def test_pressure_is_bmp280_like(run) -> None:  # type: ignore[no-untyped-def]
    # Quantised to the 20-bit step; noise after the IIR filter about 0.2 Pa.
    steps = np.round(run.pressure_pa / 0.16)
    assert np.allclose(steps * 0.16, run.pressure_pa, rtol=0, atol=1 / 512 + 1e-9)
    assert np.array_equal(np.round(run.pressure_pa * 256) / 256, run.pressure_pa)
    still = run.truth_floor >= 0
    resid = (run.pressure_pa - run.true_pressure_pa)[still]
    hf = np.diff(resid)[:20000]
    assert 0.02 < hf.std() < 0.5
    assert np.allclose(np.round(run.temperature_c, 2), run.temperature_c)


def test_pressure_agrees_with_height_and_drift(run) -> None:  # type: ignore[no-untyped-def]
    sc = make_scenario(0)
    # Heights from the robot against the reference station: weather cancels.
    h = height_m(run.pressure_pa, run.reference_pa, sc.air.mean_c)
    errors = []
    for f in range(6):
        on = run.truth_floor == f
        errors.append(np.median(h[on] - run.truth_z_m[on]))
    errors_arr = np.array(errors)
    # One offset common to all floors (sensor offsets, mounting heights) ...
    assert np.ptp(errors_arr) < 0.6
    # ... and heights agree with the floor elevations within half a metre.
    assert np.abs(errors_arr - errors_arr.mean()).max() < 0.35
    # The reference follows the weather drift.
    drift = sc.weather.drift_pa(run.t_s)
    ref = run.reference_pa - run.reference_pa[:250].mean()
    assert np.abs(ref - (drift - drift[:250].mean())).max() < 6.0
    # Noise-free pressure is exactly hydrostatic away from the elevator.
    still = run.truth_floor >= 0
    expected = hydrostatic_pa(
        sc.weather.ground_pa(run.t_s), run.truth_z_m + ROBOT_SENSOR_HEIGHT_M, sc.air.mean_c
    )
    doors = np.abs(run.true_pressure_pa - expected) > 0.05
    assert (~doors[still]).mean() > 0.95


@pytest.mark.slow
def test_weather_drift_is_bounded_and_can_exceed_a_storey() -> None:
    exceeded = 0
    for seed in range(6):
        sc = make_scenario(seed)
        t = np.linspace(0, sc.duration_s, 2000)
        rate = np.abs(sc.weather.drift_rate_pa_s(t)) * 3600 / 100
        assert rate.max() <= 1.5 + 1e-9
        hour = abs(sc.weather.drift_pa(3600.0) - sc.weather.drift_pa(0.0))
        exceeded += hour > 11.8 * 3.6
    assert exceeded >= 3


def test_elevator_rides_make_pressure_spikes(run) -> None:  # type: ignore[no-untyped-def]
    sc = make_scenario(0)
    t = run.t_s
    truth = sc.truth(t)
    expected = hydrostatic_pa(
        sc.weather.ground_pa(t), truth.z + ROBOT_SENSOR_HEIGHT_M, sc.air.mean_c
    )
    disturbance = run.true_pressure_pa - expected
    assert np.abs(disturbance).max() > 5.0
    far = np.ones(len(t), dtype=bool)
    for tr in run.transitions:
        far &= np.abs(run.t_ns - (tr.t_start_ns + tr.t_end_ns) // 2) > 60 * 1_000_000_000
    assert np.abs(disturbance[far]).max() < 0.5


def _brute_cast(
    segs: np.ndarray, origin: np.ndarray, heading: float, angles: np.ndarray
) -> np.ndarray:
    out = np.full(len(angles), np.inf)
    p0, e = segs[:, :2], segs[:, 2:] - segs[:, :2]
    w = p0 - origin
    for k, a in enumerate(angles):
        d = np.array([math.cos(heading + a), math.sin(heading + a)])
        den = d[0] * e[:, 1] - d[1] * e[:, 0]
        with np.errstate(all="ignore"):
            t = (w[:, 0] * e[:, 1] - w[:, 1] * e[:, 0]) / den
            u = (w[:, 0] * d[1] - w[:, 1] * d[0]) / den
        ok = (np.abs(den) > 1e-12) & (t > 1e-6) & (u >= 0) & (u <= 1)
        if ok.any():
            out[k] = t[ok].min()
    return out


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    heading=st.floats(-math.pi, math.pi),
    n=st.integers(1, 40),
)
def test_segment_ray_casting_matches_brute_force(seed: int, heading: float, n: int) -> None:
    from baromap.sim.laser import cast

    rng = np.random.default_rng(seed)
    segs = rng.uniform(-6, 6, (n, 4))
    origin = rng.uniform(-1, 1, 2)
    angles = np.radians(np.arange(-90.0, 90.5, 1.0))
    got, cosines = cast(segs, origin[None, :], np.array([heading]), angles, 8.0)
    want = _brute_cast(segs, origin, heading, angles)
    want[want > 8.0] = np.inf
    # Same beams hit, at the same distances.
    differ = np.isfinite(got[0]) != np.isfinite(want)
    assert differ.sum() == 0
    both = np.isfinite(got[0]) & np.isfinite(want)
    assert np.allclose(got[0][both], want[both], atol=1e-6)
    assert np.all((cosines >= 0) & (cosines <= 1 + 1e-9))
