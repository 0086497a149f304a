"""The recorder: rotation without loss or duplicates, the disk guard, a full queue."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from mcap.records import Chunk
from mcap.stream_reader import StreamReader

from baromap.errors import RecordingError
from baromap.messages import DeviceState, PressureSample
from baromap.recording import RecordingWriter, read_messages, read_metadata, topics
from baromapd import recorder as recorder_module
from baromapd.config import ConfigProblems, RecordingConfig, parse_config
from baromapd.recorder import LatencyHistogram, Recorder


def _recorder(tmp_path: Path, **settings: float) -> Recorder:
    config = RecordingConfig(directory=tmp_path, min_free_mb=0.0, **settings)  # type: ignore[arg-type]
    return Recorder(config, robot="r1", metadata={"role": "robot"}, run_name="r1_test")


def _samples(n: int, t0: int = 1_700_000_000_000_000_000) -> list[PressureSample]:
    return [
        PressureSample(t0 + i * 20_000_000, 100000.0 + i, 20.0, i % 65536, i * 20_000)
        for i in range(n)
    ]


def test_rotation_by_size_loses_and_repeats_nothing(tmp_path: Path) -> None:
    rec = _recorder(tmp_path, rotate_size_mb=0.02, flush_interval_s=0.05)
    rec.start()
    rec.set_device_metadata("barometer", {"firmware_version": "1.0.0"})
    sent = _samples(3000)
    for i, sample in enumerate(sent):
        rec.offer(sample)
        if i % 200 == 0:
            time.sleep(0.06)  # let flushes happen, so sizes grow on disk
    rec.close()
    assert len(rec.files) >= 3
    got = [r.message.seq for path in rec.files for r in read_messages(path, [topics.BARO])]
    assert got == [s.seq for s in sent]
    for path in rec.files:  # each file stands alone: run metadata and device identities
        meta = read_metadata(path)
        assert meta[topics.METADATA_NAME]["run"] == "r1_test"
        assert meta["baromap.device.barometer"]["firmware_version"] == "1.0.0"


def test_rotation_by_duration(tmp_path: Path) -> None:
    rec = _recorder(tmp_path, rotate_minutes=0.5 / 60)
    rec.start()
    for sample in _samples(20):
        rec.offer(sample)
        time.sleep(0.05)
    rec.close()
    assert len(rec.files) >= 2
    got = [r.message.seq for path in rec.files for r in read_messages(path, [topics.BARO])]
    assert got == list(range(20))


def test_the_disk_guard_stops_writing_cleanly_and_resumes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    free = [10_000.0]
    monkeypatch.setattr(Recorder, "_free_mb", lambda self: free[0])
    config = RecordingConfig(directory=tmp_path, min_free_mb=100.0, flush_interval_s=0.05)
    rec = Recorder(config, robot="r1", metadata={}, run_name="r1_guard")
    rec.start()
    samples = _samples(30)
    for sample in samples[:10]:
        rec.offer(sample)
    time.sleep(0.3)
    free[0] = 50.0
    time.sleep(0.3)
    paused = rec.health(0)
    for sample in samples[10:20]:
        rec.offer(sample)
    time.sleep(0.3)
    free[0] = 10_000.0
    time.sleep(0.3)
    for sample in samples[20:]:
        rec.offer(sample)
    rec.close()
    assert paused.state is DeviceState.DOWN and "disk guard" in paused.detail
    assert rec.lost["PressureSample"] == 10
    assert len(rec.files) == 2  # the first finished cleanly, writing resumed in a second
    got = [r.message.seq for path in rec.files for r in read_messages(path, [topics.BARO])]
    assert got == list(range(10)) + list(range(20, 30))


def test_a_full_queue_is_counted_never_blocks(tmp_path: Path) -> None:
    rec = _recorder(tmp_path, queue_size=5)
    # Not started: nothing drains the queue.
    started = time.monotonic()
    for sample in _samples(50):
        rec.offer(sample)
    assert time.monotonic() - started < 1.0
    assert rec.dropped["PressureSample"] == 45
    assert rec.health(0).state is DeviceState.DEGRADED


def test_latency_percentiles() -> None:
    hist = LatencyHistogram()
    for us in range(1, 1001):
        hist.add(us * 1000)
    assert 980_000 <= hist.percentile_ns(99) <= 1_000_000
    assert 480_000 <= hist.percentile_ns(50) <= 520_000
    assert recorder_module.LATENCY_BIN_NS == 20_000


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_the_compression_setting_reaches_the_chunks(tmp_path: Path, compression: str) -> None:
    config = parse_config(
        f'robot = "r1"\n[recording]\ndirectory = "{tmp_path}"\nmin_free_mb = 0\n'
        f'compression = "{compression}"\nflush_interval_s = 0.05\n'
        '[barometer]\nport = "loop://"\n'
    )
    rec = Recorder(config.recording, robot="r1", metadata={"role": "robot"}, run_name="r1_c")
    rec.start()
    for i, sample in enumerate(_samples(500)):
        rec.offer(sample)
        if i % 100 == 0:
            time.sleep(0.06)  # several chunks
    rec.close()
    with rec.files[0].open("rb") as f:
        chunks = [r for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(chunks) >= 2
    assert {c.compression for c in chunks} == {"" if compression == "none" else compression}
    got = [r.message.seq for r in read_messages(rec.files[0], [topics.BARO])]
    assert got == list(range(500))


def test_an_unknown_compression_is_refused_by_key() -> None:
    with pytest.raises(ConfigProblems, match=r"recording\.compression: 'gzip' is not one of"):
        parse_config('robot = "r1"\n[recording]\ncompression = "gzip"\n[base]\nport = "loop://"\n')
    with pytest.raises(RecordingError, match="compression must be one of zstd, lz4, none"):
        RecordingWriter(Path("unused.mcap"), robot="r1", compression="brotli")
