"""The barometer session against the real firmware, running in simavr (``make -C firmware``).

The same ELF that goes onto the board answers the session's IDENTIFY, SET_RATE and
SET_OVERSAMPLING; the daemon records its samples with the device clock fitted to the host's.
"""

from __future__ import annotations

import itertools
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from daemon_rig import Rig, RunningDaemon, make_config, read_all

from baromap import messages
from baromap.recording import read_metadata, topics

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "firmware"))
from firmware_board import ELF, HARNESS, SimulatedBoard

pytestmark = pytest.mark.firmware


@pytest.fixture
def board_port(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[str]:
    if request.config.getoption("--baro-port"):
        pytest.skip("runs the firmware in simavr; a real board is covered by the rig's tests")
    if not (ELF.is_file() and HARNESS.is_file()):
        pytest.skip("firmware or simavr harness not built: make -C firmware")
    board = SimulatedBoard(tmp_path, speed=1.0)
    try:
        assert board.link is not None
        path = board.link.port.port
        board.link.port.close()  # the daemon opens it itself
        board.link = None
        yield path
    finally:
        board.close()


def test_the_daemon_records_the_real_firmware(board_port: str, tmp_path: Path) -> None:
    rig = Rig({"barometer": board_port}, None, tmp_path)
    with RunningDaemon(make_config(rig, devices=("barometer",))) as run:
        run.wait_up(("barometer",), timeout=30)
        up_at = time.monotonic()
        time.sleep(4.0)
        up_s = time.monotonic() - up_at
        health = run.daemon.health()[0]
    records = read_all(run.daemon.recorder.files)
    samples = [r.message for r in records if r.topic == topics.BARO]
    assert all(isinstance(s, messages.PressureSample) for s in samples)
    assert len(samples) >= 0.5 * 50 * up_s  # the rate the session set (default is 25 Hz)
    seqs = [s.seq for s in samples]
    assert all((b - a) % 65536 == 1 for a, b in itertools.pairwise(seqs))
    stamps = np.array([s.t_ns for s in samples])
    assert np.all(np.diff(stamps) > 0)
    # Fitted to the board's clock: 50 Hz spacing within a millisecond, not USB jitter.
    spacing_ms = np.diff(stamps)[len(stamps) // 2 :] / 1e6
    assert np.median(np.abs(spacing_ms - 20.0)) < 1.0
    assert 30_000 < samples[-1].pressure_pa < 110_000
    identity = read_metadata(run.daemon.recorder.files[0])["baromap.device.barometer"]
    assert identity["sensor"] == "BMP280" and identity["firmware_version"].count(".") == 2
    assert health.counters.get("board_sensor_state") == 2  # STATUS frames reach health
