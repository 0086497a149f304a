"""Devices failing under the daemon: unplug and replug, garbage, a stall, a new USB path.

Whatever one device does, the daemon does not crash, the other streams lose nothing, and
health (live and on ``/diagnostics``) says what happened.
"""

from __future__ import annotations

import itertools
import os
import time

from daemon_rig import Rig, RunningDaemon, make_config, read_all

from baromap import messages
from baromap.discovery import SerialDevice, UsbIdentity, resolve_port
from baromap.messages import DeviceState
from baromap.recording import topics
from baromap.sim.twins import SimDevices


def _stream(records: list, topic: str) -> list:
    return [r.message for r in records if r.topic == topic]


def _health(records: list, device: str) -> list[messages.DeviceHealth]:
    return [m for m in _stream(records, topics.DIAGNOSTICS) if m.device == device]


def test_each_device_fails_and_recovers_while_the_others_record(
    rig: Rig, twins: SimDevices, tap_program: list[str]
) -> None:
    """With each implementation of the laser's tap: its port unplugged ends it, a new one
    starts at the replug, and the handshake's flushes go through it."""
    config = make_config(rig)
    with RunningDaemon(config) as run:
        run.wait_up()
        clock = run.daemon.clock
        t_fault = clock.now_unix_ns()
        samples_before = twins.baro.samples_sent
        # The laser is unplugged, then plugged back in at the same path.
        twins.lms200.unplug()
        run.wait_until(lambda: run.states()["laser"] is DeviceState.DOWN, 5, "laser down")
        down_detail = run.daemon.health()[0].detail
        time.sleep(0.5)
        twins.lms200.replug()
        run.wait_up(("laser",))
        # A burst of line noise on the barometer's line.
        twins.baro.inject_garbage(bytes(range(1, 256)) * 8)
        # The base goes silent for longer than its silence limit.
        twins.p3at.stall(2.5)
        run.wait_until(lambda: run.states()["base"] is DeviceState.DOWN, 5, "base down")
        base_detail = next(h.detail for h in run.daemon.health() if h.device == "base")
        run.wait_up(("base",), timeout=15)
        time.sleep(1.0)
        t_end = clock.now_unix_ns()
        samples_during = twins.baro.samples_sent - samples_before
        counters = {h.device: dict(h.counters) for h in run.daemon.health()}
    assert "port failed" in down_detail
    assert "silent" in base_detail
    assert counters["laser"]["connects"] >= 2
    assert counters["base"]["connects"] >= 2
    assert any(k.startswith("bad_") for k in counters["barometer"])

    records = read_all(run.daemon.recorder.files)
    # The barometer lost nothing through all of it: every sequence number is there.
    baro = [m for m in _stream(records, topics.BARO) if m.t_ns >= t_fault]
    seqs = [m.seq for m in baro]
    assert all((b - a) % 65536 == 1 for a, b in itertools.pairwise(seqs))
    # every sample the board sent meanwhile is there (a stamp's edge case aside)
    assert len([m for m in baro if m.t_ns <= t_end]) >= samples_during - 2
    # Scans kept coming while the base was silent, odometry while the laser was unplugged.
    assert len(_stream(records, topics.SCAN)) > 0
    laser_health = _health(records, "laser")
    base_health = _health(records, "base")
    assert any(h.state is DeviceState.DOWN and "port failed" in h.detail for h in laser_health)
    assert any(h.state is DeviceState.DOWN and "silent" in h.detail for h in base_health)
    for health in (laser_health, base_health):  # and both were back up before the daemon stopped
        running = [h for h in health if h.detail != "stopped"]
        assert running[-1].state in (DeviceState.UP, DeviceState.DEGRADED)
        assert running[-1].detail != "handshake"


def test_a_replug_at_a_new_path_is_found_by_usb_identity(rig: Rig, twins: SimDevices) -> None:
    """The laser named by USB identity comes back as another tty; no restart needed."""
    identity = UsbIdentity(0x0403, 0x6001, "LASER1")
    port = twins.lms200.port
    misses = 0  # retries that looked for the identity while it was unplugged

    def resolve(spec: str) -> str:
        # What pyserial's port list says now: the twin's current pty carries the identity.
        nonlocal misses
        attached = [SerialDevice(path=port.slave_path, usb=identity)] if port.plugged else []
        if not attached:
            misses += 1
        return resolve_port(spec, attached)

    def laser_detail() -> str:
        return next(h.detail for h in run.daemon.health() if h.device == "laser")

    rig.ports["laser"] = str(identity)
    config = make_config(rig, devices=("laser",))
    # Deadlines, not pauses: on a loaded machine the retries and the handshake come late.
    with RunningDaemon(config, resolve=resolve) as run:
        run.wait_up(("laser",), timeout=30)
        first_path = next(h.port for h in run.daemon.health() if h.device == "laser")
        twins.lms200.unplug()
        run.wait_until(lambda: run.states()["laser"] is DeviceState.DOWN, 30, "laser down")
        # Two retries found no such device, and health says so.
        run.wait_until(
            lambda: misses >= 2 and "no serial device with USB identity" in laser_detail(),
            30,
            "two retries found no device with the identity",
        )
        detail = laser_detail()
        blocker = os.openpty()  # holds the old pty number, as another device would
        try:
            twins.lms200.replug()
        finally:
            for fd in blocker:
                os.close(fd)
        run.wait_up(("laser",), timeout=60)
        second_path = next(h.port for h in run.daemon.health() if h.device == "laser")
    assert "no serial device with USB identity 0403:6001:LASER1" in detail
    assert first_path != second_path
    assert second_path == port.slave_path


def test_base_and_barometer_unplugged_garbage_and_a_stall_on_the_laser(
    rig: Rig, twins: SimDevices
) -> None:
    """The other half: the base and the board pulled and put back, the laser garbled and
    silent for a moment; the laser's scans go on through the first, the others through
    the second."""
    config = make_config(rig)
    with RunningDaemon(config) as run:
        run.wait_up()
        clock = run.daemon.clock
        t0 = clock.now_unix_ns()
        scans_before = twins.lms200.scans_sent
        twins.p3at.unplug()
        twins.baro.unplug()
        run.wait_until(
            lambda: (
                run.states()["base"] is DeviceState.DOWN
                and run.states()["barometer"] is DeviceState.DOWN
            ),
            5,
            "base and barometer down",
        )
        time.sleep(0.5)
        twins.p3at.replug()
        twins.baro.replug()
        run.wait_up(("base", "barometer"))
        time.sleep(1.0)
        t1 = clock.now_unix_ns()
        scans_during = twins.lms200.scans_sent - scans_before
        sips_before = twins.p3at.sips_sent
        twins.lms200.inject_garbage(bytes(range(256)) * 4)
        time.sleep(0.3)  # on the line before the silence (a stall drops what is queued)
        twins.lms200.stall(2.0)
        run.wait_until(lambda: run.states()["laser"] is not DeviceState.UP, 5, "the laser noticed")
        run.wait_up(("laser",), timeout=20)
        time.sleep(0.5)
        t2 = clock.now_unix_ns()
        sips_during = twins.p3at.sips_sent - sips_before
        counters = {h.device: dict(h.counters) for h in run.daemon.health()}
    assert counters["base"]["connects"] >= 2 and counters["barometer"]["connects"] >= 2
    assert any(k.startswith("bad_") for k in counters["laser"])
    records = read_all(run.daemon.recorder.files)
    # Whatever the twins sent while the others were failing was recorded (counts, not gaps:
    # on a loaded machine the twins themselves may pause).
    scans = [m for m in _stream(records, topics.SCAN) if t0 <= m.t_ns <= t1]
    assert len(scans) >= scans_during - 2
    baro = [m for m in _stream(records, topics.BARO) if t1 <= m.t_ns <= t2]
    odom = _stream(records, topics.ODOM)
    assert len([m for m in odom if t1 <= m.t_ns <= t2]) >= sips_during - 2
    assert all((b.seq - a.seq) % 65536 == 1 for a, b in itertools.pairwise(baro))
    laser = _health(records, "laser")
    assert any(h.state is not DeviceState.UP and h.t_ns >= t1 for h in laser)


def test_laser_garbage_is_reported_as_garbage_not_silence(rig: Rig, twins: SimDevices) -> None:
    """Bytes that make no frame for longer than the laser's silence limit (1 s here, garbage
    2 s): the line is not silent, it is garbled, and health says so."""
    config = make_config(rig)
    with RunningDaemon(config) as run:
        run.wait_up()
        # 160 kB: about 3.2 s of line time at 500 kbaud, no valid telegram in it
        twins.lms200.inject_garbage(bytes(range(1, 256)) * 640)
        working = (DeviceState.UP, DeviceState.DEGRADED)  # degraded: bad frames counted
        run.wait_until(lambda: run.states()["laser"] not in working, 8, "laser given up on")
        detail = next(h.detail for h in run.daemon.health() if h.device == "laser")
    assert "garbage" in detail and "silent" not in detail, detail
