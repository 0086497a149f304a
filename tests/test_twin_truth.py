"""The twins' truth records: each frame matched to the instant its content was true."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest
import serial

from baromap.cli.main import main
from baromap.errors import ConfigError
from baromap.protocols import baro
from baromap.sim.scenario import make_scenario
from baromap.sim.twins import BaroTwin, SimClock
from baromap.sim.twins.truth import JsonlTruthWriter, TruthLog, read_truth_log

SCENARIO = make_scenario(2, floors=3, minutes=5.0)


def test_a_truth_log_is_bounded_and_finds_frames_by_index_and_seq() -> None:
    seen = []
    truth = TruthLog("baro", capacity=3, sink=seen.append)
    for i in range(5):
        truth.record(1000 + i, i / 25, boot=i // 4, seq=i % 4)
    assert truth.count == 5 and len(truth.records()) == 3 and len(seen) == 5
    assert truth.by_index(1) is None  # no longer kept
    assert truth.by_index(4).t_mono_ns == 1004
    assert truth.by_seq(0).t_mono_ns == 1004  # the latest seq 0: after the restart
    assert truth.by_seq(3, boot=0).t_mono_ns == 1003
    assert truth.by_seq(3, boot=1) is None
    with pytest.raises(ConfigError):
        TruthLog("baro", capacity=0)


def test_barometer_samples_carry_the_instant_they_were_measured(tmp_path: Path) -> None:
    with BaroTwin(SimClock(SCENARIO)) as twin:
        decoder = baro.Decoder()
        with serial.serial_for_url(twin.path, baudrate=115200, timeout=0.05) as port:
            frames: list[object] = []
            deadline = time.monotonic() + 10.0  # a loaded machine may be slow to give 3
            while time.monotonic() < deadline and (
                sum(isinstance(f, baro.SampleFrame) for f in frames) < 3
            ):
                frames += decoder.feed(port.read(max(1, port.in_waiting)))
            received_ns = time.monotonic_ns()
    samples = [f for f in frames if isinstance(f, baro.SampleFrame)]
    assert len(samples) >= 3
    for sample in samples:
        truth = twin.truth.by_seq(sample.seq, boot=0)
        assert truth is not None and truth.device == "baro"
        assert truth.t_mono_ns < received_ns  # measured before the host read it
    # The board's own clock (time_us) runs with the truth: equal spans, to a millisecond.
    a, b = samples[0], samples[-1]
    truth_span = twin.truth.by_seq(b.seq).t_mono_ns - twin.truth.by_seq(a.seq).t_mono_ns
    assert (b.time_us - a.time_us) * 1000 == pytest.approx(truth_span, abs=1e6)


def test_baromap_sim_writes_the_truth_as_json_lines(tmp_path: Path) -> None:
    log = tmp_path / "truth.jsonl"
    args = ["sim", "--duration", "0.8", "--floors", "3", "--minutes", "5"]

    def host() -> None:  # reads the barometer while the twins run, so its samples go out
        for _ in range(200):
            if (tmp_path / "baro").exists():
                break
            time.sleep(0.01)
        with serial.serial_for_url(str(tmp_path / "baro"), baudrate=115200, timeout=0.4) as port:
            port.read(4096)

    reader = threading.Thread(target=host)
    reader.start()
    code = main([*args, "--link-dir", str(tmp_path), "--truth-log", str(log)])
    reader.join()
    assert code == 0
    records = read_truth_log(log)
    samples = [r for r in records if r.device == "baro"]
    assert samples and all(r.seq is not None for r in samples)
    assert [r.index for r in samples] == list(range(len(samples)))
    first = json.loads(log.read_text().splitlines()[0])
    assert {"device", "index", "t_mono_ns", "t_sim_s", "boot"} <= set(first)


def test_the_truth_log_file_must_be_writable(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="truth log"):
        JsonlTruthWriter(tmp_path / "missing" / "truth.jsonl")
