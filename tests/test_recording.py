"""Recordings: every message type survives a round trip, and a cut file still reads."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from baromap import jsonmsg
from baromap import messages as m
from baromap.errors import InputFormatError, RecordingError
from baromap.recording import RecordingWriter, load_pressure, read_messages, read_metadata
from baromap.recording import topics as t
from baromap.recording.writer import MAX_T_NS

T0 = 1_763_700_000_000_000_000
stamps = st.integers(min_value=0, max_value=MAX_T_NS)
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
maybe_int = st.none() | st.integers(min_value=0, max_value=2**32)

pressure = st.builds(
    m.PressureSample,
    t_ns=stamps,
    pressure_pa=finite,
    temperature_c=st.none() | finite,
    seq=maybe_int,
    device_time_us=maybe_int,
)
odometry = st.builds(
    m.Odometry,
    t_ns=stamps,
    x_m=finite,
    y_m=finite,
    theta_rad=finite,
    v_mps=finite,
    omega_radps=finite,
    raw_x=st.integers(0, 0x7FFF),
    raw_y=st.integers(0, 0x7FFF),
    raw_theta=st.integers(-2048, 4095),
)
names = st.text(max_size=12)
floor_event = st.builds(
    m.FloorEvent,
    t_ns=stamps,
    event_id=st.integers(1, 2**53),
    kind=st.sampled_from(m.FloorEventKind),
    replaces=st.none() | st.integers(1, 2**53),
    t_start_ns=stamps,
    t_end_ns=stamps,
    from_id=st.integers(0, 50),
    to_id=st.integers(0, 50),
    from_name=names,
    to_name=names,
    height_m=finite,
    delta_pa=finite,
    delta_m=finite,
    level_pa=finite,
    at_end=st.booleans(),
)
floor_state = st.builds(
    m.FloorState,
    t_ns=stamps,
    phase=st.sampled_from(m.FloorPhase),
    floor_id=st.none() | st.integers(0, 50),
    name=st.none() | names,
    height_m=finite,
    level_m=finite,
    level_pa=finite,
    since_ns=stamps,
    floors_known=st.integers(0, 50),
    stop_floor_id=st.none() | st.integers(0, 50),
    stop_name=st.none() | names,
)
health = st.builds(
    m.DeviceHealth,
    t_ns=stamps,
    device=st.text(max_size=20),
    state=st.sampled_from(m.DeviceState),
    port=st.text(max_size=40),
    detail=st.text(max_size=80),
    counters=st.dictionaries(st.text(max_size=10), st.integers(0, 2**53)),
)
truth = st.builds(
    m.TruthPose,
    t_ns=stamps,
    x_m=finite,
    y_m=finite,
    theta_rad=finite,
    floor=st.integers(0, 20),
    z_m=finite,
) | st.builds(m.TruthFloor, t_ns=stamps, floor=st.none() | st.integers(0, 20), z_m=finite)
json_messages = pressure | odometry | floor_event | floor_state | health | truth


@given(json_messages)
def test_json_round_trip(message: m.Message) -> None:
    assert jsonmsg.loads(type(message), jsonmsg.dumps(message)) == message


def test_json_rejects_newer_schema_and_junk() -> None:
    with pytest.raises(InputFormatError):
        jsonmsg.loads(m.PressureSample, b'{"schema": 99, "t_ns": 1, "pressure_pa": 1.0}')
    with pytest.raises(InputFormatError):
        jsonmsg.loads(m.PressureSample, b"[1, 2]")
    with pytest.raises(InputFormatError):
        jsonmsg.loads(m.PressureSample, b'{"schema": 1}')


def make_scan(t_ns: int, n: int = 361, seed: int = 0) -> m.LaserScan:
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.1, 8.0, n).astype(np.float32)
    flags = np.zeros(n, dtype=np.uint16)
    flags[::17] = m.BeamFlag.DAZZLE
    ranges[::17] = np.nan
    flags[5] = m.BeamFlag.RAW_BIT13
    return m.LaserScan(
        t_ns=t_ns,
        angle_min_rad=-math.pi / 2,
        angle_increment_rad=math.pi / (n - 1),
        range_max_m=8.19,
        ranges_m=ranges,
        flags=flags,
    )


@settings(max_examples=25, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(json_messages, max_size=12), st.integers(0, 3))
def test_recording_round_trip(tmp_path: Path, batch: list[m.Message], n_scans: int) -> None:
    path = tmp_path / "run.mcap"
    scans = [make_scan(T0 + i, seed=i) for i in range(n_scans)]
    with RecordingWriter(path, robot="r1", allow_overwrite=True) as writer:
        for message in [*batch, *scans]:
            writer.write(message)
    got = [rec.message for rec in read_messages(path) if rec.topic != t.TF]
    expected = sorted([*batch, *scans], key=lambda msg: msg.t_ns)
    assert sorted(got, key=lambda msg: msg.t_ns) == expected


def test_scan_keeps_angles_flags_and_range_limits(tmp_path: Path) -> None:
    path = tmp_path / "scan.mcap"
    scan = make_scan(T0)
    with RecordingWriter(path, robot="r1") as writer:
        writer.write(scan)
    (got,) = [rec.message for rec in read_messages(path)]
    assert got == scan
    assert got.range_max_m == pytest.approx(8.19)
    assert got.angle_max_rad == pytest.approx(math.pi / 2)


def test_topics_schemas_and_metadata_are_what_foxglove_expects(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with RecordingWriter(path, robot="p3at-1", metadata={"config": "{}"}) as writer:
        writer.write(m.PressureSample(T0, 101325.0, 21.0, seq=1))
        writer.write(m.Odometry(T0, 1.0, 2.0, 0.5))
        writer.write(make_scan(T0))
        writer.write_metadata("devices", {"baro": "usb 2341:0043 serial 1234"})
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert schemas == {
        t.BARO: "baromap.PressureSample",
        t.ODOM: "baromap.Odometry",
        t.TF: "foxglove.FrameTransform",
        t.SCAN: "foxglove.LaserScan",
    }
    meta = read_metadata(path)
    assert meta["baromap"]["robot"] == "p3at-1"
    assert meta["baromap"]["config"] == "{}"
    assert meta["devices"] == {"baro": "usb 2341:0043 serial 1234"}
    (tf,) = [rec.message for rec in read_messages(path, [t.TF])]
    assert tf.child_frame_id == "base_link"
    assert tf.rotation.z == pytest.approx(math.sin(0.25))


def test_power_cut_loses_only_the_unflushed_tail(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    writer = RecordingWriter(path, robot="r1", flush_interval_s=3600)
    for i in range(100):
        writer.write(m.PressureSample(T0 + i, 100000.0 + i))
    writer.flush()
    for i in range(100, 130):
        writer.write(m.PressureSample(T0 + i, 100000.0 + i))
    cut = tmp_path / "cut.mcap"
    shutil.copy(path, cut)
    writer.close()
    data = cut.read_bytes()
    for size in (len(data), len(data) - 5, len(data) - 200):
        cut.write_bytes(data[:size])
        got = [rec.message.pressure_pa for rec in read_messages(cut)]
        assert got[: min(len(got), 100)] == [100000.0 + i for i in range(min(len(got), 100))]
        assert len(got) >= (100 if size >= len(data) - 5 else 0)
    assert read_metadata(cut)["baromap"]["robot"] == "r1"
    assert len(load_pressure(path).t_ns) == 130


def test_flush_interval_writes_chunks_while_recording(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with RecordingWriter(path, robot="r1", flush_interval_s=0.0) as writer:
        writer.write(m.PressureSample(T0, 100000.0))
        size_after_one = path.stat().st_size
        writer.write(m.PressureSample(T0 + 1, 100000.0))
        assert path.stat().st_size > size_after_one


def test_clear_errors_for_bad_paths_and_inputs(tmp_path: Path) -> None:
    not_mcap = tmp_path / "x.mcap"
    not_mcap.write_text("time_s,pressure_pa\n")
    with pytest.raises(InputFormatError):
        list(read_messages(not_mcap))
    with pytest.raises(RecordingError):
        list(read_messages(tmp_path / "missing.mcap"))
    with RecordingWriter(tmp_path / "ok.mcap", robot="r") as writer:
        with pytest.raises(RecordingError):
            writer.write_metadata("bad", {"n": 1})  # type: ignore[dict-item]
        with pytest.raises(RecordingError):
            writer.write(object())  # type: ignore[arg-type]
        with pytest.raises(RecordingError):
            writer.write(m.PressureSample(-1, 1.0))
    with pytest.raises(RecordingError):
        RecordingWriter(tmp_path / "ok.mcap", robot="r")


def test_pressure_loader_rejects_wrong_topic_type(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with RecordingWriter(path, robot="r") as writer:
        writer.write(m.Odometry(T0, 0.0, 0.0, 0.0), topic=t.BARO)
    with pytest.raises(InputFormatError):
        load_pressure(path)
