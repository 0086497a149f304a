"""Recordings: every message type survives a round trip, and a cut file still reads."""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
import signal
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from baromap import jsonmsg
from baromap import messages as m
from baromap.errors import InputFormatError, RecordingError
from baromap.recording import (
    LaserMount,
    RecordingWriter,
    load_odometry,
    load_pressure,
    load_pressure_and_odometry,
    load_pressures_and_odometry,
    read_messages,
    read_metadata,
)
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
    theta_rad=st.floats(-math.pi, math.pi),
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


@pytest.mark.slow
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


@settings(
    max_examples=25,
    deadline=None,  # file I/O and fsync: a loaded machine takes its time
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(st.lists(json_messages, max_size=12), st.integers(0, 3))
def test_recording_round_trip(tmp_path: Path, batch: list[m.Message], n_scans: int) -> None:
    path = tmp_path / "run.mcap"
    scans = [make_scan(T0 + i, seed=i) for i in range(n_scans)]
    with RecordingWriter(path, robot="r1", allow_overwrite=True) as writer:
        for message in [*batch, *scans]:
            writer.write(message)
    got = [rec.message for rec in read_messages(path) if rec.topic != t.TF]
    expected = sorted([*batch, *scans], key=lambda msg: msg.t_ns)
    got = sorted(got, key=lambda msg: msg.t_ns)
    assert [same_heading(a, b) for a, b in zip(got, expected, strict=True)] == expected


def same_heading(got: m.Message, expected: m.Message) -> m.Message:
    """Odometry's heading travels as a quaternion: equal up to rounding, then compared whole."""
    if isinstance(got, m.Odometry) and isinstance(expected, m.Odometry):
        assert math.remainder(got.theta_rad - expected.theta_rad, math.tau) == pytest.approx(
            0.0, abs=1e-12
        )
        return dataclasses.replace(got, theta_rad=expected.theta_rad)
    return got


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
        t.ODOM: "foxglove.Odometry",
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
    flushed = [100000.0 + i for i in range(100)]
    # The copy ends in the chunk being written (its header only: the rest is in memory). Cut
    # anywhere after the flushed chunk, the reader keeps exactly the flushed 100; cut inside
    # it, nothing of it (a chunk is used whole), and it never raises.
    chunk_end = _end_of_first_chunk(data)
    for size in (len(data), len(data) - 5, len(data) - 200, chunk_end, chunk_end - 1, 100):
        cut.write_bytes(data[:size])
        got = [rec.message.pressure_pa for rec in read_messages(cut)]
        assert got == (flushed if size >= chunk_end else []), size
    cut.write_bytes(data)
    assert read_metadata(cut)["baromap"]["robot"] == "r1"
    assert len(load_pressure(path).t_ns) == 130


def _end_of_first_chunk(data: bytes) -> int:
    """Byte offset just past the file's first Chunk record."""
    pos = 8  # the magic
    while True:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        pos += 9 + length
        if opcode == 0x06:
            return pos


def test_flush_interval_writes_chunks_while_recording(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with RecordingWriter(path, robot="r1", flush_interval_s=0.0) as writer:
        writer.write(m.PressureSample(T0, 100000.0))
        size_after_one = path.stat().st_size
        assert writer.size_bytes == size_after_one
        writer.write(m.PressureSample(T0 + 1, 100000.0))
        assert path.stat().st_size > size_after_one
        assert not writer.flush_if_due()  # nothing new since the last flush


@pytest.mark.slow
def test_closed_files_leave_no_channels_behind(tmp_path: Path) -> None:
    """A daemon opens a file a minute for days: the plain channels of a closed file (JSON, and
    the scans' protobuf) must go (the foxglove SDK keeps every ``foxglove.Channel`` in a
    registry of its own)."""
    import gc

    import foxglove

    def channels() -> int:
        gc.collect()
        return sum(isinstance(o, foxglove.Channel) for o in gc.get_objects())

    before = channels()
    for part in range(5):
        with RecordingWriter(tmp_path / f"run_{part}.mcap", robot="r1") as writer:
            writer.write(m.PressureSample(T0, 100000.0, seq=part))
            writer.write(m.DeviceHealth(T0, "barometer", m.DeviceState.UP, "/dev/x", "", {}))
            writer.write(make_scan(T0))
            assert channels() == before + 3
    assert channels() == before
    last = [r.message for r in read_messages(tmp_path / "run_4.mcap", [t.BARO])]
    assert last == [m.PressureSample(T0, 100000.0, seq=4)]


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


def test_odometry_travels_in_foxglove_schema_with_its_raw_counters(tmp_path: Path) -> None:
    from mcap_protobuf.decoder import DecoderFactory

    path = tmp_path / "odom.mcap"
    sent = [
        m.Odometry(T0 + i, 0.1 * i, -0.2 * i, 0.3 - 0.1 * i, 0.25, -0.5, 100 + i, 32767, -7)
        for i in range(20)
    ]
    with RecordingWriter(path, robot="r") as writer:
        for odom in sent:
            writer.write(odom)
    # Foxglove's reading of it, through the mcap packages alone
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        decoded = [(ch.topic, msg) for _, ch, _, msg in reader.iter_decoded_messages([t.ODOM])]
    assert len(decoded) == len(sent)
    first = decoded[0][1]
    assert (first.frame_id, first.body_frame_id) == ("odom", "base_link")
    assert {kv.key: kv.value for kv in first.metadata} == {
        "raw_x": "100",
        "raw_y": "32767",
        "raw_theta": "-7",
    }
    got = [rec.message for rec in read_messages(path, [t.ODOM])]
    assert [same_heading(a, b) for a, b in zip(got, sent, strict=True)] == sent
    series = load_odometry(path)
    assert series.raw_x.tolist() == [o.raw_x for o in sent]
    assert series.raw_theta.tolist() == [-7] * len(sent)
    assert np.allclose(series.poses(), [(o.x_m, o.y_m, o.theta_rad) for o in sent])
    assert np.allclose(series.v_mps, 0.25) and np.allclose(series.omega_radps, -0.5)


def _chunks(path: Path) -> list[list[str]]:
    """Topics of the messages of each chunk, in file order, as the mcap package sees them."""
    from mcap.records import Channel, Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    channels: dict[int, str] = {}
    out = []
    with path.open("rb") as f:
        for record in StreamReader(f, emit_chunks=True).records:
            if isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Chunk):
                topics_ = []
                for inner in breakup_chunk(record):
                    if isinstance(inner, Channel):
                        channels[inner.id] = inner.topic
                    elif isinstance(inner, Message):
                        topics_.append(channels[inner.channel_id])
                out.append(topics_)
    return out


def test_static_laser_transform_is_in_every_chunk_and_every_second(tmp_path: Path) -> None:
    mount = LaserMount(0.16, -0.02, 0.05)
    paths = [tmp_path / "part0.mcap", tmp_path / "part1.mcap"]  # a rotation: two files
    for part, path in enumerate(paths):
        with RecordingWriter(path, robot="r", laser_mount=mount, flush_interval_s=3600) as w:
            for i in range(60):  # 6 s at 10 Hz, a flush every 2 s
                t_ns = T0 + (part * 60 + i) * 100_000_000
                w.write(m.Odometry(t_ns, 0.01 * i, 0.0, 0.0))
                if i % 20 == 19:
                    w.flush()
        chunks = _chunks(path)
        assert len(chunks) >= 3
        assert all(chunk[0] == t.TF_STATIC for chunk in chunks)
        statics = list(read_messages(path, [t.TF_STATIC]))
        times = [rec.log_time_ns for rec in statics]
        assert max(np.diff(times)) <= 1_000_000_000
        tf = statics[0].message
        assert (tf.parent_frame_id, tf.child_frame_id) == ("base_link", "laser")
        assert (tf.translation.x, tf.translation.y) == pytest.approx((0.16, -0.02))
        assert 2 * math.atan2(tf.rotation.z, tf.rotation.w) == pytest.approx(0.05)
        assert LaserMount.from_metadata(read_metadata(path)) == mount


def test_a_mount_stated_in_metadata_becomes_the_static_transform(tmp_path: Path) -> None:
    path = tmp_path / "daemon.mcap"
    mount = LaserMount(0.2, 0.0, -0.1)
    with RecordingWriter(path, robot="r", metadata={"laser_mount": mount.to_json()}) as writer:
        writer.write(m.PressureSample(T0, 1.0))
    (static,) = [rec.message for rec in read_messages(path, [t.TF_STATIC])]
    assert static.translation.x == pytest.approx(0.2)
    with pytest.raises(RecordingError):
        RecordingWriter(tmp_path / "bad.mcap", robot="r", metadata={"laser_mount": "{x"})
    carmen = tmp_path / "carmen.mcap"  # the CARMEN importer's spelling
    with RecordingWriter(carmen, robot="r", metadata={"laser_offset": "0.1 0.0 0.0"}) as writer:
        writer.write(m.PressureSample(T0, 1.0))
    assert LaserMount.from_metadata(read_metadata(carmen)) == LaserMount(0.1)
    assert len(list(read_messages(carmen, [t.TF_STATIC]))) == 1


def test_a_recording_states_one_laser_mount(tmp_path: Path) -> None:
    with RecordingWriter(tmp_path / "a.mcap", robot="r") as writer:
        writer.write(m.PressureSample(T0, 1.0))
        writer.set_laser_mount(LaserMount(0.1, 0.0, 0.0))
        writer.set_laser_mount(LaserMount(0.1, 0.0, 0.0))
        with pytest.raises(RecordingError):
            writer.set_laser_mount(LaserMount(0.2, 0.0, 0.0))
        writer.write(m.PressureSample(T0 + 1, 1.0))
    assert [rec.topic for rec in read_messages(tmp_path / "a.mcap")] == [
        t.BARO,
        t.TF_STATIC,
        t.BARO,
    ]
    assert LaserMount.from_metadata(read_metadata(tmp_path / "a.mcap")) == LaserMount(0.1)
    with pytest.raises(InputFormatError):
        LaserMount(math.nan, 0.0, 0.0)


KILLED_WRITER = """
import sys, time
from baromap import messages as m
from baromap.recording import RecordingWriter
T0 = 1_763_700_000_000_000_000
writer = RecordingWriter(sys.argv[1], robot="r", flush_interval_s=3600)
for i in range(500):
    writer.write(m.PressureSample(T0 + i, 100000.0 + i))
writer.flush()
print("flushed", file=sys.stderr, flush=True)
for i in range(500, 520):
    writer.write(m.PressureSample(T0 + i, 100000.0 + i))
time.sleep(60)
"""


def test_sigkill_keeps_everything_up_to_the_last_flush(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    with subprocess.Popen(
        [sys.executable, "-c", KILLED_WRITER, str(path)],
        stdout=subprocess.DEVNULL,  # the writer's logs
        stderr=subprocess.PIPE,
        text=True,
    ) as proc:
        try:
            assert proc.stderr is not None
            assert proc.stderr.readline().strip() == "flushed"
        finally:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
    got = load_pressure(path)
    assert got.pressure_pa[:500].tolist() == [100000.0 + i for i in range(500)]
    assert read_metadata(path)["baromap"]["robot"] == "r"


def test_messages_come_in_log_time_order_across_chunks(tmp_path: Path) -> None:
    path = tmp_path / "late.mcap"
    with RecordingWriter(path, robot="r", flush_interval_s=3600) as writer:
        for block in ([5, 6, 9], [3, 7, 8], [1, 2, 10]):  # chunks whose times overlap
            for i in block:
                writer.write(m.PressureSample(T0 + i, float(i)))
            writer.flush()
    assert [rec.message.pressure_pa for rec in read_messages(path)] == sorted(
        [5.0, 6.0, 9.0, 3.0, 7.0, 8.0, 1.0, 2.0, 10.0]
    )
    assert load_pressure(path).pressure_pa.tolist() == [1, 2, 3, 5, 6, 7, 8, 9, 10]


def _handmade(path: Path, payloads: list[bytes], schema_name: str = "baromap.PressureSample"):
    """A recording written by the mcap package itself, with payloads of our choosing."""
    from mcap.writer import Writer

    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="test")
        schema = writer.register_schema(schema_name, "jsonschema", b"{}")
        channel = writer.register_channel(t.BARO, "json", schema)
        for i, payload in enumerate(payloads):
            writer.add_message(channel, T0 + i, payload, T0 + i)
        writer.finish()


def test_pressure_loader_validates_untrusted_payloads(tmp_path: Path) -> None:
    good = [jsonmsg.dumps(m.PressureSample(T0 + i, 1000.0 + i, 20.0)) for i in range(50)]
    path = tmp_path / "nan.mcap"
    nan_temperature = b'{"schema":1,"t_ns":%d,"pressure_pa":1.5,"temperature_c":NaN}' % (T0 + 50)
    _handmade(path, [*good, nan_temperature])
    series = load_pressure(path)
    assert series.pressure_pa.tolist() == [1000.0 + i for i in range(50)] + [1.5]
    assert math.isnan(series.temperature_c[-1])
    for bad in (
        b'{"schema":1,"t_ns":"12","pressure_pa":1.0}',
        b'{"schema":1,"t_ns":1,"pressure_pa":"1.0"}',
        b'{"schema":1,"t_ns":1.5,"pressure_pa":1.0}',
        b'{"schema":1,"pressure_pa":1.0}',
        b'{"schema":7,"t_ns":1,"pressure_pa":1.0}',
        b'{"schema":1,"t_ns":1,"pressure_pa":1.0},{"schema":1,"t_ns":2,"pressure_pa":1.0}',
        b"not json",
        b"",
    ):
        _handmade(path, [*good, bad])
        with pytest.raises(InputFormatError):
            load_pressure(path)
        with pytest.raises(InputFormatError):
            list(read_messages(path))
    _handmade(path, good, schema_name="baromap.Odometry")
    with pytest.raises(InputFormatError):
        load_pressure(path)


def test_both_series_in_one_pass_match_the_message_reader(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with RecordingWriter(path, robot="r", flush_interval_s=3600) as writer:
        for i in range(300):
            writer.write(m.PressureSample(T0 + i * 40_000_000, 1e5 + i, None if i % 3 else 21.0))
            if i % 2 == 0:
                writer.write(m.Odometry(T0 + i * 40_000_000, i * 0.01, 0.0, 0.1, raw_x=i))
            if i % 100 == 99:
                writer.flush()
    pressure, odom = load_pressure_and_odometry(path)
    samples = [rec.message for rec in read_messages(path, [t.BARO])]
    assert pressure.t_ns.tolist() == [s.t_ns for s in samples]
    assert np.array_equal(
        pressure.temperature_c,
        [math.nan if s.temperature_c is None else s.temperature_c for s in samples],
        equal_nan=True,
    )
    assert odom.raw_x.tolist() == list(range(0, 300, 2))


def test_several_pressure_topics_in_one_pass_match_one_topic_at_a_time(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with RecordingWriter(path, robot="r", flush_interval_s=3600) as writer:
        for i in range(200):
            writer.write(m.PressureSample(T0 + i * 40_000_000, 1e5 + i))
            if i % 4 == 0:
                writer.write(
                    m.PressureSample(T0 + i * 40_000_000, 2e5 - i), topic=t.REFERENCE_PRESSURE
                )
            writer.write(m.Odometry(T0 + i * 40_000_000, i * 0.01, 0.0, 0.0, raw_x=i))
            if i % 50 == 49:
                writer.flush()
    pressures, odom = load_pressures_and_odometry(
        path, [t.BARO, t.REFERENCE_PRESSURE, "/absent"], t.ODOM
    )
    for topic in (t.BARO, t.REFERENCE_PRESSURE):
        alone = load_pressure(path, topic)
        assert pressures[topic].t_ns.tolist() == alone.t_ns.tolist()
        assert pressures[topic].pressure_pa.tolist() == alone.pressure_pa.tolist()
    assert pressures[t.REFERENCE_PRESSURE].pressure_pa.tolist() == [
        2e5 - i for i in range(0, 200, 4)
    ]
    assert len(pressures["/absent"].t_ns) == 0
    assert odom.raw_x.tolist() == list(range(200))


def test_any_cut_of_a_file_reads_back_a_prefix(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with RecordingWriter(path, robot="r", flush_interval_s=3600) as writer:
        for i in range(400):
            writer.write(m.PressureSample(T0 + i, float(i)))
            writer.write(m.Odometry(T0 + i, float(i), 0.0, 0.0))
            if i % 50 == 49:
                writer.flush()
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    previous = -1
    for size in range(8, len(data), max(1, len(data) // 97)):
        cut.write_bytes(data[:size])
        got = load_pressure(cut).pressure_pa.tolist()
        assert got == [float(i) for i in range(len(got))]
        assert len(got) >= previous  # a longer cut never loses what a shorter one kept
        previous = len(got)
        odom = load_odometry(cut)
        assert odom.x_m.tolist() == [float(i) for i in range(len(odom))]
    assert previous >= 350  # all but the unflushed tail and the summary


def test_info_reads_the_summary_and_flags_a_cut_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from baromap.cli.main import main

    path = tmp_path / "run.mcap"
    with RecordingWriter(path, robot="r", laser_mount=LaserMount(), flush_interval_s=3600) as w:
        for i in range(200):
            w.write(m.PressureSample(T0 + i * 40_000_000, 1e5))
            w.write(make_scan(T0 + i * 40_000_000, n=181, seed=i), topic=t.SCAN)
            if i % 50 == 49:
                w.flush()
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "INCOMPLETE" not in out
    assert "baromap.PressureSample" in out and "foxglove.LaserScan" in out
    assert "25.00 Hz" in out  # 200 samples 40 ms apart
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size * 2 // 3])
    assert main(["info", str(cut)]) == 3
    out = capsys.readouterr().out
    assert "INCOMPLETE" in out and "not closed cleanly" in out
    assert "/baro" in out


@pytest.mark.parametrize(
    "options",
    [
        {"compression": "NONE"},
        {"compression": "LZ4", "chunk_size": 2000},
        {"compression": "ZSTD", "chunk_size": 2000, "index_types": "NONE"},
        {"use_chunking": False},
    ],
    ids=["uncompressed", "lz4", "no-indexes", "unchunked"],
)
def test_files_from_other_writers_read_as_the_mcap_package_reads_them(
    tmp_path: Path, options: dict[str, object]
) -> None:
    """Chunks with and without compression or message indexes, and no chunks at all."""
    from mcap.writer import CompressionType, IndexType, Writer

    kwargs = dict(options)
    if "compression" in kwargs:
        kwargs["compression"] = CompressionType[str(kwargs["compression"])]
    if "index_types" in kwargs:
        kwargs["index_types"] = IndexType[str(kwargs["index_types"])]
    path = tmp_path / "other.mcap"
    with path.open("wb") as f:
        writer = Writer(f, **kwargs)  # type: ignore[arg-type]
        writer.start(profile="", library="test")
        schema = writer.register_schema("baromap.PressureSample", "jsonschema", b"{}")
        baro = writer.register_channel(t.BARO, "json", schema)
        other = writer.register_channel("/other", "json", schema)
        for i in range(300):
            sample = jsonmsg.dumps(m.PressureSample(T0 + i, 1000.0 + i))
            writer.add_message(baro if i % 3 else other, T0 + i, sample, T0 + i)
        writer.finish()
    with path.open("rb") as f:
        expected = [
            (c.topic, msg.log_time)
            for _, c, msg in make_reader(f).iter_messages(log_time_order=True)
        ]
    got = [(rec.topic, rec.log_time_ns) for rec in read_messages(path)]
    assert got == expected
    series = load_pressure(path)
    assert series.t_ns.tolist() == [T0 + i for i in range(300) if i % 3]


def test_detect_calls_a_false_mcap_what_it_is(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from baromap.cli.main import main

    fake = tmp_path / "run.mcap"
    fake.write_text("time_s,pressure_pa\n0,101325\n")
    assert main(["detect", str(fake)]) == 1
    assert "is named .mcap but is not an MCAP" in capsys.readouterr().err


def test_run_parts_orders_a_runs_files_and_refuses_what_is_not_one_run(tmp_path: Path) -> None:
    """The files of a rotated run come in the order of their parts whatever order they are
    named in; runs of one robot are taken across restarts only when asked, in time order,
    and said in the log when hours apart; other robots and overlapping runs are refused."""
    from structlog.testing import capture_logs

    from baromap.errors import ConfigError
    from baromap.recording.run_parts import run_parts

    hour = 3600 * 10**9

    def part(name: str, robot: str, run: str, number: int, t_ns: int) -> Path:
        path = tmp_path / name
        meta = {"run": run, "part": str(number)}
        with RecordingWriter(path, robot=robot, metadata=meta) as writer:
            writer.write(m.PressureSample(t_ns, 101325.0, 21.0, seq=1))
            writer.write(m.PressureSample(t_ns + 10**9, 101325.0, 21.0, seq=2))
        return path

    first, second = (
        part("a.mcap", "r1", "run1", 0, T0),
        part("b.mcap", "r1", "run1", 1, T0 + 2 * 10**9),
    )
    assert run_parts([second, first]) == (first, second)
    assert run_parts(tmp_path) == (first, second)
    later = part("c.mcap", "r1", "run2", 0, T0 + 3 * hour)
    with pytest.raises(ConfigError, match="different runs"):
        run_parts([first, later])
    with capture_logs() as logs:
        assert run_parts([later, second, first], across_runs=True) == (first, second, later)
    apart = [e["apart_min"] for e in logs if e["event"].startswith("runs far apart")]
    assert apart == [pytest.approx(180.0, abs=0.1)]
    overlapping = part("d.mcap", "r1", "run3", 0, T0 + 1)
    with pytest.raises(ConfigError, match="overlap in time"):
        run_parts([first, overlapping], across_runs=True)
    other = part("e.mcap", "r2", "run1", 2, T0 + 4 * 10**9)
    with pytest.raises(ConfigError, match="different robots"):
        run_parts([first, other])
    with pytest.raises(ConfigError, match="given twice"):
        run_parts([first, first])
