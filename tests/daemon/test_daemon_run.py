"""The daemon against the three devices (twins on ptys, or real ones): what a run records.

Counts, orderings and sequence continuity with generous slack; never rates over wall time.
"""

from __future__ import annotations

import itertools
import json
import time

import numpy as np
from daemon_rig import Rig, RunningDaemon, make_config, read_all

from baromap import messages
from baromap.odometry.robot_metadata import ROBOT_METADATA, model_from_metadata
from baromap.protocols import lms200
from baromap.recording import read_metadata, topics


def test_a_run_records_every_stream_with_identities(rig: Rig) -> None:
    config = make_config(rig)
    sim = rig.sim
    with RunningDaemon(config) as run:
        run.wait_up()
        up_at = time.monotonic()
        sent = (sim.lms200.scans_sent, sim.p3at.sips_sent, sim.baro.samples_sent) if sim else None
        time.sleep(4.0)
        up_s = time.monotonic() - up_at
        if sim is not None and sent is not None:
            sent = (
                sim.lms200.scans_sent - sent[0],
                sim.p3at.sips_sent - sent[1],
                sim.baro.samples_sent - sent[2],
            )
    files = run.daemon.recorder.files
    assert len(files) == 1
    if rig.sim is not None:  # left as found: the laser back at 9600 and idle, the robot closed
        assert rig.sim.lms200.port.baud == 9600
        assert rig.sim.lms200.mode == lms200.Mode.REQUEST
        assert rig.sim.p3at.session.value == "closed"
    records = read_all(files)
    by_topic: dict[str, list[messages.Message]] = {}
    for record in records:
        by_topic.setdefault(record.topic, []).append(record.message)
    for topic in (topics.BARO, topics.SCAN, topics.ODOM, topics.TF, topics.DIAGNOSTICS):
        assert by_topic.get(topic), f"nothing on {topic}"
    assert topics.FLOOR_STATE in by_topic

    if sent is not None:  # every frame the twins sent while all were up was recorded
        lost_on_line = {t.name: t.port.bytes_dropped for t in rig.sim.twins}  # type: ignore[union-attr]
        health = {h.device: dict(h.counters) for h in run.daemon.health()}
        for topic, n in zip((topics.SCAN, topics.ODOM, topics.BARO), sent, strict=True):
            assert len(by_topic[topic]) >= n, (
                f"{topic}: {len(by_topic[topic])} of {n}; twins dropped {lost_on_line}; {health}"
            )
        assert sent[0] >= 10 * up_s  # at 500 kbaud (9600 would carry 2.5 scans a second)
    else:  # real devices: at least half of LMS200 75 Hz, SIP 10 Hz, barometer 50 Hz
        assert len(by_topic[topics.SCAN]) >= 0.5 * 75 * up_s
        assert len(by_topic[topics.ODOM]) >= 0.5 * 10 * up_s
        assert len(by_topic[topics.BARO]) >= 0.5 * 50 * up_s
    assert len(by_topic[topics.TF]) >= len(by_topic[topics.ODOM])

    # Every stream in time order, and no barometer sample lost between board and file.
    for topic in (topics.BARO, topics.SCAN, topics.ODOM):
        stamps = np.array([m.t_ns for m in by_topic[topic]])
        assert np.all(np.diff(stamps) > 0), f"{topic} time stamps not increasing"
    seqs = [m.seq for m in by_topic[topics.BARO] if isinstance(m, messages.PressureSample)]
    assert all((b - a) % 65536 == 1 for a, b in itertools.pairwise(seqs))
    scans = [m for m in by_topic[topics.SCAN] if isinstance(m, messages.LaserScan)]
    assert {s.beam_count for s in scans} == {181}

    # Stamps lie within the run, on the host's clock mapped to Unix time.
    meta = read_metadata(files[0])
    header = meta[topics.METADATA_NAME]
    wall0 = int(header["clock_wall0_ns"])
    for m in by_topic[topics.BARO] + by_topic[topics.SCAN] + by_topic[topics.ODOM]:
        assert wall0 - 10**9 < m.t_ns < wall0 + 120 * 10**9

    # The metadata says what was recorded, from what.
    assert header["robot"] == "test"
    assert json.loads(header["laser_mount"]) == {"x_m": 0.0, "y_m": 0.0, "yaw_rad": 0.0}
    assert "[laser]" in header["configuration"]
    # /odom is one frame across the base's restarts, and the header says so to the mapping
    assert header[topics.ODOMETRY_TRACKS_KEY] == topics.ODOMETRY_TRACKS_JOINED
    laser = meta["baromap.device.laser"]
    base = meta["baromap.device.base"]
    barometer = meta["baromap.device.barometer"]
    assert laser["type"].startswith("LMS")
    assert laser["baud"] == "500000"
    assert base["subclass"] and base["model"]
    # ... and with what factors /odom's raw counters were turned into metres.
    robot = model_from_metadata(meta)
    assert robot is not None and robot.name == base["model"]
    assert meta[ROBOT_METADATA]["reported_subclass"] == base["subclass"]
    assert barometer["firmware_version"].count(".") == 2

    health = [m for m in by_topic[topics.DIAGNOSTICS] if isinstance(m, messages.DeviceHealth)]
    assert {h.device for h in health} >= {"laser", "base", "barometer", "recorder"}
    last = {h.device: h for h in health}
    assert last["recorder"].counters["messages"] > 0
