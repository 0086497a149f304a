"""Power cycles and clock steps during a run: the recording stays continuous and monotonic."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest
from daemon_rig import Rig, RunningDaemon, make_config, read_all

from baromap.protocols import lms200
from baromap.recording import topics
from baromap.sim.twins import SimDevices


def _power_cycle_laser(twins: SimDevices) -> None:
    """Cut the laser's power briefly: it comes back at 9600 baud and says so with ``90``."""
    twin = twins.lms200
    power_cycle = getattr(twin, "power_cycle", None)
    if power_cycle is not None:
        power_cycle(0.5)
        return
    twin.port.stall(0.5)
    time.sleep(0.5)
    twin.power_on()
    twin.port.send(lms200.encode_reply(0x90, b"LMS200;30106 V02.10 LMS ready"))


def test_a_laser_power_cycle_mid_run_reinitialises_it_and_the_rest_loses_nothing(
    rig: Rig, twins: SimDevices
) -> None:
    with RunningDaemon(make_config(rig)) as run:
        run.wait_up()
        time.sleep(1.0)
        cut_ns = run.daemon.clock.now_unix_ns()
        _power_cycle_laser(twins)
        run.wait_until(
            lambda: (
                next(h for h in run.daemon.health() if h.device == "laser").counters.get(
                    "restarts", 0
                )
                >= 1
            ),
            10,
            "the laser session saw the power-on telegram",
        )
        run.wait_up(("laser",))
        time.sleep(1.5)
        laser = next(h for h in run.daemon.health() if h.device == "laser")
    records = read_all(run.daemon.recorder.files)
    scans = [r.message for r in records if r.topic == topics.SCAN]
    after = [s for s in scans if s.t_ns > cut_ns + 2_000_000_000]
    assert after, "scans resumed after the power cycle"
    assert laser.counters["connects"] == 1 + laser.counters["restarts"]  # same port, no replug
    diagnostics = [r.message for r in records if r.topic == topics.DIAGNOSTICS]
    assert any(
        d.device == "laser" and "re-initialising" in d.detail and "power" in d.detail
        for d in diagnostics
    )
    stamps = np.array([s.t_ns for s in scans])
    assert np.diff(stamps).max() > 0.3e9  # the recording shows the gap...
    baro = [r.message for r in records if r.topic == topics.BARO]
    seqs = [m.seq for m in baro]
    assert all((b - a) % 65536 == 1 for a, b in itertools.pairwise(seqs))  # ...and no other


def test_a_wall_clock_step_during_a_run_leaves_time_stamps_monotonic(
    rig: Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    real_time_ns, real_time = time.time_ns, time.time
    with RunningDaemon(make_config(rig)) as run:
        run.wait_up()
        time.sleep(1.0)
        # Someone (or NTP) sets the clock back an hour, then forward again.
        monkeypatch.setattr(time, "time_ns", lambda: real_time_ns() - 3600 * 10**9)
        monkeypatch.setattr(time, "time", lambda: real_time() - 3600.0)
        time.sleep(1.5)
        monkeypatch.setattr(time, "time_ns", real_time_ns)
        monkeypatch.setattr(time, "time", real_time)
        time.sleep(1.0)
    end_ns = run.daemon.clock.now_unix_ns()
    start_ns = run.daemon.clock.wall0_ns
    records = read_all(run.daemon.recorder.files)
    for topic in (topics.BARO, topics.SCAN, topics.ODOM):
        stamps = np.array([r.message.t_ns for r in records if r.topic == topic])
        assert len(stamps) > 10
        assert np.all(np.diff(stamps) > 0), f"{topic} went backwards"
        assert stamps.min() > start_ns - 10**9 and stamps.max() <= end_ns
