"""A reference station's pressure, through Zenoh and the daemon's wiring, removes the weather.

A station publisher sends a weather front (pressure rising 100 Pa, about 8 m of height, in
ten seconds) while a robot standing still on its floor sees the same rise. The robot's daemon
side (``create_publisher`` from its configuration, the floor tracker's ``offer_reference``)
hands the station's samples to the detector: no floor change. Without the station the same
samples are a floor change. The station's and the robot's samples reach the tracker in time
order (each second of station samples is seen arriving before the robot's of the same
second), as they would live.
"""

from __future__ import annotations

import time

import pytest
from procs import endpoint, free_port

from baromap.errors import ConfigError
from baromap.floors import FloorDetectorConfig
from baromap.live.settings import LiveSettings
from baromap.messages import NS_PER_S, FloorEvent, Message, PressureSample
from baromapd import live
from baromapd.config import ConfigProblems, parse_config
from baromapd.floors import FloorTracker
from baromapd.live import LivePublisher, create_publisher

P0 = 100_000.0
RATE_HZ = 5
#: Station samples sent before the robot's of the same instants (one round trip per batch:
#: a second of samples, well inside the tracker's reference tolerance).
BATCH = RATE_HZ


def weather(t_s: float) -> float:
    """Pressure change of the front: flat 60 s, +100 Pa over 10 s, flat again."""
    return min(max(t_s - 60.0, 0.0), 10.0) * 10.0


def sample(i: int, offset: float = 0.0) -> PressureSample:
    t_s = i / RATE_HZ
    return PressureSample(round(t_s * NS_PER_S), P0 + offset + weather(t_s), 20.0)


def wait(what: object, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not what():  # type: ignore[operator]
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.002)


def run_robot(with_station: bool) -> list[Message]:
    published: list[Message] = []
    tracker = FloorTracker(FloorDetectorConfig())
    station = robot = None
    try:
        station_ep = endpoint(free_port())
        robot_table = f'[zenoh]\nlisten = []\nconnect = ["{station_ep}"]\n'
        if with_station:
            robot_table += '[reference]\nstation = "lobby"\n'
        config = parse_config(
            f'robot = "r1"\n[barometer]\nport = "loop://"\n{robot_table}', "robot.toml"
        )
        robot = create_publisher(config, reference=tracker.offer_reference)
        assert robot is not None
        station = LivePublisher(
            LiveSettings(listen=(station_ep,), pressure_period_s=0.0), "lobby", station=True
        )
        station.start()
        wait(lambda: station.health()["state"] == "open" and robot.health()["state"] == "open")
        if with_station:  # the robot's subscription has reached the station
            probe = 0
            while robot.health().get("reference_samples", 0) == 0:
                station.offer(sample(-1000 + probe))  # before the run: the same calm weather
                probe += 1
                time.sleep(0.01)
        for first in range(0, RATE_HZ * 100, BATCH):
            batch = range(first, first + BATCH)
            if with_station:
                expected = int(robot.health()["reference_samples"]) + BATCH
                for i in batch:
                    station.offer(sample(i))
                wait(lambda e=expected: robot.health()["reference_samples"] >= e)
            for i in batch:
                published += tracker.process(sample(i, offset=-50.0))  # a few metres higher
    finally:
        if robot is not None:
            robot.close()
        if station is not None:
            station.close()
        published += tracker.finish()
    return published


def test_a_weather_front_is_a_floor_change_without_a_station_and_none_with_one(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # pressure does not wake a publisher's worker, which looks every PRESSURE_HOLD_S: a
    # hundred round trips at the default are 20 s of waiting that the wiring does not need
    monkeypatch.setattr(live, "PRESSURE_HOLD_S", 0.01)
    alone = [m for m in run_robot(with_station=False) if isinstance(m, FloorEvent)]
    assert len(alone) == 1 and alone[0].delta_pa == pytest.approx(100.0, abs=10.0)
    corrected = [m for m in run_robot(with_station=True) if isinstance(m, FloorEvent)]
    assert corrected == []


def test_reference_and_zenoh_tables_are_checked_with_the_configuration() -> None:
    with pytest.raises(ConfigProblems) as problems:
        parse_config(
            'robot = "r1"\nrole = "station"\n[barometer]\nport = "loop://"\n'
            '[zenoh]\nmode = "client"\n[reference]\nstation = "lobby/2"\n'
        )
    keys = {p.key for p in problems.value.problems}
    assert {"zenoh.connect", "reference", "reference.station"} <= keys
    with pytest.raises(ConfigProblems, match="robot: 'reference' is reserved"):
        parse_config('robot = "reference"\n[barometer]\nport = "loop://"\n')
    config = parse_config('robot = "r1"\n[base]\nport = "loop://"\n[reference]\nstation = "a"\n')
    with pytest.raises(ConfigError, match=r"^reference\.station:"):
        create_publisher(config, reference=None)  # no barometer, no detector to correct
    disabled = parse_config('robot = "r1"\n[base]\nport = "loop://"\n[zenoh]\nenabled = false\n')
    assert create_publisher(disabled) is None
