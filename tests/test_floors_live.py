"""The live floor contract: stops that are no visits, corrections, stable ids and names.

Each failure class of the live-decisions issue is reproduced on a trace built for it
(:mod:`baromap.evaluation.floor_traces`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from baromap.errors import ConfigError, InputFormatError
from baromap.evaluation.floor_traces import TRACE_EPOCH_NS, Stay, Trace, trace
from baromap.floors import (
    FloorDetectorConfig,
    OnlineFloorDetector,
    apply_corrections,
    detect_floors,
    load_building_model,
)
from baromap.floors.building_model import BuildingModel, ModelFloor
from baromap.messages import (
    NS_PER_S,
    FloorEvent,
    FloorEventKind,
    FloorPhase,
    Odometry,
    RideDirection,
    RideEventKind,
)
from baromap.messages import PressureSample as Sample

STOREY_M = 3.2


def live(
    tr: Trace, config: FloorDetectorConfig | None = None, *, odometry: bool = True
) -> OnlineFloorDetector:
    return tr.detected(config, odometry=odometry)


def secs(t_ns: int) -> float:
    return (t_ns - TRACE_EPOCH_NS) / NS_PER_S


def moves(events: list[FloorEvent] | tuple[FloorEvent, ...]) -> list[tuple[int, int]]:
    return [(e.from_id, e.to_id) for e in events]


# -- 1. a trip that pauses and continues ends near a known floor: no new floor -----------


def landing_near_a_known_floor(pause_s: float) -> Trace:
    """Up two storeys and back, then up again with a pause at one storey (a floor never
    visited), ending 0.4 m above the known floor: the level is that floor's, a little off."""
    return trace(
        [
            Stay(0.0, 60),
            Stay(2 * STOREY_M, 60, drive_m=3.0),
            Stay(0.0, 60, drive_m=3.0),
            Stay(STOREY_M, pause_s),
            Stay(2 * STOREY_M + 0.4, 60, drive_m=3.0),
        ]
    )


def test_a_landing_that_ends_near_a_known_floor_is_that_floor() -> None:
    detector = live(landing_near_a_known_floor(5.0), odometry=False)
    assert moves(detector.events) == [(0, 1), (1, 0), (0, 1)]
    assert all(e.kind is FloorEventKind.TRANSITION for e in detector.events)
    assert detector.registry.known == 2


def test_a_visit_decided_on_a_landing_is_corrected_and_merged() -> None:
    # A walker-like setting: visits after 3 s. The pause at one storey (5 s) is then taken for
    # a visit to a new floor, until the trip goes on to the known floor: a correction replaces
    # the event, and the floor that was a landing is merged into the known one.
    config = FloorDetectorConfig(min_visit_s=3.0)
    detector = live(landing_near_a_known_floor(5.0), config, odometry=False)
    kinds = [e.kind for e in detector.events]
    assert kinds == [FloorEventKind.TRANSITION] * 3 + [FloorEventKind.CORRECTION]
    landing, correction = detector.events[2], detector.events[3]
    assert landing.to_id == 2 and landing.height_m == pytest.approx(STOREY_M, abs=0.15)
    assert correction.replaces == landing.event_id
    assert (correction.from_id, correction.to_id) == (0, 1)
    assert correction.t_start_ns == landing.t_start_ns
    assert correction.t_end_ns > landing.t_end_ns
    assert moves(detector.transitions) == [(0, 1), (1, 0), (0, 1)]
    assert detector.registry.known == 2 and detector.registry.resolve(2) == 1
    assert apply_corrections(detector.events) == list(detector.transitions)
    state = detector.state()
    assert state.floor_id == 1 and state.floors_known == 2


def test_a_landing_visit_on_a_new_floor_moves_to_where_the_trip_ended() -> None:
    config = FloorDetectorConfig(min_visit_s=3.0)
    tr = trace([Stay(0.0, 60), Stay(2.2, 5.0), Stay(3.5, 60, drive_m=3.0)])
    detector = live(tr, config, odometry=False)
    assert [e.kind for e in detector.events] == [
        FloorEventKind.TRANSITION,
        FloorEventKind.CORRECTION,
    ]
    (final,) = detector.transitions
    assert (final.from_id, final.to_id) == (0, 1)
    assert final.height_m == pytest.approx(3.5, abs=0.15)
    assert detector.registry.height_m(1) == pytest.approx(3.5, abs=0.15)


# -- 2. a stop at a passing floor: part of the ride unless the robot drives off ----------


def intermediate_stop(stop_s: float, drive_m: float) -> Trace:
    return trace(
        [
            Stay(0.0, 60),
            Stay(STOREY_M, stop_s, drive_m=drive_m, drive_after_s=0.5),
            Stay(2 * STOREY_M, 60, drive_m=3.0),
        ]
    )


@pytest.mark.parametrize("odometry", [True, False])
def test_a_5_s_stop_in_the_car_is_part_of_the_ride(odometry: bool) -> None:
    tr = intermediate_stop(5.0, drive_m=0.0)
    detector = live(tr, odometry=odometry)
    (event,) = detector.transitions
    assert (event.from_id, event.to_id) == (0, 1)
    assert event.delta_m == pytest.approx(2 * STOREY_M, abs=0.15)
    assert secs(event.t_start_ns) < 60.5  # the trip began with the first leg
    kinds = [e.kind for e in detector.events]
    if odometry:
        # decided as the car stopped at the passing floor, corrected when it went on
        assert kinds == [FloorEventKind.TRANSITION, FloorEventKind.CORRECTION]
        halt, _ = tr.stays_s[1]
        assert secs(detector.events[0].t_ns) - halt < 2.0
        assert detector.registry.known == 2  # the passing floor was no floor of the run
    else:
        assert kinds == [FloorEventKind.TRANSITION]


def test_a_5_s_stop_where_the_robot_drives_off_is_a_visit() -> None:
    tr = intermediate_stop(5.0, drive_m=1.5)
    detector = live(tr)
    assert moves(detector.events) == [(0, 1), (1, 2)]
    first = detector.events[0]
    assert first.height_m == pytest.approx(STOREY_M, abs=0.15)
    # decided when it had driven a metre (0.5 s into the stop, 0.5 m/s), not later
    stop_start, _ = tr.stays_s[1]
    assert secs(first.t_ns) - stop_start < 0.5 + 1.0 / 0.5 + 1.0


def test_a_long_stop_without_moving_stays_in_the_car_with_odometry() -> None:
    tr = intermediate_stop(40.0, drive_m=0.0)
    detector = live(tr)
    assert moves(detector.transitions) == [(0, 1)]
    assert detector.transitions[0].delta_m == pytest.approx(2 * STOREY_M, abs=0.15)
    # Without odometry, 40 s at a storey is a visit.
    assert moves(live(tr, odometry=False).events) == [(0, 1), (1, 2)]


def _a_halt_at_a_known_floor() -> Trace:
    """Floors 0, 1, 0, then up to 2 with an 8 s halt at floor 1 on the way."""
    return trace(
        [
            Stay(0.0, 60),
            Stay(STOREY_M, 60, drive_m=3.0),
            Stay(0.0, 60, drive_m=3.0),
            Stay(STOREY_M, 8.0),
            Stay(2 * STOREY_M, 60, drive_m=3.0),
        ]
    )


def test_while_stopped_the_state_says_so() -> None:
    # Floor 1 is known from a first visit; on the way up again the car stops there. Without
    # odometry nothing says the robot stays in: the stop is not yet a visit.
    tr = _a_halt_at_a_known_floor()
    stop_start = tr.stays_s[3][0]
    detector = OnlineFloorDetector()
    seen = None
    for ti, pi in zip(tr.t_ns.tolist(), tr.pressure_pa.tolist(), strict=True):
        detector.update(Sample(ti, pi, 15.0))
        if seen is None and secs(ti) > stop_start + 4.0:
            seen = detector.state()
    assert seen is not None and seen.phase is FloorPhase.STOPPED
    assert (seen.floor_id, seen.name) == (0, "0")  # still where the ride began
    assert (seen.stop_floor_id, seen.stop_name) == (1, "1")
    assert seen.level_m == pytest.approx(STOREY_M, abs=0.15)
    assert moves(detector.transitions) == [(0, 1), (1, 0), (0, 2)]


def test_a_halt_with_the_robot_in_the_car_is_decided_at_once_and_corrected() -> None:
    # The same ride with odometry (the robot stands in the car all along): the halt at the
    # known floor is decided as the car stops there, and corrected when the car goes on.
    tr = _a_halt_at_a_known_floor()
    detector = OnlineFloorDetector()
    odo_t, odo_x, odo_y = tr.odometry
    o = 0
    during_halt = None
    halt_start, _ = tr.stays_s[3]
    for ti, pi in zip(tr.t_ns.tolist(), tr.pressure_pa.tolist(), strict=True):
        while o < odo_t.size and odo_t[o] <= ti:
            detector.update_odometry(Odometry(int(odo_t[o]), float(odo_x[o]), float(odo_y[o]), 0))
            o += 1
        detector.update(Sample(ti, pi, 15.0))
        if during_halt is None and secs(ti) > halt_start + 4.0:
            during_halt = detector.state()
    assert during_halt is not None and during_halt.phase is FloorPhase.SETTLED
    assert (during_halt.floor_id, during_halt.name) == (1, "1")
    halt, correction = detector.events[2:]
    assert (halt.kind, halt.to_id) == (FloorEventKind.TRANSITION, 1)
    assert secs(halt.t_ns) - halt_start < 2.0
    assert (correction.kind, correction.replaces) == (FloorEventKind.CORRECTION, halt.event_id)
    assert (correction.from_id, correction.to_id) == (0, 2)
    assert moves(detector.transitions) == [(0, 1), (1, 0), (0, 2)]


def test_the_doors_of_a_halted_car_are_no_turn_back() -> None:
    # Halted at a passing floor on the way up, the doors' seal and a draught leave the
    # pressure 6.5 Pa (0.55 m) higher for the rest of the stop: no leg back, no visit.
    tr = intermediate_stop(10.0, drive_m=0.0)
    start, end = tr.stays_s[1]
    s = tr.seconds()
    doors = (s > start + 3.0) & (s < end)
    shifted = Trace(tr.t_ns, tr.pressure_pa + 6.5 * doors, tr.temperature_c, tr.odometry, ())
    detector = live(shifted, odometry=False)
    assert moves(detector.events) == [(0, 1)]
    assert detector.events[0].height_m == pytest.approx(2 * STOREY_M, abs=0.15)


def test_a_visit_on_a_sloping_floor_counts_from_when_the_trip_came_to_rest() -> None:
    # Without odometry: down a storey, 8 s there, 1.2 m further down a slope on the same
    # floor, 12 s there, then on down: 20 s at that floor is a visit, though no single rest
    # lasted min_visit_s.
    tr = trace(
        [
            Stay(0.0, 60),
            Stay(-STOREY_M, 8.0),
            Stay(-STOREY_M - 1.2, 12.0),
            Stay(-2 * STOREY_M - 1.2, 60),
        ]
    )
    detector = live(tr, odometry=False)
    assert moves(detector.events) == [(0, 1), (1, 2)]
    first_rest = tr.stays_s[1][0]
    decided = secs(detector.events[0].t_ns)
    assert decided - first_rest < FloorDetectorConfig().min_visit_s + 2.0
    assert detector.events[0].height_m == pytest.approx(-STOREY_M - 1.2, abs=0.15)


def test_a_stop_followed_by_a_turn_back_is_a_visit() -> None:
    # Without odometry: down a storey for 8 s (shorter than min_visit_s) and back up.
    tr = trace([Stay(0.0, 60), Stay(-STOREY_M, 8.0), Stay(0.0, 60)])
    detector = live(tr, odometry=False)
    assert moves(detector.events) == [(0, 1), (1, 0)]
    # With odometry and the robot never leaving the car, it was one ride there and back:
    # decided as the car stopped, withdrawn when it came back.
    detector = live(tr)
    assert [e.kind for e in detector.events] == [
        FloorEventKind.TRANSITION,
        FloorEventKind.RETRACTION,
    ]
    assert detector.events[1].replaces == detector.events[0].event_id
    assert detector.transitions == () and apply_corrections(detector.events) == []
    assert detector.registry.known == 1 and detector.state().floor_id == 0


# -- 3. what was published is what a replay gives ------------------------------------------


def test_a_replay_gives_the_same_events_corrections_included() -> None:
    config = FloorDetectorConfig(min_visit_s=3.0)
    tr = landing_near_a_known_floor(5.0)
    first = live(tr, config, odometry=False)
    again = live(tr, config, odometry=False)
    assert any(e.kind is FloorEventKind.CORRECTION for e in first.events)
    assert again.events == first.events
    # Post-run, the run is cut by the same transitions, corrections applied.
    detection = detect_floors(tr.t_ns, tr.pressure_pa, tr.temperature_c, config=config)
    assert detection.events == tuple(first.events)
    rank = {1: 1, 0: 0}  # floor 1 (3.2 m) above the start floor
    assert [(x.from_floor, x.to_floor) for x in detection.transitions] == [
        (rank[a], rank[b]) for a, b in moves(apply_corrections(first.events))
    ]
    assert [x.t_detect_ns for x in detection.transitions] == [
        e.t_ns for e in apply_corrections(first.events)
    ]


def test_event_ids_are_unique_and_increasing() -> None:
    config = FloorDetectorConfig(min_visit_s=3.0)
    events = live(landing_near_a_known_floor(5.0), config, odometry=False).events
    ids = [e.event_id for e in events]
    assert ids == sorted(set(ids)) and ids[0] == 1


def test_a_correction_of_an_unknown_event_is_refused() -> None:
    tr = intermediate_stop(40.0, drive_m=0.0)
    event = live(tr).events[0]
    orphan = FloorEvent(**{**_fields(event), "kind": FloorEventKind.CORRECTION, "replaces": 99})
    with pytest.raises(InputFormatError):
        apply_corrections([event, orphan])


def _fields(event: FloorEvent) -> dict[str, object]:
    return {name: getattr(event, name) for name in event.__dataclass_fields__}


# -- 4. stable ids and names ---------------------------------------------------------------


def test_ids_never_renumber_and_names_count_from_the_start_floor() -> None:
    # The paper starts on floor 5: up one, down two (a floor below the start turns up).
    tr = trace(
        [
            Stay(0.0, 60),
            Stay(STOREY_M, 60, drive_m=3.0),
            Stay(0.0, 60, drive_m=3.0),
            Stay(-STOREY_M, 60, drive_m=3.0),
            Stay(STOREY_M, 60, drive_m=3.0),
        ]
    )
    detector = live(tr, FloorDetectorConfig(start_floor="5"))
    assert moves(detector.events) == [(0, 1), (1, 0), (0, 2), (2, 1)]
    assert [(e.from_name, e.to_name) for e in detector.events] == [
        ("5", "6"),
        ("6", "5"),
        ("5", "4"),
        ("4", "6"),
    ]
    assert [round(e.height_m, 1) for e in detector.events] == pytest.approx(
        [STOREY_M, 0.0, -STOREY_M, STOREY_M], abs=0.15
    )


def test_names_come_from_a_building_model_by_relative_height(tmp_path: Path) -> None:
    path = tmp_path / "building.yaml"
    path.write_text(
        "floors:\n"
        "  - {index: 0, elevation_m: 0.0, name: B}\n"
        "  - {index: 1, elevation_m: 5.4, name: G}\n"
        "  - {index: 2, elevation_m: 9.1}\n"
        "  - {index: 3, elevation_m: 12.6, name: roof}\n"
    )
    model = load_building_model(path)
    assert [f.name for f in model.floors] == ["B", "G", "2", "roof"]
    config = FloorDetectorConfig(start_floor="G", building=model)
    # From G: up 3.5 m (model: 3.7 m to "2"), up 3.5 m more ("roof"), down to B (-5.4 m).
    tr = trace(
        [
            Stay(0.0, 60),
            Stay(3.5, 60, drive_m=3.0),
            Stay(7.0, 60, drive_m=3.0),
            Stay(-5.4, 60, drive_m=3.0),
        ]
    )
    events = live(tr, config).events
    assert [(e.from_name, e.to_name) for e in events] == [("G", "2"), ("2", "roof"), ("roof", "B")]


def test_a_floor_the_model_does_not_know_gets_a_counted_name() -> None:
    model = BuildingModel((ModelFloor("G", 0.0), ModelFloor("1", 4.0)))
    config = FloorDetectorConfig(start_floor="G", building=model)
    tr = trace([Stay(0.0, 60), Stay(-3.4, 60, drive_m=3.0)])
    (event,) = live(tr, config).events
    assert event.to_name == "G-1"


def test_consecutive_floors_get_consecutive_names_past_a_tall_lobby() -> None:
    # A 5.4 m ground storey under 3.4 m ones, started on the first floor: the lobby is one
    # storey down (1.6 storeys of 3.4 m), and the floor above it the next name.
    tr = trace(
        [
            Stay(0.0, 60),
            Stay(3.4, 60, drive_m=3.0),
            Stay(-5.4, 60, drive_m=3.0),
            Stay(6.8, 60, drive_m=3.0),
        ]
    )
    detector = live(tr, FloorDetectorConfig(start_floor="1"))
    assert [e.to_name for e in detector.events] == ["2", "0", "3"]
    assert [e.estimated_name for e in detector.events] == [True, True, True]
    # counted in the 3.4 m storey the first ride showed, not the nominal 3.5 m
    assert detector.registry.name(0) == "1" and not detector.registry.estimated(0)


def test_two_storeys_at_once_leave_a_name_for_the_floor_between() -> None:
    tr = trace([Stay(0.0, 60), Stay(2 * STOREY_M, 60, drive_m=3.0), Stay(STOREY_M, 60)])
    detector = live(tr)
    assert [e.to_name for e in detector.transitions] == ["2", "1"]


def test_a_configured_storey_height_names_tall_storeys_one_by_one() -> None:
    # 6 m storeys: counted in the nominal 3.5 m they would be two apart each.
    tr = trace([Stay(0.0, 60), Stay(6.0, 60, drive_m=3.0), Stay(12.2, 60, drive_m=3.0)])
    assert [e.to_name for e in live(tr).events] == ["2", "4"]
    config = FloorDetectorConfig(storey_m=6.0)
    assert [e.to_name for e in live(tr, config).events] == ["1", "2"]


def test_a_name_from_the_model_is_no_estimate() -> None:
    model = BuildingModel((ModelFloor("G", 0.0), ModelFloor("M", 4.0)))
    config = FloorDetectorConfig(start_floor="G", building=model)
    tr = trace([Stay(0.0, 60), Stay(4.0, 60, drive_m=3.0), Stay(-3.4, 60, drive_m=3.0)])
    events = live(tr, config).events
    assert [(e.to_name, e.estimated_name) for e in events] == [("M", False), ("G-1", True)]


# -- 5. rides: announced as they start ------------------------------------------------------


def test_a_ride_is_announced_as_it_starts_and_ended_by_its_transition() -> None:
    tr = trace([Stay(0.0, 60), Stay(-STOREY_M, 60, drive_m=3.0)])
    detector = live(tr)
    started, ended = detector.rides
    assert (started.kind, ended.kind) == (RideEventKind.STARTED, RideEventKind.ENDED)
    assert started.ride_id == ended.ride_id == 1
    assert started.direction is ended.direction is RideDirection.DOWN
    assert (started.from_id, started.from_name, started.to_id) == (0, "0", None)
    (event,) = detector.events
    assert (ended.to_id, ended.to_name, ended.floor_event_id) == (1, "-1", event.event_id)
    # announced during the ride (3.2 s at 1 m/s), decided once the car stopped
    ride_start, _ = tr.stays_s[0][1], tr.stays_s[1][0]
    assert secs(started.t_ns) - ride_start < 2.0 < secs(event.t_ns) - ride_start
    assert abs(secs(started.t_start_ns) - ride_start) < 0.5


@pytest.mark.parametrize("spike_pa", [-15.0, 15.0])
def test_a_spike_is_no_ride(spike_pa: float) -> None:
    # A ventilation spike: by the time the change has begun, the pressure is on its way
    # back, so no ride is announced.
    tr = trace([Stay(0.0, 120)])
    after = (tr.seconds() - 60.0).clip(0.0, None)
    spike = np.where(after > 0.0, spike_pa * np.exp(-after / 1.5), 0.0)
    spiked = Trace(tr.t_ns, tr.pressure_pa + spike, tr.temperature_c, tr.odometry, ())
    detector = live(spiked)
    assert detector.events == [] and detector.rides == []


def test_a_ride_that_comes_to_rest_short_of_a_floor_is_withdrawn_with_a_reason() -> None:
    # 1.2 m up (a ramp, a landing), a while there, and back: announced, then withdrawn.
    tr = trace([Stay(0.0, 60), Stay(1.2, 20), Stay(0.0, 60)])
    detector = live(tr, odometry=False)
    assert detector.events == []
    started, withdrawn = detector.rides
    assert (started.kind, started.direction) == (RideEventKind.STARTED, RideDirection.UP)
    assert withdrawn.kind is RideEventKind.RETRACTED and withdrawn.ride_id == started.ride_id
    assert withdrawn.reason == "came to rest 1.2 m from floor 0: no ride"


def test_a_step_faster_than_a_car_can_ride_is_no_stop_in_the_car() -> None:
    # Standing in the car, doors shut: 2 m of pressure in half a second, held 4 s, gone again
    # (two spikes in a row, a door slammed). A car needs 2.3 s at 1.5 m/s² for 2 m from rest
    # to rest, so this is no ride, however still it held.
    tr = trace([Stay(0.0, 120)])
    s = tr.seconds()
    bump = np.interp(s, [60.0, 60.5, 64.5, 65.0], [0.0, 24.0, 24.0, 0.0], left=0.0, right=0.0)
    bumped = Trace(tr.t_ns, tr.pressure_pa + bump, tr.temperature_c, tr.odometry, ())
    detector = live(bumped)
    assert detector.events == []
    # the same 2 m over 3 s, as a slow car rides it, is a ride decided at its stop
    ride = np.interp(s, [60.0, 63.0], [0.0, 24.0], left=0.0, right=24.0)
    rode = live(Trace(tr.t_ns, tr.pressure_pa + ride, tr.temperature_c, tr.odometry, ()))
    (event,) = rode.events
    assert event.delta_m == pytest.approx(-24.0 / 11.9, abs=0.2)
    assert secs(event.t_ns) - 63.0 < 2.5


def test_rides_with_a_halt_are_each_a_ride() -> None:
    # The robot stays in the car through a halt: two rides, the second ends with the
    # correction of what the first decided.
    detector = live(intermediate_stop(5.0, drive_m=0.0))
    kinds = [(r.ride_id, r.kind) for r in detector.rides]
    assert kinds == [
        (1, RideEventKind.STARTED),
        (1, RideEventKind.ENDED),
        (2, RideEventKind.STARTED),
        (2, RideEventKind.ENDED),
    ]
    first, correction = detector.events
    assert detector.rides[1].floor_event_id == first.event_id
    assert detector.rides[3].floor_event_id == correction.event_id
    assert detector.rides[2].from_id == first.to_id


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"start_floor": ""}, "start_floor"),
        ({"start_floor": "9", "building": BuildingModel((ModelFloor("G", 0.0),))}, "start_floor"),
        (
            {"building": BuildingModel((ModelFloor("0", 0.0), ModelFloor("1", 1.0)))},
            "building",
        ),
        ({"min_visit_s": -1.0}, "min_visit_s"),
        ({"leave_m": 0.0}, "leave_m"),
        ({"storey_m": float("nan")}, "storey_m"),
        ({"min_visit_s": True}, "min_visit_s"),
    ],
)
def test_config_errors_name_the_field(changes: dict[str, object], field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        FloorDetectorConfig(**changes)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "text",
    ["floors: []\n", "nothing: 1\n", "floors:\n  - {index: 0}\n", "floors: [1, 2]\n", ":\n- ["],
)
def test_a_bad_building_model_is_an_input_error(tmp_path: Path, text: str) -> None:
    path = tmp_path / "building.yaml"
    path.write_text(text)
    with pytest.raises(InputFormatError):
        load_building_model(path)


def test_odometry_that_stops_arriving_falls_back_to_the_dwell() -> None:
    tr = intermediate_stop(40.0, drive_m=0.0)
    t_odo, x, y = tr.odometry
    cut = t_odo < tr.t_ns[0] + 30 * NS_PER_S  # the base went silent before the ride
    detector = live(
        Trace(tr.t_ns, tr.pressure_pa, tr.temperature_c, (t_odo[cut], x[cut], y[cut]), ())
    )
    assert moves(detector.events) == [(0, 1), (1, 2)]
    bad = OnlineFloorDetector()
    bad.update_odometry(Odometry(5, float("nan"), 0.0, 0.0))
    bad.update_odometry(Odometry(10, 0.0, 0.0, 0.0))
    bad.update_odometry(Odometry(5, 0.0, 0.0, 0.0))
    assert bad.ignored_odometry == 2
    assert np.isnan(bad.state().height_m)
