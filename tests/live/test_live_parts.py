"""The Zenoh side's parts that need no network: keys, settings, payloads, the schedule."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from baromap import jsonmsg
from baromap.errors import ConfigError, InputFormatError
from baromap.live.keys import Channel, NodeKeys, robot_of, robot_selector
from baromap.live.payloads import decode, encode
from baromap.live.schedule import PressureDecimator, PublishSchedule
from baromap.live.settings import LiveSettings, ReferenceSettings, ZenohMode
from baromap.messages import (
    NS_PER_S,
    DeviceHealth,
    DeviceState,
    FloorEvent,
    FloorEventKind,
    FloorPhase,
    FloorState,
    Odometry,
    PressureSample,
)

S = NS_PER_S


def state(
    t_ns: int = 0, floor: int | None = 1, level: float = 99_000.0, **kw: object
) -> FloorState:
    fields: dict[str, object] = {
        "t_ns": t_ns,
        "phase": FloorPhase.SETTLED,
        "floor_id": floor,
        "name": None if floor is None else str(floor),
        "height_m": 3.5,
        "level_m": 3.5,
        "level_pa": level,
        "since_ns": 0,
        "floors_known": 2,
    }
    fields.update(kw)
    return FloorState(**fields)  # type: ignore[arg-type]


EVENT = FloorEvent(
    t_ns=10 * S,
    event_id=1,
    kind=FloorEventKind.TRANSITION,
    replaces=None,
    t_start_ns=2 * S,
    t_end_ns=9 * S,
    from_id=0,
    to_id=1,
    from_name="0",
    to_name="1",
    height_m=3.46,
    delta_pa=-41.5,
    delta_m=3.46,
    level_pa=99_958.5,
)


# -- keys -------------------------------------------------------------------------------


def test_keys_of_robots_and_stations_are_those_of_the_design() -> None:
    robot = NodeKeys.robot("pioneer-1")
    assert robot.key(Channel.EVENT) == "baromap/pioneer-1/floor/event"
    assert robot.key(Channel.STATE) == "baromap/pioneer-1/floor/state"
    assert robot.key(Channel.ALIVE) == "baromap/pioneer-1/alive"
    station = NodeKeys.reference("lobby")
    assert station.key(Channel.PRESSURE) == "baromap/reference/lobby/pressure"
    with pytest.raises(ConfigError, match="no 'floor/event'"):
        station.key(Channel.EVENT)
    assert robot_selector(Channel.EVENT) == "baromap/*/floor/event"
    assert robot_of("baromap/pioneer-1/floor/state") == "pioneer-1"
    assert robot_of("baromap/reference/lobby/pressure") is None
    assert robot_of("other/x/y") is None


@pytest.mark.parametrize("bad", ["", "a/b", "r*", "$x", "r 1", "é", "x" * 65, 7])
def test_ids_that_would_break_a_key_are_refused(bad: object) -> None:
    with pytest.raises(ConfigError, match="robot id"):
        NodeKeys.robot(bad)  # type: ignore[arg-type]


def test_a_robot_cannot_be_named_like_the_stations() -> None:
    with pytest.raises(ConfigError, match="reserved"):
        NodeKeys.robot("reference")


# -- settings ---------------------------------------------------------------------------


def test_defaults_keep_the_daemon_on_loopback() -> None:
    settings = LiveSettings.from_table({})
    assert settings.mode is ZenohMode.PEER
    assert settings.listen == ("tcp/127.0.0.1:7447",)
    assert settings.connect == ()
    assert settings.multicast_scouting is False
    config = settings.zenoh_config()
    assert json.loads(config.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447"]
    assert json.loads(config.get_json("scouting/multicast/enabled")) is False
    assert json.loads(config.get_json("mode")) == "peer"


def test_a_client_table_listens_nowhere_and_connects_to_its_routers() -> None:
    settings = LiveSettings.from_table(
        {"mode": "client", "connect": ["tcp/10.1.2.3:7447", "tcp/10.1.2.4:7447"]}
    )
    assert settings.listen == ()
    config = settings.zenoh_config()
    assert json.loads(config.get_json("mode")) == "client"
    assert json.loads(config.get_json("connect/endpoints")) == [
        "tcp/10.1.2.3:7447",
        "tcp/10.1.2.4:7447",
    ]


@pytest.mark.parametrize(
    ("table", "key"),
    [
        ({"mode": "router"}, "zenoh.mode"),
        ({"listen": "tcp/127.0.0.1:7447"}, "zenoh.listen"),
        ({"listen": ["127.0.0.1:7447"]}, "zenoh.listen"),
        ({"listen": ["carrier-pigeon/1.2.3.4:5"]}, "zenoh.listen"),
        ({"connect": ["tcp/10.0.0.1:0"]}, "zenoh.connect"),
        ({"connect": ["tcp/10.0.0.1"]}, "zenoh.connect"),
        ({"mode": "client"}, "zenoh.connect"),
        ({"mode": "client", "connect": ["tcp/h:1"], "listen": ["tcp/h:2"]}, "zenoh.listen"),
        ({"multicast_scouting": "yes"}, "zenoh.multicast_scouting"),
        ({"state_period_s": 0}, "zenoh.state_period_s"),
        ({"pressure_period_s": math.nan}, "zenoh.pressure_period_s"),
        ({"health_period_s": True}, "zenoh.health_period_s"),
        ({"queue_size": 3}, "zenoh.queue_size"),
        ({"config_file": "/nonexistent/zenoh.json5"}, "zenoh.config_file"),
        ({"enabled": 1}, "zenoh.enabled"),
        ({"lisen": []}, "zenoh.lisen"),
    ],
)
def test_bad_settings_name_their_key(table: dict[str, object], key: str) -> None:
    with pytest.raises(ConfigError, match=f"^{key}:"):
        LiveSettings.from_table(table)


def test_a_zenoh_file_is_the_base_and_the_table_wins(tmp_path: Path) -> None:
    file = tmp_path / "zenoh.json5"
    file.write_text(
        '{ mode: "client", listen: { endpoints: ["tcp/0.0.0.0:9999"] },'
        " transport: { unicast: { open_timeout: 1234 } } }"
    )
    config = LiveSettings.from_table({"config_file": str(file)}).zenoh_config()
    assert json.loads(config.get_json("transport/unicast/open_timeout")) == 1234
    assert json.loads(config.get_json("mode")) == "peer"
    assert json.loads(config.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447"]


def test_an_unreadable_zenoh_file_is_a_config_error(tmp_path: Path) -> None:
    file = tmp_path / "zenoh.json5"
    file.write_text("{ mode: ")
    with pytest.raises(ConfigError, match=r"^zenoh\.config_file:"):
        LiveSettings.from_table({"config_file": str(file)}).zenoh_config()


def test_reference_table() -> None:
    assert ReferenceSettings.from_table({"station": "lobby"}).station == "lobby"
    with pytest.raises(ConfigError, match=r"^reference\.station:"):
        ReferenceSettings.from_table({})
    with pytest.raises(ConfigError, match=r"^reference\.station:"):
        ReferenceSettings.from_table({"station": "lobby/2"})
    with pytest.raises(ConfigError, match=r"^reference\.statoin:"):
        ReferenceSettings.from_table({"statoin": "lobby"})


# -- payloads ---------------------------------------------------------------------------


def test_payloads_are_json_with_a_schema_version_and_round_trip() -> None:
    unknown = state(floor=None, level=math.nan, height_m=math.nan, phase=FloorPhase.UNKNOWN)
    health = DeviceHealth(5 * S, "baro", DeviceState.UP, "/dev/ttyACM0", "", {"crc_errors": 2})
    for channel, message in (
        (Channel.EVENT, EVENT),
        (Channel.STATE, state()),
        (Channel.PRESSURE, PressureSample(S, 100_000.25, 21.5)),
        (Channel.HEALTH, health),
    ):
        payload = encode(message)
        assert json.loads(payload)["schema"] == jsonmsg.SCHEMA_VERSION
        assert payload == jsonmsg.dumps(message)  # what a recording's JSON channel holds
        assert decode(channel, payload) == message
    payload = encode(unknown)
    assert json.loads(payload, parse_constant=pytest.fail)["level_pa"] is None  # no NaN: JSON
    back = decode(Channel.STATE, payload)
    assert back.floor_id is None and math.isnan(back.level_pa) and math.isnan(back.height_m)


@pytest.mark.parametrize(
    "payload",
    [b"", b"not json", b"[1]", b'{"schema": 99}', b'{"t_ns": 1}', b'{"phase": "flying"}'],
)
def test_a_bad_payload_is_an_input_format_error(payload: bytes) -> None:
    good = json.loads(encode(state()))
    if payload == b'{"phase": "flying"}':
        payload = json.dumps(good | {"phase": "flying"}).encode()
    with pytest.raises(InputFormatError):
        decode(Channel.STATE, payload)


def test_only_published_types_encode() -> None:
    with pytest.raises(TypeError):
        encode(Odometry(0, 0.0, 0.0, 0.0))


# -- schedule ---------------------------------------------------------------------------


def test_pressure_is_published_as_block_means_stamped_at_their_last_sample() -> None:
    decimator = PressureDecimator(S // 5)
    out = [
        decimator.push(PressureSample(i * S // 50, 100_000.0 + i, 20.0 + (i % 2)))
        for i in range(101)
    ]
    means = [m for m in out if m is not None]
    assert len(means) == 10  # 2 s of samples at 50 Hz, one mean each 0.2 s
    first = means[0]
    assert first.t_ns == S // 5  # the block's last sample, never later than the data
    assert first.pressure_pa == pytest.approx(100_000.0 + 5.0)  # mean of samples 0..10
    for k, mean in enumerate(means[1:], start=1):  # then the 10 samples after each block
        assert mean.t_ns == (k + 1) * S // 5
        assert mean.pressure_pa == pytest.approx(100_000.0 + 10 * k + 5.5)
    assert all(m.temperature_c is not None and 20.0 <= m.temperature_c <= 21.0 for m in means)


def test_a_gap_restarts_the_blocks_and_bad_samples_are_skipped() -> None:
    decimator = PressureDecimator(S)
    assert decimator.push(PressureSample(0, 1.0)) is None
    assert decimator.push(PressureSample(S // 2, math.nan)) is None
    mean = decimator.push(PressureSample(100 * S, 3.0))  # after a long gap
    assert mean is not None and mean.pressure_pa == 2.0 and mean.temperature_c is None
    assert decimator.push(PressureSample(100 * S + S // 2, 5.0)) is None  # a new full block
    assert decimator.ignored == 1


def test_period_zero_passes_every_sample() -> None:
    decimator = PressureDecimator(0)
    sample = PressureSample(1, 2.0)
    assert decimator.push(sample) is sample


def test_state_goes_out_on_change_and_periodically_not_on_drift() -> None:
    schedule = PublishSchedule(LiveSettings(state_period_s=5.0))
    assert schedule.next_due_ns() is None
    first = schedule.offer(state(0, floor=1), now_ns=0)
    assert [o.channel for o in first] == [Channel.STATE]
    # the level drifts and the stamp ticks: not a change
    assert schedule.offer(state(S, floor=1, level=99_000.4), now_ns=S) == []
    assert schedule.due(4 * S) == []
    periodic = schedule.due(5 * S)
    assert [o.message for o in periodic] == [state(S, floor=1, level=99_000.4)]
    assert schedule.next_due_ns() == 10 * S
    changed = schedule.offer(state(6 * S, floor=1, phase=FloorPhase.CHANGING), now_ns=6 * S)
    assert [o.channel for o in changed] == [Channel.STATE]
    assert schedule.state == state(6 * S, floor=1, phase=FloorPhase.CHANGING)


def test_events_pass_at_once_and_other_messages_are_not_published() -> None:
    schedule = PublishSchedule(LiveSettings())
    assert [o.message for o in schedule.offer(EVENT, now_ns=0)] == [EVENT]
    assert schedule.offer(Odometry(0, 0.0, 0.0, 0.0), now_ns=0) == []
    assert schedule.ignored == 1


def test_health_is_the_latest_of_each_device_each_period() -> None:
    schedule = PublishSchedule(LiveSettings(health_period_s=1.0))
    up = DeviceHealth(0, "baro", DeviceState.UP)
    assert schedule.offer(up, now_ns=0) == []
    assert [o.message for o in schedule.due(0)] == [up]
    laser = DeviceHealth(S // 2, "laser", DeviceState.DOWN, detail="no answer")
    baro = DeviceHealth(S // 2, "baro", DeviceState.DEGRADED)
    schedule.offer(laser, now_ns=S // 2)
    schedule.offer(baro, now_ns=S // 2)
    assert schedule.due(S // 2) == []
    assert sorted((o.message for o in schedule.due(S)), key=str) == sorted([laser, baro], key=str)
    assert all(o.channel is Channel.HEALTH for o in schedule.due(2 * S))


def test_a_station_publishes_pressure_and_health_only() -> None:
    schedule = PublishSchedule(LiveSettings(pressure_period_s=0.0), station=True)
    assert schedule.offer(EVENT, now_ns=0) == []
    assert schedule.offer(state(), now_ns=0) == []
    out = schedule.offer(PressureSample(0, 100_000.0), now_ns=0)
    assert [o.channel for o in out] == [Channel.PRESSURE]
    assert schedule.state is None
