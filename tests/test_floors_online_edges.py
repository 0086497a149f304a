"""The online floor detector at its edges: a threshold met exactly, a gap in the samples, the
first decisions of a run, the rides it announces. Each test feeds a few hundred to a few
thousand noise-free synthetic samples (milliseconds) and reads its numbers off the module's
constants and the configuration, so a retune moves the tests with it."""

from __future__ import annotations

import copy
import math
from collections.abc import Callable

import numpy as np
import pytest
from structlog.testing import capture_logs

from baromap.evaluation.floor_traces import DRIVE_M_S, TRACE_EPOCH_NS, Stay, Trace, trace
from baromap.floors import FloorDetectorConfig, OnlineFloorDetector
from baromap.floors.building_model import BuildingModel, ModelFloor
from baromap.floors.config import MAX_AIR_C, MIN_AIR_C
from baromap.floors.height import pa_per_m, pressure_drop_pa
from baromap.floors.online import MAX_CAR_ACCEL_M_S2, MAX_WEATHER_RATE_PA_S
from baromap.floors.replay import replay
from baromap.messages import (
    NS_PER_S,
    FloorEvent,
    FloorEventKind,
    FloorPhase,
    Odometry,
    PressureSample,
    RideDirection,
    RideEvent,
    RideEventKind,
)

P0 = 97_700.0
T_C = 15.0
RATE_HZ = 10.0
CONFIG = FloorDetectorConfig()
#: Pa per metre at the start pressure: the detector's thresholds are metres times this.
GRADIENT = pa_per_m(P0, T_C)


def at(seconds: float) -> int:
    return TRACE_EPOCH_NS + round(seconds * NS_PER_S)


def feed(
    detector: OnlineFloorDetector,
    start_s: float,
    end_s: float,
    pressure: Callable[[float], float],
) -> list[FloorEvent | RideEvent]:
    """Samples at RATE_HZ from ``start_s`` (included) to ``end_s`` (excluded), the pressure
    a function of the time in seconds; returns the events published meanwhile."""
    out: list[FloorEvent | RideEvent] = []
    for k in range(round((end_s - start_s) * RATE_HZ)):
        s = start_s + k / RATE_HZ
        out += detector.update(PressureSample(at(s), pressure(s), T_C))
    return out


def storeys_pa(storeys: float) -> float:
    """The pressure change of climbing ``storeys`` minimum transitions (negative going up)."""
    return -pressure_drop_pa(storeys * CONFIG.min_transition_m, P0, T_C)


def live(
    tr: Trace, config: FloorDetectorConfig | None = CONFIG, *, odometry: bool = True
) -> OnlineFloorDetector:
    return tr.detected(config, odometry=odometry)


def moves(events: list[FloorEvent] | tuple[FloorEvent, ...]) -> list[tuple[int, int]]:
    return [(e.from_id, e.to_id) for e in events]


def secs(t_ns: int) -> float:
    return (t_ns - TRACE_EPOCH_NS) / NS_PER_S


# -- a gap in the samples -----------------------------------------------------------------


def test_the_weather_drift_is_carried_over_a_gap_in_the_samples() -> None:
    """A gap longer than max_gap_s starts a change (the robot may have moved meanwhile),
    measured from where the weather has taken the floor's level over the gap."""
    drift = MAX_WEATHER_RATE_PA_S / 2
    detector = OnlineFloorDetector(CONFIG)

    def weather(s: float) -> float:
        return P0 + drift * s

    feed(detector, 0.0, 400.0, weather)  # long enough for the tracker to learn the drift
    assert detector.phase is FloorPhase.SETTLED
    gap = 3 * CONFIG.max_gap_s
    resume = 400.0 + gap
    assert detector.update(PressureSample(at(resume), weather(resume), T_C)) == []
    state = detector.state()
    assert state.phase is FloorPhase.CHANGING
    # the floor's level moved with the weather by drift * gap: the robot is on it
    carried_m = drift * gap / GRADIENT
    assert abs(state.level_m) < carried_m / 10
    assert feed(detector, resume + 0.1, resume + 30.0, weather) == []
    state = detector.state()
    assert state.phase is FloorPhase.SETTLED and abs(state.level_m) < carried_m / 10


# -- the first samples and the state before them --------------------------------------------


def test_the_state_is_stamped_with_the_last_sample_and_nothing_before_the_first() -> None:
    detector = OnlineFloorDetector(CONFIG)
    state = detector.state()
    assert (state.t_ns, state.since_ns) == (0, 0)  # no time seen yet
    for _ in range(2):  # each unusable first sample is counted, not only the last
        detector.update(PressureSample(at(0.0), math.nan, T_C))
    assert detector.ignored_samples == 2
    feed(detector, 0.0, 1.0, lambda s: P0)
    assert detector.state().t_ns == at(0.9) and detector.floor_id is None
    feed(detector, 1.0, 10.0, lambda s: P0)
    state = detector.state()
    assert state.floor_id == 0 and state.t_ns == at(9.9)
    # the start floor is known from the first sample that ends a still window
    assert state.since_ns == at(CONFIG.settle_s)


def test_without_a_reference_station_the_level_is_the_pressure() -> None:
    detector = OnlineFloorDetector(CONFIG)
    feed(detector, 0.0, 10.0, lambda s: P0)
    assert detector.level == P0 and detector.smoothed == P0
    assert detector.state().level_pa == P0


def test_a_reference_reading_moves_the_correction_by_its_time_based_gain() -> None:
    """One reference step of ``x`` Pa, ``dt`` after the first reading, moves the weather
    correction by x * dt / (reference_tau_s + dt); the robot's level is its pressure less
    that, and what it publishes is back in measured pascals."""
    detector = OnlineFloorDetector(CONFIG)
    detector.update_reference(PressureSample(at(0.0), P0, T_C))
    dt = CONFIG.reference_tau_s / 4
    step = 10.0
    detector.update_reference(PressureSample(at(dt), P0 + step, T_C))
    correction = step * dt / (CONFIG.reference_tau_s + dt)
    feed(detector, 0.0, 30.0, lambda s: P0)
    assert detector.level == pytest.approx(P0 - correction, abs=1e-6)
    assert detector.state().level_pa == pytest.approx(P0, abs=1e-6)


def test_levels_published_with_a_reference_station_are_measured_pressures() -> None:
    """The weather the station sees is taken off the robot's pressure for the decisions and
    put back in the levels published: an event's level is the pressure the robot read."""
    weather = MAX_WEATHER_RATE_PA_S  # Pa/s, seen by both
    tr = trace([Stay(0.0, 60), Stay(2 * CONFIG.min_transition_m, 60)], noise_pa=0.0)
    seconds = tr.seconds()
    robot = tr.pressure_pa + weather * seconds
    station = (tr.t_ns, P0 + weather * seconds)
    detector, _, _ = replay(tr.t_ns, robot, tr.temperature_c, CONFIG, reference=station)
    (event,) = detector.events
    at_event = robot[tr.t_ns == event.t_ns][0]
    assert event.level_pa == pytest.approx(at_event, abs=0.5)
    assert event.delta_m == pytest.approx(2 * CONFIG.min_transition_m, abs=0.05)


def test_temperatures_at_the_plausible_bounds_are_glitches() -> None:
    """A reading of exactly MIN_AIR_C or MAX_AIR_C is as implausible as one beyond: the last
    plausible temperature stands, and heights are the same as with no reading at all."""
    tr = trace([Stay(0.0, 60), Stay(2 * CONFIG.min_transition_m, 60)], noise_pa=0.0)
    bounds = [MIN_AIR_C if k % 2 else MAX_AIR_C for k in range(tr.t_ns.size)]
    bounds[0] = T_C
    none, _, _ = replay(tr.t_ns, tr.pressure_pa, [T_C] * tr.t_ns.size, CONFIG)
    glitched, _, _ = replay(tr.t_ns, tr.pressure_pa, bounds, CONFIG)
    assert [e.delta_m for e in glitched.events] == [e.delta_m for e in none.events]
    assert len(none.events) == 1


def test_log_lines_say_what_happened() -> None:
    """The debug and info lines an operator reads: every floor and ride event with its
    fields, and a gap with its length in seconds."""
    tr = trace([Stay(0.0, 30), Stay(2 * CONFIG.min_transition_m, 30)], noise_pa=0.0)
    keep = tr.seconds() < 10.0
    keep |= tr.seconds() > 10.0 + 2 * CONFIG.max_gap_s
    with capture_logs() as logs:
        detector, _, _ = replay(tr.t_ns[keep], tr.pressure_pa[keep], tr.temperature_c[keep], CONFIG)
    (gap,) = [e for e in logs if e["event"] == "pressure gap"]
    kept = tr.t_ns[keep]
    assert gap["seconds"] == pytest.approx(float(np.diff(kept).max()) / NS_PER_S)
    (floor,) = [e for e in logs if e["event"] == "floor event"]
    (event,) = detector.events
    assert floor["kind"] == "transition" and floor["event_id"] == event.event_id
    assert (floor["from_name"], floor["to_name"]) == (event.from_name, event.to_name)
    assert floor["delta_m"] == round(event.delta_m, 2) != event.delta_m
    rides = [e for e in logs if e["event"] == "ride event"]
    assert len(detector.rides) == 2  # started, ended
    assert [r["kind"] for r in rides] == [r.kind.value for r in detector.rides]
    assert [r["reason"] for r in rides] == [r.reason for r in detector.rides]


# -- when decisions are taken ----------------------------------------------------------------


def test_without_odometry_a_stop_is_a_visit_exactly_min_visit_s_after_it_came_to_rest() -> None:
    tr = trace([Stay(0.0, 60), Stay(2 * CONFIG.min_transition_m, 60)], noise_pa=0.0)
    (event,) = live(tr, odometry=False).events
    assert event.t_ns - event.t_end_ns == round(CONFIG.min_visit_s * NS_PER_S)


def test_the_pressure_is_still_for_settle_s_before_a_stop_is_known() -> None:
    """Three still samples do not make a still window: it spans settle_s."""
    tr = trace([Stay(0.0, 60), Stay(2 * CONFIG.min_transition_m, 60)], noise_pa=0.0)
    arrived = tr.stays_s[1][0]
    detector = OnlineFloorDetector(CONFIG)
    known = None
    for ti, pi in zip(tr.t_ns.tolist(), tr.pressure_pa.tolist(), strict=True):
        detector.update(PressureSample(ti, pi, T_C))
        if known is None and detector.phase is FloorPhase.STOPPED:
            known = secs(ti)
    assert known is not None
    assert CONFIG.settle_s <= known - arrived < CONFIG.settle_s + 2 * CONFIG.level_tau_s


def test_the_state_during_a_change_follows_the_pressure() -> None:
    height = 2 * CONFIG.min_transition_m
    tr = trace([Stay(0.0, 60), Stay(height, 60)], noise_pa=0.0)
    detector = OnlineFloorDetector(CONFIG)
    halfway = tr.stays_s[0][1] + height / 2  # the ride goes at 1 m/s
    for ti, pi in zip(tr.t_ns.tolist(), tr.pressure_pa.tolist(), strict=True):
        detector.update(PressureSample(ti, pi, T_C))
        if secs(ti) >= halfway:
            break
    state = detector.state()
    assert state.phase is FloorPhase.CHANGING and state.floor_id == 0
    # the smoothed pressure lags the ride by about level_tau_s
    assert state.level_m == pytest.approx(height / 2 - CONFIG.level_tau_s, abs=0.3)


@pytest.mark.parametrize("where", ["stopped", "changing"])
def test_the_input_ending_during_a_stop_or_a_change_decides_it(where: str) -> None:
    """finish() decides a stop still waiting to be a visit, or a change that has not come
    to rest, from what there was: an event marked at_end."""
    height = 2 * CONFIG.min_transition_m
    stays = [Stay(0.0, 60), Stay(height, CONFIG.min_visit_s / 2 if where == "stopped" else 0.2)]
    tr = trace(stays, noise_pa=0.0)
    detector = OnlineFloorDetector(CONFIG)
    for ti, pi in zip(tr.t_ns.tolist(), tr.pressure_pa.tolist(), strict=True):
        assert not any(
            isinstance(e, FloorEvent) for e in detector.update(PressureSample(ti, pi, T_C))
        )
    assert detector.phase is (FloorPhase.STOPPED if where == "stopped" else FloorPhase.CHANGING)
    published = detector.finish()
    (event,) = [e for e in published if isinstance(e, FloorEvent)]
    assert event.at_end and event.t_ns == tr.t_ns[-1] and moves([event]) == [(0, 1)]
    assert [r.kind for r in published if isinstance(r, RideEvent)][-1] is RideEventKind.ENDED


def replay_with_gap(
    tr: Trace, after: Callable[[OnlineFloorDetector, float], bool], gap_s: float
) -> OnlineFloorDetector:
    """Replay ``tr`` (pressure only) with no samples for ``gap_s`` after the first sample
    at which ``after(detector, seconds)`` holds."""
    detector = OnlineFloorDetector(CONFIG)
    gap_from = math.inf
    for ti, pi in zip(tr.t_ns.tolist(), tr.pressure_pa.tolist(), strict=True):
        s = secs(ti)
        if math.isinf(gap_from) and after(detector, s):
            gap_from = s
        if gap_from < s < gap_from + gap_s:
            continue
        detector.update(PressureSample(ti, pi, T_C))
    detector.finish()
    return detector


def test_a_gap_on_a_floor_then_a_storey_up_is_a_trip_from_before_the_gap() -> None:
    """The robot may have moved during the gap: the trip began at the last sample before
    it, and the ride (never seen) is announced with the floor event, upwards."""
    height = 2 * CONFIG.min_transition_m
    tr = trace([Stay(0.0, 60), Stay(height, 60)], noise_pa=0.0)
    last_before = 50.0
    gap = tr.stays_s[1][0] + 5.0 - last_before
    detector = replay_with_gap(tr, lambda d, s: s >= last_before, gap)
    (event,) = detector.events
    assert moves([event]) == [(0, 1)] and event.t_start_ns == at(last_before)
    started, ended = detector.rides
    assert started.kind is RideEventKind.STARTED and ended.kind is RideEventKind.ENDED
    assert started.direction is RideDirection.UP and started.t_start_ns == at(last_before)


def test_a_gap_on_a_floor_the_robot_stays_on_is_no_event() -> None:
    height = 2 * CONFIG.min_transition_m
    tr = trace([Stay(0.0, 60), Stay(height, 120)], noise_pa=0.0)
    detector = replay_with_gap(tr, lambda d, s: len(d.events) == 1, 3 * CONFIG.max_gap_s)
    assert moves(detector.events) == [(0, 1)]
    assert detector.phase is FloorPhase.SETTLED and detector.floor_id == 1


def test_the_weather_drift_is_carried_over_a_gap_during_a_change() -> None:
    """From the start floor too: the floor's level goes on with the weather over the gap,
    so the step is measured from where the floor is now."""
    height = 2 * CONFIG.min_transition_m
    drift = MAX_WEATHER_RATE_PA_S / 2
    tr = trace([Stay(0.0, 400), Stay(height, 60)], noise_pa=0.0, drift_pa_s=drift)
    gap = 3 * CONFIG.max_gap_s
    detector = replay_with_gap(tr, lambda d, s: d.phase is FloorPhase.CHANGING, gap)
    (event,) = detector.events
    assert event.from_id == 0 and event.to_id == 1
    assert abs(event.delta_m - height) < drift * gap / GRADIENT / 10


# -- when a change begins ----------------------------------------------------------------------


def ramp_m(start_s: float, metres: float, m_s: float) -> Callable[[float], float]:
    """Height above the start floor: still, then a move of ``metres`` at ``m_s`` from
    ``start_s``."""

    def height(s: float) -> float:
        return math.copysign(min(abs(metres), m_s * max(0.0, s - start_s)), metres)

    return height


@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["up", "down"])
@pytest.mark.parametrize("where", ["settled", "stopped"])
@pytest.mark.parametrize(
    ("metres", "m_s"),
    [
        # fast and short: the rate passes start_rate_m_s; the level never moves start_m
        (0.8 * CONFIG.start_m, 4 * CONFIG.start_rate_m_s),
        # slow and long: the rate stays below start_rate_m_s; the level moves past start_m
        (2 * CONFIG.start_m, 1.2 * CONFIG.settle_rate_m_s),
    ],
    ids=["on-the-rate", "on-the-level"],
)
def test_a_change_begins_on_the_rate_or_on_the_level_either_way(
    metres: float, m_s: float, where: str, sign: float
) -> None:
    """On a floor and at a stop alike, a change begins as soon as either the Holt rate
    passes start_rate_m_s or the level leaves by start_m, up or down."""
    storey = 2 * CONFIG.min_transition_m
    base = ramp_m(30.0, storey, 1.0) if where == "stopped" else (lambda s: 0.0)
    begin = 30.0 + storey + 5.0  # a few seconds into the stop: not yet a visit
    move = ramp_m(begin, sign * metres, m_s)
    detector = OnlineFloorDetector(CONFIG)
    feed(detector, 0.0, begin, lambda s: P0 - GRADIENT * base(s))
    assert detector.phase is (FloorPhase.STOPPED if where == "stopped" else FloorPhase.SETTLED)
    phases = []
    for k in range(round(20 * RATE_HZ)):
        s = begin + k / RATE_HZ
        detector.update(PressureSample(at(s), P0 - GRADIENT * (base(s) + move(s)), T_C))
        phases.append(detector.phase)
    assert FloorPhase.CHANGING in phases


# -- a car's stop ------------------------------------------------------------------------------


def decided_after_arrival_s(tr: Trace, event: FloorEvent, stay: int) -> float:
    return secs(event.t_ns) - tr.stays_s[stay][0]


@pytest.mark.parametrize("share", [0.5, 1.5])
def test_a_stop_is_decided_as_the_car_stops_only_after_a_ride_a_car_could_make(
    share: float,
) -> None:
    """A car goes from rest to rest at MAX_CAR_ACCEL_M_S2 at most: a step of h metres takes
    2 sqrt(h / that). In ``share`` of that time it is no ride in a car (a spike, a gust),
    and the robot standing still is no visit either, until the input ends."""
    height = 2 * CONFIG.min_transition_m
    fastest_s = 2 * math.sqrt(height / MAX_CAR_ACCEL_M_S2)
    ride_m_s = height / (share * fastest_s)
    tr = trace([Stay(0.0, 60), Stay(height, 60)], ride_m_s=ride_m_s, noise_pa=0.0)
    (event,) = live(tr).events
    if share < 1.0:
        assert event.at_end
    else:
        assert not event.at_end
        assert decided_after_arrival_s(tr, event, 1) < CONFIG.stop_s + 1.0


def test_a_slow_car_is_decided_where_it_stops_not_on_the_way() -> None:
    """A car slower than stop_rate_m_s shows a still-looking window on the way (its
    spread within stop_band_m): the rate tells it is still moving."""
    tr = trace(
        [Stay(0.0, 60), Stay(4 * CONFIG.min_transition_m, 60)],
        ride_m_s=1.25 * CONFIG.stop_rate_m_s,
        noise_pa=0.0,
    )
    detector = live(tr)
    (event,) = detector.events
    assert event.kind is FloorEventKind.TRANSITION and not event.at_end
    assert decided_after_arrival_s(tr, event, 1) < CONFIG.stop_s + 1.0


def test_a_car_that_pauses_short_of_a_storey_rides_one_trip_from_its_first_leg() -> None:
    height = 2 * CONFIG.min_transition_m
    pause = (CONFIG.min_transition_m / 2, CONFIG.landing_s / 3)
    tr = trace([Stay(0.0, 60), Stay(*pause), Stay(height, 60)], noise_pa=0.0)
    (event,) = live(tr).events
    assert not event.at_end and decided_after_arrival_s(tr, event, 2) < CONFIG.stop_s + 1.0
    assert secs(event.t_start_ns) < tr.stays_s[0][1] + 1.0  # dated from the first leg


def test_a_car_going_on_is_corrected_as_it_stops_however_long_it_stood() -> None:
    """The robot never leaves the car: the first stop is decided as the car stops, and each
    leg on (half a minimum storey is enough) corrects it as the car stops again, also after
    a halt longer than landing_s."""
    storey = 2 * CONFIG.min_transition_m
    on = 1.5 * CONFIG.min_transition_m
    stays = [Stay(0.0, 60), Stay(storey, CONFIG.landing_s / 3)]
    stays += [Stay(storey + on, 2 * CONFIG.landing_s), Stay(2 * storey + on, 60)]
    tr = trace(stays, noise_pa=0.0)
    detector = live(tr)
    kinds = [e.kind for e in detector.events]
    assert kinds == [FloorEventKind.TRANSITION] + [FloorEventKind.CORRECTION] * 2
    first, *corrections = detector.events
    assert 0.0 < decided_after_arrival_s(tr, first, 1) < CONFIG.stop_s + 1.0
    for stay, event in enumerate(corrections, start=2):
        # on the stop's short window, not the still test's settle_s and more
        assert 0.0 < decided_after_arrival_s(tr, event, stay) < CONFIG.stop_s
    assert moves(detector.transitions) == [(0, 1)]
    assert detector.transitions[0].delta_m == pytest.approx(2 * storey + on, abs=0.1)


def test_off_stairs_the_visit_is_decided_when_the_robot_has_driven_leave_m() -> None:
    """Moving during the change (stairs, a ramp): no car; the stop becomes a visit when the
    robot has driven leave_m from where it stood when the pressure came to rest."""
    storey = 2 * CONFIG.min_transition_m
    drive_after = 10.0
    stays = [Stay(0.0, 60, drive_m=3.0, drive_after_s=58.0)]
    stays += [Stay(storey, 60, drive_m=3.0, drive_after_s=drive_after)]
    tr = trace(stays, noise_pa=0.0)
    (event,) = live(tr).events
    left = drive_after + CONFIG.leave_m / DRIVE_M_S
    assert decided_after_arrival_s(tr, event, 1) == pytest.approx(left, abs=0.15)


@pytest.mark.parametrize("share", [1.0, 0.99])
def test_a_robot_that_moved_leave_m_during_the_ride_was_not_in_a_car(share: float) -> None:
    """In a car means it moved less than leave_m while the pressure changed: exactly leave_m
    is out of the car (and standing since, it has not driven off: no visit until the end)."""
    storey = 2 * CONFIG.min_transition_m
    tr = trace([Stay(0.0, 60), Stay(storey, 60)], noise_pa=0.0)
    odo_t, _, odo_y = tr.odometry
    moved_from = tr.stays_s[0][1] + 0.5  # half a second into the ride
    odo_x = np.where((odo_t - TRACE_EPOCH_NS) / NS_PER_S > moved_from, share * CONFIG.leave_m, 0.0)
    detector, _, _ = replay(
        tr.t_ns, tr.pressure_pa, tr.temperature_c, CONFIG, odometry=(odo_t, odo_x, odo_y)
    )
    (event,) = detector.events
    assert event.at_end is (share >= 1.0)


@pytest.mark.parametrize("seal_share", [0.5, 1.5], ids=["below-start_m", "above-start_m"])
def test_a_floor_decided_as_the_car_stops_is_measured_again_once_the_doors_open(
    seal_share: float,
) -> None:
    """The car's doors hold the pressure off the floor's for a few seconds after the stop
    (less or more than start_m): the decision sees that level, and the floor's level is
    measured again once the pressure has been still on the floor, with no event."""
    storey = 2 * CONFIG.min_transition_m
    tr = trace([Stay(0.0, 60), Stay(storey, 60)], noise_pa=0.0)
    s = tr.seconds()
    arrived = tr.stays_s[1][0]
    seal = seal_share * CONFIG.start_m * GRADIENT
    p = tr.pressure_pa + np.where((s > arrived - 2.0) & (s < arrived + 3.0), seal, 0.0)
    detector, _, _ = replay(tr.t_ns, p, tr.temperature_c, CONFIG, odometry=tr.odometry)
    (event,) = detector.events
    assert not event.at_end and secs(event.t_ns) < arrived + 3.0  # before the doors opened
    assert event.level_pa == pytest.approx(p[-1] + seal, abs=seal / 2)
    floor = tr.pressure_pa[-1] - tr.pressure_pa[0]
    assert detector.registry.relative_pa(1) == pytest.approx(floor, abs=0.2)
    state = detector.state()
    assert state.phase is FloorPhase.SETTLED and state.floor_id == 1
    assert state.level_m == pytest.approx(state.height_m, abs=0.01)
    assert state.level_pa == pytest.approx(p[-1], abs=0.2)


def test_a_leg_back_from_a_stop_decided_in_the_car_is_its_level_measured_again() -> None:
    """After a ride down decided as the car stops, the pressure comes back up by less than a
    minimum storey (the last of the car's motion), the robot still in the car however long
    it stood: no correction, the floor's level is where it settled, and the ride announced
    on the way is withdrawn, saying why."""
    storey = 2 * CONFIG.min_transition_m
    back = 0.9 * CONFIG.min_transition_m
    stood = CONFIG.landing_s + 5.0
    tr = trace([Stay(0.0, 60), Stay(-storey, stood), Stay(-storey + back, 60)], noise_pa=0.0)
    detector = live(tr)
    (event,) = detector.events
    assert event.kind is FloorEventKind.TRANSITION and moves([event]) == [(0, 1)]
    floor = tr.pressure_pa[-1] - tr.pressure_pa[0]
    # measured on the still window that ended the leg: within its band
    band = CONFIG.settle_rate_m_s * CONFIG.settle_s * GRADIENT
    assert detector.registry.relative_pa(1) == pytest.approx(floor, abs=band)
    state = detector.state()
    assert state.level_m == pytest.approx(-storey + back, abs=0.05)
    kinds = [(r.kind, r.direction) for r in detector.rides]
    assert kinds == [
        (RideEventKind.STARTED, RideDirection.DOWN),
        (RideEventKind.ENDED, RideDirection.DOWN),
        (RideEventKind.STARTED, RideDirection.UP),
        (RideEventKind.RETRACTED, RideDirection.UP),
    ]
    assert detector.rides[-1].reason == "the pressure settled on the floor just decided: no ride"


def test_the_weather_moves_a_stop_that_waits_for_the_robot_to_drive_off() -> None:
    """Off stairs with the robot standing, the stop waits for it to drive off: meanwhile the
    stop's level follows the weather as a floor's does, and the stop goes on, decided only
    when the input ends."""
    storey = 2 * CONFIG.min_transition_m
    # long enough on the start floor for the drift tracker to learn the weather
    stays = [Stay(0.0, 400, drive_m=3.0, drive_after_s=398.0), Stay(storey, 600)]
    drift = MAX_WEATHER_RATE_PA_S / 2  # over the stop, far more than start_m
    tr = trace(stays, noise_pa=0.0, drift_pa_s=drift)
    assert drift * 600 > 3 * CONFIG.start_m * GRADIENT
    detector = live(tr)
    (event,) = detector.events
    assert event.at_end and moves([event]) == [(0, 1)]
    assert event.delta_m == pytest.approx(storey, abs=0.1)
    assert secs(detector.rides[0].t_ns) < tr.stays_s[1][0]  # one ride, announced on the stairs


def test_a_ride_that_turns_the_other_way_is_withdrawn_and_the_other_announced() -> None:
    """A gust up and down of more than ride_m each way, back on the floor: two rides
    announced, each withdrawn with its reason, no floor event."""
    swing = 2.4 * CONFIG.ride_m
    tr = trace([Stay(0.0, 60), Stay(swing, 0.5), Stay(-swing, 0.5), Stay(0.0, 60)], noise_pa=0.0)
    detector = live(tr)
    assert detector.events == []
    rides = [(r.kind, r.direction, r.reason) for r in detector.rides]
    turned = "the pressure turned the other way: a transient, not the car"
    assert rides == [
        (RideEventKind.STARTED, RideDirection.UP, ""),
        (RideEventKind.RETRACTED, RideDirection.UP, turned),
        (RideEventKind.STARTED, RideDirection.DOWN, ""),
        (RideEventKind.RETRACTED, RideDirection.DOWN, "came to rest 0.0 m from floor 0: no ride"),
    ]


# -- where a trip began -------------------------------------------------------------------------

RAMP_M = (CONFIG.start_m + CONFIG.min_transition_m) / 4  # more than start_m, two less than a storey


@pytest.mark.parametrize(
    ("heights", "first_leg"),
    [
        # two ramps up, each a short stop (a landing), then a storey up: from the first
        ([RAMP_M, 2 * RAMP_M, 2 * RAMP_M + 2 * CONFIG.min_transition_m], 0),
        # a ramp up, back down past the floor, then a storey down: from the turn
        ([RAMP_M, -RAMP_M, -RAMP_M - 2 * CONFIG.min_transition_m], 1),
        # a ramp up, then a storey down: the ramp was no part of the trip
        ([RAMP_M, RAMP_M - 2 * CONFIG.min_transition_m], 1),
    ],
    ids=["on-the-same-way", "turned-back", "the-other-way"],
)
def test_a_trip_is_dated_from_its_first_leg_in_its_direction(
    heights: list[float], first_leg: int
) -> None:
    """Legs shorter than a storey that stop for less than landing_s are landings of one
    trip when they go the trip's way; a leg the other way starts the trip afresh."""
    pause = CONFIG.landing_s / 3
    stays = [Stay(0.0, 60)] + [Stay(h, pause) for h in heights[:-1]] + [Stay(heights[-1], 60)]
    tr = trace(stays, noise_pa=0.0)
    (event,) = live(tr, odometry=False).events
    assert event.delta_m == pytest.approx(heights[-1], abs=0.1)
    left = tr.stays_s[first_leg][1]  # the leg began as this stay ended
    assert left - 0.5 < secs(event.t_start_ns) < left + 1.0


# -- stops and floors ---------------------------------------------------------------------------


def test_a_move_of_less_than_half_a_storey_from_a_stop_is_no_leg_of_the_trip() -> None:
    """Without odometry, a stop is a visit once it lasted min_visit_s: a move back toward
    the floor left by less than half a minimum storey (the doors' seal, a spike's tail) is
    no leg, and the stop goes on from when it began."""
    storey = 2 * CONFIG.min_transition_m
    back = 0.4 * CONFIG.min_transition_m  # more than start_m: a change begins
    assert back > CONFIG.start_m
    tr = trace([Stay(0.0, 60), Stay(storey, 5), Stay(storey - back, 60)], noise_pa=0.0)
    detector = OnlineFloorDetector(CONFIG)
    since = None
    stops = set()
    for ti, pi in zip(tr.t_ns.tolist(), tr.pressure_pa.tolist(), strict=True):
        detector.update(PressureSample(ti, pi, T_C))
        if detector.phase is FloorPhase.STOPPED and not detector.events:
            stops.add(detector.state().since_ns)
            since = since or detector.state().since_ns
    detector.finish()
    (event,) = detector.events
    assert stops == {since}  # the same stop before and after the move
    assert event.t_ns - event.t_end_ns == round(CONFIG.min_visit_s * NS_PER_S)
    assert event.t_end_ns < at(tr.stays_s[1][1])  # it came to rest before the move
    assert event.delta_m == pytest.approx(storey - back, abs=0.1)


def test_a_floor_within_a_minimum_storey_of_a_known_one_is_that_floor() -> None:
    storey = 2 * CONFIG.min_transition_m
    off = 0.8 * CONFIG.min_transition_m
    stays = [Stay(0.0, 60), Stay(storey, 60), Stay(0.0, 60), Stay(storey + off, 60)]
    detector = live(trace(stays, noise_pa=0.0), odometry=False)
    assert moves(detector.events) == [(0, 1), (1, 0), (0, 1)]


def test_a_floor_more_than_half_a_minimum_storey_off_the_building_model_is_counted() -> None:
    """A model floor names a floor found within half a minimum storey of it; further off,
    the name is counted (an estimate), and the ride's end says so as the event does."""
    storey = 2 * CONFIG.min_transition_m
    model = BuildingModel((ModelFloor("0", 0.0), ModelFloor("1", storey)))
    config = FloorDetectorConfig(building=model)
    for off, name, estimated in [(0.25, "1", False), (0.75, "2", True)]:
        height = storey + off * CONFIG.min_transition_m
        detector = live(trace([Stay(0.0, 60), Stay(height, 60)], noise_pa=0.0), config)
        (event,) = detector.events
        assert (event.to_name, event.estimated_name) == (name, estimated)
        ended = detector.rides[-1]
        assert ended.kind is RideEventKind.ENDED
        assert (ended.to_name, ended.estimated_name) == (name, estimated)


def test_a_stop_carries_the_weather_over_a_gap() -> None:
    """A gap during a stop: when the pressure comes to rest again within half a minimum
    storey of where the weather has taken the stop (here the robot moved a third of a
    storey back toward the floor it left, less than the weather over the gap and that
    together), it is the same stop, decided at the level it came to."""
    storey = 2 * CONFIG.min_transition_m
    drift = MAX_WEATHER_RATE_PA_S / 2
    gap = 6 * CONFIG.max_gap_s
    back = 0.35 * CONFIG.min_transition_m
    assert back * GRADIENT + drift * gap > pressure_drop_pa(CONFIG.min_transition_m, P0, T_C) / 2
    stays = [Stay(0.0, 400), Stay(storey, 5 + gap / 2), Stay(storey - back, 60)]
    tr = trace(stays, noise_pa=0.0, drift_pa_s=drift)
    stopped = tr.stays_s[1][0]
    detector = replay_with_gap(tr, lambda d, s: s >= stopped + 5.0, gap)
    (event,) = detector.events
    assert event.delta_m == pytest.approx(storey - back, abs=0.1)


def test_a_ramp_slower_than_the_settle_rate_announces_no_ride() -> None:
    """Rides are announced on a pressure moving faster than settle_rate_m_s: a ramp at half
    that, climbing most of a minimum storey, never is one."""
    tr = trace(
        [Stay(0.0, 60), Stay(0.8 * CONFIG.min_transition_m, 60)],
        ride_m_s=CONFIG.settle_rate_m_s / 2,
        noise_pa=0.0,
    )
    detector = live(tr)
    assert detector.phase is FloorPhase.SETTLED and detector.floor_id == 0
    assert detector.rides == [] and detector.events == []


def test_a_car_ride_inside_a_gap_is_decided_on_a_whole_short_window_after_it() -> None:
    """The robot stood in the car while the samples stopped: the stop is decided as a car's,
    once the samples after the gap span stop_s, dated from the last sample before it."""
    storey = 2 * CONFIG.min_transition_m
    tr = trace([Stay(0.0, 60), Stay(storey, 60)], noise_pa=0.0)
    s = tr.seconds()
    keep = (s < 55.0) | (s > 70.0)
    t, p = tr.t_ns[keep], tr.pressure_pa[keep]
    detector, _, _ = replay(t, p, tr.temperature_c[keep], CONFIG, odometry=tr.odometry)
    (event,) = detector.events
    before, after = (int(x) for x in t[np.flatnonzero(np.diff(t) > NS_PER_S)[0] + np.arange(2)])
    assert event.t_start_ns == before and not event.at_end
    assert event.t_ns - after == round(CONFIG.stop_s * NS_PER_S)


# -- a floor decided as the car stops, until landing_s after ---------------------------------

#: The samples' spacing, ns.
STEP_NS = round(NS_PER_S / RATE_HZ)


def feed_in_car(
    detector: OnlineFloorDetector, stamps: list[int], pressure: Callable[[int], float]
) -> list[FloorEvent | RideEvent]:
    """A robot standing still (its odometry at each stamp, then its pressure sample there);
    returns the events published meanwhile."""
    out: list[FloorEvent | RideEvent] = []
    for t in stamps:
        detector.update_odometry(Odometry(t, 0.0, 0.0, 0.0))
        out += detector.update(PressureSample(t, pressure(t), T_C))
    return out


def decided_in_the_car() -> tuple[OnlineFloorDetector, int, float]:
    """A ride two minimum storeys up in the car, decided as it stops: the detector fed up
    to that decision, the end of the time its floor's level is measured again
    (``landing_s`` after it), and the floor's pressure."""
    storey = 2 * CONFIG.min_transition_m
    height = ramp_m(60.0, storey, 1.0)
    detector = OnlineFloorDetector(CONFIG)
    for k in range(round(120 * RATE_HZ)):
        t = at(0.0) + k * STEP_NS
        published = feed_in_car(detector, [t], lambda t: P0 - GRADIENT * height(secs(t)))
        if any(isinstance(e, FloorEvent) for e in published):
            (event,) = detector.events
            assert not event.at_end
            return detector, t + round(CONFIG.landing_s * NS_PER_S), P0 + storeys_pa(2.0)
    raise AssertionError("the car's stop was not decided")


def stepped(before_pa: float, at_ns: int, step_pa: float) -> Callable[[int], float]:
    """A pressure of ``before_pa`` that steps by ``step_pa`` at ``at_ns``."""
    return lambda t: before_pa + (step_pa if t >= at_ns else 0.0)


def stamps_around(until: int, first: int, last: int) -> list[int]:
    """Sample stamps ``until + j * STEP_NS`` for j in [first, last]."""
    return [until + j * STEP_NS for j in range(first, last + 1)]


@pytest.mark.parametrize("late", [0, 1], ids=["at-landing_s", "one-sample-after"])
def test_a_move_short_of_a_storey_until_landing_s_after_a_cars_stop_is_its_level(
    late: int,
) -> None:
    """A change that settles less than half a minimum storey away up to and including
    ``landing_s`` after a floor was decided as the car stopped is that floor's level measured
    again (the doors' seal, the sensor's lag); one sample later it is a move on the floor (a
    ramp, a landing), kept as an offset from its level."""
    detector, until, floor_p = decided_in_the_car()
    jump_m = 1.5 * CONFIG.start_m  # a change begins, and it is no leg of a trip
    assert jump_m < CONFIG.min_transition_m / 2
    first = -((until - detector.events[0].t_ns) // STEP_NS) + 1
    # the jump from which the change settles exactly ``late`` samples after ``until``
    for jump in range(-1, first, -1):
        trial = copy.deepcopy(detector)
        feed_in_car(
            trial,
            stamps_around(until, first, late + 10),
            stepped(floor_p, until + jump * STEP_NS, jump_m * GRADIENT),
        )
        state = trial.state()
        if state.phase is FloorPhase.SETTLED and state.since_ns == until + late * STEP_NS:
            break
    else:
        raise AssertionError("no jump settles at that sample")
    assert [e.kind for e in trial.events] == [FloorEventKind.TRANSITION]
    floor = storeys_pa(2.0)  # the floor's level, measured again once the car stood still
    if late == 0:
        assert state.level_m == pytest.approx(state.height_m, abs=0.01)
        assert trial.registry.relative_pa(1) == pytest.approx(floor + jump_m * GRADIENT, abs=0.2)
    else:
        assert state.level_m == pytest.approx(state.height_m - jump_m, abs=0.05)
        assert trial.registry.relative_pa(1) == pytest.approx(floor, abs=0.1)


def test_rides_are_held_to_the_stop_band_until_landing_s_after_a_cars_stop() -> None:
    """Until ``landing_s`` after a floor was decided as the car stopped (that instant
    included), a ride is announced only beyond ``ride_m + stop_band_m``; after it, beyond
    ``ride_m``."""
    detector, until, floor_p = decided_in_the_car()
    # a ramp down at half a metre per second reaching ride_m + stop_band_m / 2 at ``until``
    speed = 0.5
    top_m = CONFIG.ride_m + CONFIG.stop_band_m / 2
    begin = until - round(top_m / speed * NS_PER_S)

    def pressure(t: int) -> float:
        return floor_p + GRADIENT * speed * max(0.0, (t - begin) / NS_PER_S)

    first = -((until - detector.events[0].t_ns) // STEP_NS) + 1
    assert feed_in_car(detector, stamps_around(until, first, 0), pressure) == []
    state = detector.state()
    assert state.phase is FloorPhase.CHANGING
    # beyond ride_m already: only the band held it back
    assert CONFIG.ride_m < state.height_m - state.level_m < CONFIG.ride_m + CONFIG.stop_band_m
    (started,) = feed_in_car(detector, [until + STEP_NS], pressure)
    assert isinstance(started, RideEvent) and started.kind is RideEventKind.STARTED
    assert started.direction is RideDirection.DOWN


def test_while_its_level_is_measured_again_a_moving_pressure_is_no_measurement() -> None:
    """After a car's stop, the floor's level is taken again only from settle_s of samples
    that were still on both counts (their smoothed pressure in the band, their slope below
    settle_rate_m_s): a step of the raw pressure, its slope steep while the smoothed
    pressure has hardly moved, leaves the level where the step's first sample took it
    (its window still looked still) until settle_s after the step."""
    detector, until, floor_p = decided_in_the_car()
    step_at = until - round(CONFIG.landing_s / 2 * NS_PER_S)
    step_pa = 0.5 * CONFIG.start_m * GRADIENT  # neither its level nor its rate starts a change
    pressure = stepped(floor_p, step_at, step_pa)

    first = -((until - detector.events[0].t_ns) // STEP_NS) + 1
    stamps = stamps_around(until, first, 0)
    feed_in_car(detector, [t for t in stamps if t < step_at], pressure)
    measured = detector.registry.relative_pa(1)
    assert measured == pytest.approx(storeys_pa(2.0), abs=0.1)
    # what the smoothed pressure moves on the step's first sample
    dt = STEP_NS / NS_PER_S
    first_share = step_pa * dt / (CONFIG.level_tau_s + dt)
    settled_at = step_at + round(CONFIG.settle_s * NS_PER_S)
    for t in (t for t in stamps if t >= step_at):
        feed_in_car(detector, [t], pressure)
        assert detector.phase is FloorPhase.SETTLED
        if t < settled_at:
            assert abs(detector.registry.relative_pa(1) - measured) <= first_share + 1e-6
    assert detector.registry.relative_pa(1) == pytest.approx(measured + step_pa, abs=0.2)


def test_a_new_detector_has_no_pressure_level_until_a_usable_sample() -> None:
    detector = OnlineFloorDetector(CONFIG)
    detector.update(PressureSample(at(0.0), math.nan, T_C))
    assert math.isnan(detector.level) and math.isnan(detector.smoothed)
    assert detector.rate == 0.0


def test_a_stop_left_on_the_sample_it_resumed_goes_on_as_one_trip() -> None:
    """The base's odometry stopped arriving before the ride (the detector goes on on the
    pressure alone). A move back of less than half a minimum storey from a stop is no leg:
    the stop resumes; a jump a storey on at the very next sample begins a change from that
    moment, and the trip goes on from its first leg, a visit min_visit_s after it came to
    rest."""
    storey = 2 * CONFIG.min_transition_m
    back = 0.4 * CONFIG.min_transition_m
    stays = [Stay(0.0, 60), Stay(storey, 5), Stay(storey - back, 60)]
    tr = trace(stays, noise_pa=0.0)
    p = tr.pressure_pa.copy()
    detector = OnlineFloorDetector(CONFIG)
    for k in range(round(30 * RATE_HZ)):  # odometry for the first half minute only
        detector.update_odometry(Odometry(at(k / RATE_HZ), 0.0, 0.0, 0.0))
    phases = [detector.phase]
    jumped_at = None
    for i, t in enumerate(tr.t_ns.tolist()):
        detector.update(PressureSample(t, float(p[i]), T_C))
        if detector.phase is not phases[-1]:
            phases.append(detector.phase)
            if phases[1:] == [FloorPhase.SETTLED] + [FloorPhase.CHANGING, FloorPhase.STOPPED] * 2:
                assert detector.events == []  # the stop resumed, not yet a visit
                p[i + 1 :] += storeys_pa(2.0)  # a storey up at the next sample
                jumped_at = tr.t_ns[i + 1]
        if jumped_at == t:
            assert detector.phase is FloorPhase.CHANGING
    assert jumped_at is not None
    (event,) = detector.events
    assert not event.at_end and moves([event]) == [(0, 1)]
    assert event.delta_m == pytest.approx(2 * storey - back, abs=0.1)
    assert event.t_ns - event.t_end_ns == round(CONFIG.min_visit_s * NS_PER_S)
    left = tr.stays_s[0][1]  # the trip's first leg began as the start floor's stay ended
    assert left - 0.5 < secs(event.t_start_ns) < left + 1.0


def test_a_new_floor_the_car_goes_on_from_to_within_a_storey_of_a_known_one_is_merged() -> None:
    """A floor decided as the car stopped, new (more than a minimum storey from every known
    floor), then the car going on by less than a minimum storey to a level nearer a known
    floor: the trip ended at that floor, so the new one was a landing and is merged into it
    (two floors closer than min_transition_m cannot both exist), by a correction."""
    m = CONFIG.min_transition_m
    known, decided, ended = 2.5 * m, 1.2 * m, 2.0 * m
    assert abs(decided - known) >= m and abs(ended - decided) < m
    assert abs(ended - known) < abs(ended - decided)  # nearer the known floor
    assert ended - decided > m / 2  # a leg of the trip
    stays = [Stay(0.0, 60), Stay(known, 60, drive_m=3.0, drive_after_s=20.0)]
    stays += [Stay(0.0, 60, drive_m=3.0, drive_after_s=20.0), Stay(decided, 5), Stay(ended, 60)]
    detector = live(trace(stays, noise_pa=0.0))
    kinds = [e.kind for e in detector.events]
    assert kinds == [FloorEventKind.TRANSITION] * 3 + [FloorEventKind.CORRECTION]
    assert moves(detector.events) == [(0, 1), (1, 0), (0, 2), (0, 1)]
    assert moves(detector.transitions) == [(0, 1), (1, 0), (0, 1)]
    assert detector.registry.known == 2 and detector.floor_id == 1
