"""The bar's other half: when Zenoh cannot connect, or its peer accepts and never answers,
``baromapd`` records on at full rate.

The daemon runs on the three pty twins, in this process, with its publisher configured
towards nowhere. Full rate, told without a stopwatch: every barometer frame the twin sent
while the daemon was up is in the recording (sequence numbers without a gap: a reader held up
even briefly would have let the board's frames pile up and be lost), the recorder dropped
nothing, the laser and the base kept coming, and the publisher says what happened to it.
"""

from __future__ import annotations

import itertools
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from procs import endpoint, free_port

from baromap.messages import DeviceState, LaserScan, Odometry, PressureSample
from baromap.recording import read_messages, topics
from baromap.sim.twins import SimDevices
from baromapd.app import Daemon
from baromapd.config import parse_config

RUN_S = 4.0
#: The twins and the daemon share this process: on a loaded machine all its threads can be held
#: up together for a second or more. The twins then skip what they could not send (no sequence
#: gap), but a daemon at its default 1-2 s silence limit would take the pause for a dead device
#: and set it up again, and the samples read during that handshake are not recorded: a gap the
#: router has nothing to do with. Silence detection is tested elsewhere; here it waits.
PATIENT = "silence_s = 60\ngarbage_s = 60\n"


@pytest.fixture
def twins(tmp_path: Path) -> Iterator[SimDevices]:
    with SimDevices(link_dir=tmp_path / "links", minutes=30, seed=3) as sim:
        yield sim


@pytest.fixture
def mute_peer() -> Iterator[str]:
    """An endpoint whose connections the kernel accepts and nobody ever speaks on."""
    with socket.socket() as mute:
        mute.bind(("127.0.0.1", 0))
        mute.listen(64)
        yield endpoint(mute.getsockname()[1])


def run_daemon(twins: SimDevices, directory: Path, zenoh_table: str) -> tuple[Daemon, dict]:
    paths = twins.paths()
    config = parse_config(
        f'robot = "r1"\n[recording]\ndirectory = "{directory}"\nmin_free_mb = 0\n'
        f'[laser]\nport = "{paths["lms200"]}"\nbaud = 500000\n{PATIENT}'
        f'[base]\nport = "{paths["p3at"]}"\n{PATIENT}'
        f'[barometer]\nport = "{paths["baro"]}"\nrate_hz = 50\n{PATIENT}'
        f"[zenoh]\n{zenoh_table}\n"
    )
    daemon = Daemon(config, view=False)
    assert daemon.live is not None, "the publisher is part of this run"
    thread = threading.Thread(target=daemon.run, name="test-baromapd")
    thread.start()
    try:
        deadline = time.monotonic() + 60
        while not all(
            h.state is DeviceState.UP
            for h in daemon.health()
            if h.device in ("laser", "base", "barometer")
        ):
            assert time.monotonic() < deadline, f"devices not up: {daemon.health()}"
            time.sleep(0.05)
        sent_before = twins.baro.samples_sent
        time.sleep(RUN_S)
        sent = twins.baro.samples_sent - sent_before
        health = {h.device: h for h in daemon.health()}
    finally:
        daemon.request_stop()
        thread.join(60)
    assert not thread.is_alive(), "the daemon did not stop"
    return daemon, {"sent": sent, "health": health}


def check_full_rate(daemon: Daemon, sent: int) -> None:
    records = [r for path in daemon.recorder.files for r in read_messages(path)]
    baro = [r.message for r in records if r.topic == topics.BARO]
    assert all(isinstance(m, PressureSample) for m in baro)
    seqs = [m.seq for m in baro]
    assert all((b - a) % 65536 == 1 for a, b in itertools.pairwise(seqs)), "frames were lost"
    assert len(baro) >= sent  # every frame sent while we watched (and those around it)
    assert any(isinstance(r.message, LaserScan) for r in records)
    assert any(isinstance(r.message, Odometry) for r in records)
    assert not daemon.recorder.dropped, f"the recorder dropped {dict(daemon.recorder.dropped)}"


def test_recording_goes_on_when_no_router_can_be_reached(tmp_path: Path, twins: SimDevices) -> None:
    nowhere = endpoint(free_port())
    daemon, seen = run_daemon(
        twins, tmp_path / "rec", f'mode = "client"\nconnect = ["{nowhere}"]\nretry_max_s = 0.5'
    )
    check_full_rate(daemon, seen["sent"])
    zenoh = seen["health"]["zenoh"]
    assert zenoh.state is DeviceState.DEGRADED and zenoh.detail == "connecting"
    assert zenoh.counters["open_failures"] >= 2
    assert zenoh.counters["published"] == 0
    assert zenoh.counters["offered"] > seen["sent"]  # it was offered everything, took no time


def test_recording_goes_on_when_the_peer_never_answers(
    tmp_path: Path, twins: SimDevices, mute_peer: str
) -> None:
    zenoh_file = tmp_path / "zenoh.json5"  # a hung handshake is given up after 1 s, not 10
    zenoh_file.write_text("{ transport: { unicast: { open_timeout: 1000 } } }")
    daemon, seen = run_daemon(
        twins,
        tmp_path / "rec",
        f'listen = ["{endpoint(free_port())}"]\nconnect = ["{mute_peer}"]\n'
        f'config_file = "{zenoh_file}"',
    )
    check_full_rate(daemon, seen["sent"])
    zenoh = seen["health"]["zenoh"]
    assert zenoh.state is DeviceState.UP  # a peer opens alone and keeps trying its peers
    assert zenoh.counters["published"] > 0
    assert zenoh.counters["dropped_bulk"] == zenoh.counters["dropped_urgent"] == 0
