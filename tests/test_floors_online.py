"""The online floor detector and detect_floors, on synthetic series with known answers."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from baromap.floors import FloorDetectorConfig, OnlineFloorDetector, detect_floors
from baromap.floors.height import pressure_drop_pa
from baromap.floors.still_window import StillWindow
from baromap.messages import NS_PER_S, FloorEvent, FloorPhase, PressureSample

RATE_HZ = 10.0
P0 = 97_700.0
STOREY_M = 3.2


def series(
    plan: list[tuple[float, float]],
    *,
    drift_pa_s: float = 0.0,
    noise_pa: float = 0.3,
    seed: int = 0,
    ride_m_s: float = 1.0,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """Pressure for ``plan`` = [(height_m, dwell_s), ...], riding between at ``ride_m_s``."""
    heights: list[float] = []
    for k, (height, dwell) in enumerate(plan):
        if k:
            previous = plan[k - 1][0]
            steps = max(1, int(abs(height - previous) / ride_m_s * RATE_HZ))
            heights.extend(np.linspace(previous, height, steps, endpoint=False)[1:].tolist())
        heights.extend([height] * int(dwell * RATE_HZ))
    z = np.asarray(heights)
    t_s = np.arange(z.size) / RATE_HZ
    rng = np.random.default_rng(seed)
    p = P0 * np.exp(-z / 8434.5) + drift_pa_s * t_s + rng.normal(0.0, noise_pa, z.size)
    return (t_s * NS_PER_S).astype(np.int64), p


def run(
    t: npt.NDArray[np.int64], p: npt.NDArray[np.float64], config: FloorDetectorConfig | None = None
) -> tuple[OnlineFloorDetector, list[FloorEvent]]:
    detector = OnlineFloorDetector(config)
    published = []
    for ti, pi in zip(t.tolist(), p.tolist(), strict=True):
        published += detector.update(PressureSample(ti, pi, 15.0))
    published += detector.finish()
    events = [e for e in published if isinstance(e, FloorEvent)]
    assert events == detector.events  # published in order, rides beside them
    return detector, events


def moves(events: list[FloorEvent]) -> list[tuple[int, int]]:
    return [(e.from_id, e.to_id) for e in events]


def test_one_storey_up_is_one_event_with_the_right_height() -> None:
    t, p = series([(0.0, 60), (STOREY_M, 60)])
    detector, events = run(t, p)
    assert len(events) == 1
    event = events[0]
    assert (event.from_id, event.to_id, event.from_name, event.to_name) == (0, 1, "0", "1")
    assert event.event_id == 1 and event.replaces is None
    assert event.delta_m == pytest.approx(STOREY_M, abs=0.1)
    assert event.height_m == pytest.approx(STOREY_M, abs=0.1)
    assert event.delta_pa == pytest.approx(-pressure_drop_pa(STOREY_M, P0), abs=1.0)
    assert event.t_start_ns <= event.t_end_ns <= event.t_ns
    # The pressure came to rest within a few seconds of arriving (ride 3.2 s from t=60 s)...
    assert event.t_end_ns / NS_PER_S < 60 + STOREY_M + 2.0
    # ...and without odometry the stop is a visit once it lasted min_visit_s.
    wait = (event.t_ns - event.t_end_ns) / NS_PER_S
    assert wait == pytest.approx(FloorDetectorConfig().min_visit_s, abs=0.2)
    state = detector.state()
    assert state.floor_id == 1 and state.phase is FloorPhase.SETTLED and state.floors_known == 2
    assert state.height_m == pytest.approx(STOREY_M, abs=0.1)
    assert state.level_m == pytest.approx(STOREY_M, abs=0.1)


def test_going_down_finds_a_lower_floor_under_a_new_id() -> None:
    t, p = series([(0.0, 40), (-STOREY_M, 40)])
    _, events = run(t, p)
    assert moves(events) == [(0, 1)]  # the start floor keeps id 0, however low the next is
    assert events[0].delta_m < 0 and events[0].height_m == pytest.approx(-STOREY_M, abs=0.1)
    assert events[0].to_name == "-1"


@pytest.mark.parametrize("spike_pa", [-25.0, -12.0, 12.0, 25.0])
def test_ventilation_spikes_and_small_steps_raise_no_event(spike_pa: float) -> None:
    t, p = series([(0.0, 120)])
    p = p.copy()
    i = int(40 * RATE_HZ)
    p[i : i + 15] += spike_pa  # a 1.5 s gust from the elevator shaft
    j = int(80 * RATE_HZ)
    p[j:] += pressure_drop_pa(1.0, P0)  # a 1 m ramp: below the 1.8 m threshold
    detector, events = run(t, p)
    assert events == []
    assert detector.state().floor_id == 0


def test_revisits_get_their_old_id_in_spite_of_drift() -> None:
    # 1.5 hPa/h is about a storey in 20 minutes; the run lasts 50 minutes.
    plan = [(0.0, 300), (STOREY_M, 600), (2 * STOREY_M, 600), (0.0, 600), (STOREY_M, 600)]
    plan += [(2 * STOREY_M, 300)]
    t, p = series(plan, drift_pa_s=150.0 / 3600.0)
    _, events = run(t, p)
    assert moves(events) == [(0, 1), (1, 2), (2, 0), (0, 1), (1, 2)]
    assert [e.to_name for e in events] == ["1", "2", "0", "1", "2"]


def test_the_detector_is_causal() -> None:
    t, p = series([(0.0, 30), (STOREY_M, 30), (0.0, 30)])
    _, all_events = run(t, p)
    cut = int(50 * RATE_HZ)
    detector = OnlineFloorDetector()
    early = []
    for ti, pi in zip(t[:cut].tolist(), p[:cut].tolist(), strict=True):
        decided = detector.update(PressureSample(ti, pi))
        # stamped with the sample that decided it: nothing is dated before it was known
        assert [e.t_ns for e in decided] == [ti] * len(decided)
        early += decided
    floor_events = [e for e in early if isinstance(e, FloorEvent)]
    assert floor_events, "the cut falls after the first decision, or this compares nothing"
    assert floor_events == [e for e in all_events if e.t_ns < t[cut]]


def test_reference_station_removes_weather() -> None:
    plan = [(0.0, 300), (STOREY_M, 900), (0.0, 600)]
    drift = 6.0 / 60.0  # a storm: 6 hPa/h
    t, p = series(plan, drift_pa_s=drift)
    reference = P0 + drift * t / NS_PER_S
    detection = detect_floors(t, p, reference=(t, reference))
    assert [(tr.from_floor, tr.to_floor) for tr in detection.transitions] == [(0, 1), (1, 0)]
    assert detection.floors[1].elevation_m == pytest.approx(STOREY_M, abs=0.1)


def test_bad_samples_are_counted_not_raised() -> None:
    detector = OnlineFloorDetector()
    assert detector.update(PressureSample(10, P0)) == []
    assert detector.update(PressureSample(5, P0)) == []  # older
    assert detector.update(PressureSample(20, float("nan"))) == []
    assert detector.ignored_samples == 2
    state = detector.state()
    assert state.floor_id is None and state.phase is FloorPhase.UNKNOWN


def test_a_new_detector_knows_no_floor_and_no_level() -> None:
    state = OnlineFloorDetector().state()
    assert state.floors_known == 0 and state.floor_id is None and math.isnan(state.level_pa)


def test_reference_readings_count_each_bad_one_and_correct_within_a_second() -> None:
    """Every unusable reference reading is counted; a reading half a second after the last one
    moves the weather correction (the station may report faster than once a second)."""
    detector = OnlineFloorDetector()
    for t in (1, 2):
        detector.update_reference(PressureSample(t, float("nan")))
    assert detector.ignored_samples == 2
    plain, corrected = OnlineFloorDetector(), OnlineFloorDetector()
    corrected.update_reference(PressureSample(0, P0))
    for detector in (plain, corrected):
        detector.update(PressureSample(NS_PER_S // 4, P0))
    corrected.update_reference(PressureSample(NS_PER_S // 2, P0 + 50.0))
    for detector in (plain, corrected):
        detector.update(PressureSample(3 * NS_PER_S // 4, P0))
    assert plain.state().level_pa == P0 and corrected.state().level_pa != P0


def test_bad_temperatures_and_reference_readings_do_not_stop_the_detector() -> None:
    t, p = series([(0.0, 60), (STOREY_M, 60)])
    detector = OnlineFloorDetector()
    events = []
    for k, (ti, pi) in enumerate(zip(t.tolist(), p.tolist(), strict=True)):
        glitch = [float("nan"), -300.0, 15.0][k % 3]  # NaN, below absolute zero, fine
        detector.update_reference(PressureSample(ti, float("nan") if k == 5 else P0))
        events += detector.update(PressureSample(ti, pi, glitch))
    events = [e for e in events if isinstance(e, FloorEvent)]
    assert moves(events) == [(0, 1)]
    assert events[0].delta_m == pytest.approx(STOREY_M, abs=0.1)
    assert detector.ignored_samples == 1  # the NaN reference reading


def test_detect_floors_result_is_consistent() -> None:
    plan = [(0.0, 60), (2 * STOREY_M, 60), (STOREY_M, 60), (2 * STOREY_M, 60)]
    t, p = series(plan)
    detection = detect_floors(t, p, np.full(t.shape, 15.0))
    assert [(tr.from_floor, tr.to_floor) for tr in detection.transitions] == [
        (0, 2),
        (2, 1),
        (1, 2),
    ]
    elevations = [f.elevation_m for f in detection.floors]
    np.testing.assert_allclose(elevations, [0.0, STOREY_M, 2 * STOREY_M], atol=0.1)
    assert [f.visits for f in detection.floors] == [1, 1, 2]
    assert detection.floor_of(int(30 * NS_PER_S)) == 0
    assert detection.floor_of(int(-1 * NS_PER_S)) is None
    assert detection.smoothed_pa.shape == detection.rate_pa_per_s.shape == t.shape
    document = detection.to_json()
    assert set(document) >= {"floors", "transitions", "segments"}
    assert document["transitions"][0]["from"] == 0 and document["transitions"][0]["to"] == 2
    segments = detection.segments
    assert all(a.t_end_ns <= b.t_start_ns for a, b in itertools.pairwise(segments))


@pytest.mark.parametrize("every", [5, 10, 20])
def test_a_barometer_read_slowly_still_finds_its_floors(every: int) -> None:
    """Every 5th, 10th, 20th sample kept: 2, 1 and 0.5 Hz. With a sample every 1.5 s or
    more, the shortest run of samples spanning the settle window (1.5 s) held two, fewer than
    the three a stillness test needs, and the detector never settled on a floor at all (and
    detect_floors then failed building a floor it had no name for)."""
    plan = [(0.0, 60), (2 * STOREY_M, 60), (STOREY_M, 60)]
    t, p = series(plan)
    t, p = t[::every], p[::every]
    detection = detect_floors(t, p, np.full(t.shape, 15.0))
    assert [(tr.from_floor, tr.to_floor) for tr in detection.transitions] == [(0, 2), (2, 1)]
    elevations = [f.elevation_m for f in detection.floors]
    np.testing.assert_allclose(elevations, [0.0, STOREY_M, 2 * STOREY_M], atol=0.15)
    assert [f.name for f in detection.floors] == ["0", "1", "2"]


def test_a_run_that_never_comes_to_rest_has_one_floor_without_a_name() -> None:
    """Pressure that never stays still for the settle window (a barometer going up and down
    by a metre every few seconds): no floor is ever known by name, and that is the answer,
    not a failure."""
    t = (np.arange(0, 120, 0.1) * NS_PER_S).astype(np.int64)
    p = P0 + 12.0 * np.sin(np.arange(t.size) * 0.35)
    detection = detect_floors(t, p, np.full(t.shape, 15.0))
    assert detection.transitions == ()
    assert [f.name for f in detection.floors] == [""]


def test_paper_method_on_a_clean_run_and_its_failure_under_drift() -> None:
    plan = [(0.0, 120), (STOREY_M, 120), (0.0, 120)]
    t, p = series(plan, noise_pa=0.2)
    clean = detect_floors(t, p, method="paper")
    assert len(clean.floors) == 2
    assert clean.transitions[0].to_floor == 1
    # With drift, the revisit of floor 0 no longer matches floor 0's mean.
    plan = [(0.0, 900), (STOREY_M, 900), (0.0, 900)]
    t, p = series(plan, drift_pa_s=150.0 / 3600.0)
    drifted = detect_floors(t, p, method="paper")
    online = detect_floors(t, p, method="online")
    assert len(online.floors) == 2
    assert len(drifted.floors) != 2 or len(drifted.transitions) != 2


def test_detect_floors_rejects_bad_input() -> None:
    from baromap.errors import ConfigError, InputFormatError

    with pytest.raises(InputFormatError):
        detect_floors([], [])
    with pytest.raises(InputFormatError):
        detect_floors([1, 2], [P0])
    with pytest.raises(ConfigError):
        detect_floors([1, 2], [P0, P0], method="magic")


@pytest.mark.parametrize("method", ["online", "paper"])
def test_non_finite_and_repeated_samples_are_left_out(method: str, tmp_path: Path) -> None:
    from baromap.floors.plot import plot_detection

    plan = [(0.0, 120), (STOREY_M, 120)]
    t, p = series(plan, noise_pa=0.2)
    temp = np.full(t.shape, 15.0)
    clean = detect_floors(t, p, temp, method=method)
    bad_t = np.concatenate([t, t[500:510]])  # repeated stamps, out of order
    bad_p = np.concatenate([p, p[500:510]])
    bad_p[[100, 1800]] = [np.nan, np.inf]
    bad_temp = np.concatenate([temp, temp[500:510]])
    dirty = detect_floors(bad_t, bad_p, bad_temp, method=method)
    assert dirty.t_ns.size == t.size - 2
    assert np.isfinite(dirty.smoothed_pa).all()
    assert [f.elevation_m for f in dirty.floors] == pytest.approx(
        [f.elevation_m for f in clean.floors], abs=0.05
    )
    assert [(x.from_floor, x.to_floor) for x in dirty.transitions] == [(0, 1)]
    assert (dirty.threshold_pa_per_s is None) == (method == "online")
    # the figure takes the raw series with its own times, longer than the detection's
    plot_detection(dirty, bad_t, bad_p, tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 10_000


def test_config_min_height_is_honoured() -> None:
    t, p = series([(0.0, 60), (STOREY_M, 60)])
    _, events = run(t, p, FloorDetectorConfig(min_transition_m=4.0, start_m=0.5))
    assert events == []


def test_a_long_stop_at_an_offset_is_no_landing_of_the_next_trip() -> None:
    # A 1 m ramp, a minute there, then 0.6 m more and soon after a storey up: the trip that
    # reaches the next floor began with the 0.6 m leg, not with the ramp a minute earlier.
    t, p = series([(0.0, 60), (1.0, 60), (1.6, 8), (1.6 + STOREY_M, 60)], noise_pa=0.2)
    _, events = run(t, p)
    assert moves(events) == [(0, 1)]
    assert 115.0 < events[0].t_start_ns / NS_PER_S < 125.0


def test_the_stop_is_known_one_window_after_the_pressure_stops() -> None:
    """Stillness is one test over settle_s, not a lagging rate and then a hold."""
    config = FloorDetectorConfig()
    for seed in range(3):
        t, p = series([(0.0, 60), (STOREY_M, 60)], seed=seed)
        stopped = 60 + STOREY_M
        detector = OnlineFloorDetector(config)
        known = None
        for ti, pi in zip(t.tolist(), p.tolist(), strict=True):
            detector.update(PressureSample(ti, pi, 15.0))
            if known is None and detector.phase is FloorPhase.STOPPED:
                known = ti / NS_PER_S
        # settle_s of stillness plus the smoothing's catching up (level_tau_s); a Holt rate
        # quiet for settle_s took about 4.5 s here
        assert known is not None
        assert known - stopped < config.settle_s + 2 * config.level_tau_s


@pytest.mark.parametrize("spike_pa", [-15.0, 15.0])
def test_a_spike_after_the_stop_is_not_taken_for_the_floor(spike_pa: float) -> None:
    t, p = series([(0.0, 60), (STOREY_M, 60)], noise_pa=0.2)
    p = p.copy()
    after = (t / NS_PER_S - (60 + STOREY_M + 0.5)).clip(0.0, None)
    p += np.where(after > 0.0, spike_pa * np.exp(-after / 0.7), 0.0)  # fading over seconds
    detector, events = run(t, p)
    assert moves(events) == [(0, 1)]
    final = float(np.median(p[-200:]))
    assert abs(events[0].level_pa - final) < pressure_drop_pa(0.3, P0)
    assert detector.state().level_pa == pytest.approx(final, abs=0.5)


def test_the_floor_level_is_taken_once_the_doors_are_open() -> None:
    # The car stays 4 Pa above the floor's pressure for 3 s after the stop, then the doors
    # open: the pressure settles first, but the visit (and the floor's level) comes after.
    plan = [(0.0, 60), (STOREY_M, 60), (0.0, 60), (STOREY_M, 60)]
    t, p = series(plan, noise_pa=0.2)
    p = p.copy()
    s = t / NS_PER_S
    stop = 60 + STOREY_M
    p += np.where((s > stop - 5.0) & (s < stop + 3.0), 4.0, 0.0)
    detector, events = run(t, p)
    assert moves(events) == [(0, 1), (1, 0), (0, 1)]
    assert events[0].t_ns / NS_PER_S > stop + 3.0
    level = float(np.median(p[(s > stop + 10.0) & (s < stop + 50.0)]))
    expected = -pressure_drop_pa(STOREY_M, P0)
    assert detector.registry.relative_pa(1) == pytest.approx(expected, abs=1.0)
    assert events[0].level_pa == pytest.approx(level, abs=1.0)


def test_a_lull_in_the_ride_is_no_floor() -> None:
    # The car pauses for 3 s at 2.2 m (above the minimum height) and goes on to 3.2 m.
    plan = [(0.0, 60), (2.2, 3), (STOREY_M, 60), (0.0, 60), (STOREY_M, 60)]
    t, p = series(plan, noise_pa=0.2)
    detector, events = run(t, p)
    assert moves(events) == [(0, 1), (1, 0), (0, 1)]
    assert all(e.replaces is None for e in events)
    assert events[0].delta_m == pytest.approx(STOREY_M, abs=0.1)
    assert events[0].t_start_ns / NS_PER_S < 60.5  # dated from the first leg
    assert detector.state().height_m == pytest.approx(STOREY_M, abs=0.1)


def test_samples_before_a_gap_do_not_count_as_stillness() -> None:
    t, p = series([(0.0, 60), (STOREY_M, 60)])
    s = t / NS_PER_S
    keep = (s < 61.0) | (s > 75.0)  # 14 s without data during and after the ride
    _, events = run(t[keep], p[keep])
    assert moves(events) == [(0, 1)]
    assert events[0].t_end_ns / NS_PER_S >= 75.0


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(0.001, 8.0), st.floats(-50.0, 50.0), st.floats(-5.0, 5.0)),
        min_size=1,
        max_size=300,
    ),
    st.integers(1, 4),
)
def test_still_window_matches_a_direct_computation(
    steps: list[tuple[float, float, float]], min_samples: int
) -> None:
    """Running sums and monotonic queues agree with a fit over the samples kept."""
    window_ns = round(1.5 * NS_PER_S)
    window = StillWindow(window_ns, min_samples)
    times: list[int] = []
    raw: list[float] = []
    smooth: list[float] = []
    t = 1_700_000_000 * NS_PER_S
    for dt, p, s in steps:
        t += max(1, round(dt * NS_PER_S))
        times.append(t)
        raw.append(97_000.0 + p)
        smooth.append(97_000.0 + p + s)
        window.push(t, raw[-1], smooth[-1])
        # the shortest run of latest samples that spans the window and holds min_samples
        # (or all there are)
        k = len(times) - 1
        while k > 0 and (times[-1] - times[k] < window_ns or len(times) - k < min_samples):
            k -= 1
        assert window.count == len(times) - k
        assert window.start_ns == times[k]
        assert window.spread() == pytest.approx(max(smooth[k:]) - min(smooth[k:]), abs=1e-9)
        if window.count >= 2:
            x = (np.asarray(times[k:]) - times[k]) / NS_PER_S
            slope = np.polyfit(x, np.asarray(raw[k:]) - 97_000.0, 1)[0]
            assert window.slope() == pytest.approx(slope, rel=1e-6, abs=1e-6)
