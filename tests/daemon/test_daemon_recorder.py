"""The recorder: rotation without loss or duplicates, the disk guard, a full queue."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from structlog.testing import capture_logs

from baromap.errors import RecordingError, RecordingWriteError
from baromap.messages import DeviceState, PressureSample
from baromap.recording import RecordingWriter, read_messages, read_metadata, topics
from baromap.recording.frames import LASER_MOUNT_KEY, LaserMount
from baromapd import recorder as recorder_module
from baromapd.config import ConfigProblems, RecordingConfig, parse_config
from baromapd.recorder import LatencyHistogram, Recorder


def _recorder(tmp_path: Path, **settings: float) -> Recorder:
    config = RecordingConfig(directory=tmp_path, min_free_mb=0.0, **settings)  # type: ignore[arg-type]
    return Recorder(config, robot="r1", metadata={"role": "robot"}, run_name="r1_test")


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The recorder's monotonic clock in the test's hand: ``clock[0]`` is now, in ns."""
    now = [10**15]
    monkeypatch.setattr(recorder_module.time, "monotonic_ns", lambda: now[0])
    return now


@pytest.fixture
def free_space_looks(monkeypatch: pytest.MonkeyPatch, clock: list[int]) -> list[int]:
    """When (``clock[0]``) the recorder looked at the free space: 1000 MB each time."""
    looked: list[int] = []

    def free_mb(self: Recorder) -> float:
        looked.append(clock[0])
        return 1000.0

    monkeypatch.setattr(Recorder, "_free_mb", free_mb)
    return looked


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
    with capture_logs() as logged:
        rec.start()
        for sample in _samples(20):
            rec.offer(sample)
            time.sleep(0.05)
        rec.close()
    rotations = [e for e in logged if e["event"] == "rotating recording"]
    assert rotations and all(e["reason"] == "rotation" for e in rotations)
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


class _FailingWrites:
    """Makes the recorder's writer fail as the MCAP library does on a full or failing disk: a
    ``RuntimeError`` (its FoxgloveError), not a BaromapError or an OSError."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, error: Exception) -> None:
        self.failing = False
        self.error = error
        real = RecordingWriter.write

        def write(writer: RecordingWriter, message: object, topic: str | None = None) -> None:
            if self.failing:
                raise self.error
            real(writer, message, topic)  # type: ignore[arg-type]

        monkeypatch.setattr(RecordingWriter, "write", write)


def _wait(predicate: object, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():  # type: ignore[operator]
            return
        time.sleep(0.02)
    pytest.fail("condition not reached")


def test_a_writer_failure_of_any_type_is_a_fault_said_once_and_a_new_file_follows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(recorder_module, "FAULT_RETRY_NS", 200_000_000)
    failing = _FailingWrites(monkeypatch, RuntimeError("FoxgloveError: MCAP error: I/O error"))
    rec = _recorder(tmp_path, flush_interval_s=0.05)
    with capture_logs() as logged:
        _fail_and_resume(rec, failing)
    assert rec.alive is False and rec.error is None, "the thread survived the fault"
    faults = [e for e in logged if e["event"] == "recorder fault"]
    assert len(faults) == 1, faults
    assert faults[0]["log_level"] == "error" and faults[0]["reason"].startswith("writer error")
    assert faults[0]["during"] == "write"
    assert rec.lost == {"PressureSample": 10}  # the one that failed and the nine after it
    assert [e["event"] for e in logged].count("recording resumes") == 1
    assert rec.fatal is None
    assert len(rec.files) == 2
    # the first file stopped at the fault (its first message in the fault is lost), the second
    # took everything after the retry
    got = [r.message.seq for path in rec.files for r in read_messages(path, [topics.BARO])]
    assert got == list(range(10)) + list(range(20, 30))


def _fail_and_resume(rec: Recorder, failing: _FailingWrites) -> None:
    rec.start()
    samples = _samples(30)
    for sample in samples[:10]:
        rec.offer(sample)
    _wait(lambda: rec.written[topics.BARO] == 10)
    failing.failing = True
    for sample in samples[10:20]:
        rec.offer(sample)
    _wait(lambda: rec.fault is not None and rec.backlog == 0)
    faulted = rec.health(0)
    failing.failing = False
    _wait(lambda: rec.fault is None)  # retried in a new file
    for sample in samples[20:]:
        rec.offer(sample)
    rec.close()
    assert faulted.state is DeviceState.DOWN
    assert faulted.detail.startswith("recorder fault: writer error: RuntimeError")
    assert faulted.counters["faults"] == 1


def test_a_full_disk_waits_for_space_then_resumes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    full = OSError(28, "No space left on device")
    failing = _FailingWrites(monkeypatch, RecordingWriteError("cannot write: I/O error", full))
    free: list[float | None] = [0.5]
    monkeypatch.setattr(Recorder, "_free_mb", lambda self: free[0])
    rec = _recorder(tmp_path, flush_interval_s=0.05)
    rec.start()
    samples = _samples(20)
    failing.failing = True
    rec.offer(samples[0])
    _wait(lambda: rec.fault is not None)
    failing.failing = False
    time.sleep(0.3)  # no room yet: no new file, however long it waits
    assert len(rec.files) == 1 and rec.fault is not None
    assert rec.health(0).detail.startswith("recorder fault: disk full")
    free[0] = None  # free space unknown: not taken for room
    time.sleep(0.2)
    assert len(rec.files) == 1
    free[0] = 5.0
    _wait(lambda: len(rec.files) == 2 and rec.fault is None)
    for sample in samples[1:]:
        rec.offer(sample)
    rec.close()
    assert rec.fatal is None
    assert [r.message.seq for r in read_messages(rec.files[1], [topics.BARO])] == list(range(1, 20))


def test_repeated_faults_make_the_recorder_give_up(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(recorder_module, "FAULT_RETRY_NS", 50_000_000)
    failing = _FailingWrites(monkeypatch, OSError(5, "Input/output error"))
    failing.failing = True
    rec = _recorder(tmp_path, flush_interval_s=0.05)
    rec.start()
    for sample in _samples(200):
        rec.offer(sample)
        time.sleep(0.005)
        if rec.fatal:
            break
    rec.close()
    assert rec.fatal is not None and "I/O error" in rec.fatal
    assert rec.faults == recorder_module.FATAL_FAULTS
    assert rec.health(0).detail.startswith("recorder gave up")


def test_free_space_that_cannot_be_read_is_unknown_not_infinite(tmp_path: Path) -> None:
    rec = _recorder(tmp_path / "gone")
    assert rec._free_mb() is None
    rec._guard_disk()  # no writer, no free space known: nothing opens, nothing raises
    assert rec.files == []


def test_cut_files_of_an_earlier_run_are_recovered_at_start(tmp_path: Path) -> None:
    import shutil as sh

    from mcap.reader import make_reader

    writer = RecordingWriter(tmp_path / "r1_old_000.mcap", robot="r1", flush_interval_s=3600)
    for sample in _samples(50):
        writer.write(sample)
    writer.flush()
    for sample in _samples(5, t0=1_800_000_000_000_000_000):
        writer.write(sample)
    sh.copy(tmp_path / "r1_old_000.mcap", tmp_path / "r1_cut_000.mcap")
    writer.close()
    (tmp_path / "r1_old_000.mcap").unlink()
    rec = _recorder(tmp_path)
    rec.start()
    _wait(lambda: rec.recovered)
    rec.close()
    (fixed,) = rec.recovered
    assert fixed.name == "r1_cut_000.recovered.mcap"
    assert (tmp_path / "r1_cut_000.mcap").exists(), "the original is kept"
    with fixed.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == 50
        assert len(list(reader.iter_messages())) == 50
    # this run's own file is not taken for a cut one, nor recovered again by the next run
    assert recorder_module.cut_recordings(tmp_path) == []


def test_fault_reasons_name_what_the_os_refused() -> None:
    import errno

    from baromapd.recorder import fault_reason

    def reason(code: int) -> str:
        return fault_reason(RecordingWriteError("cannot write", OSError(code, "refused")))

    assert reason(errno.ENOSPC).startswith("disk full: ")
    assert reason(errno.EDQUOT).startswith("disk full: ")
    assert reason(errno.EIO).startswith("I/O error: ")
    assert reason(errno.EROFS).startswith("read-only file system: ")
    assert reason(errno.EACCES).startswith("permission denied: ")
    assert reason(errno.EPERM).startswith("permission denied: ")
    assert reason(errno.ENOENT).startswith("OS error: ")
    assert fault_reason(OSError(errno.EIO, "x")) == "I/O error: [Errno 5] x"
    try:
        raise RuntimeError("library") from OSError(errno.ENOSPC, "full")
    except RuntimeError as exc:
        assert fault_reason(exc) == "disk full: library"
    assert fault_reason(RecordingWriteError("no os error")) == (
        "writer error: RecordingWriteError: no os error"
    )
    assert fault_reason(ValueError("v")) == "writer error: ValueError: v"


def test_the_retry_pause_doubles_to_its_cap_and_three_faults_in_a_minute_are_fatal(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    clock = [10**12]
    monkeypatch.setattr(recorder_module.time, "monotonic_ns", lambda: clock[0])
    rec = _recorder(tmp_path)
    first = recorder_module.FAULT_RETRY_NS
    with capture_logs() as logged:
        rec._fault("write", OSError(5, "bad block"))
        assert rec._retry_ns == clock[0] + first
        assert rec._retry_delay_ns == 2 * first
        assert rec.paused == "recorder fault: I/O error: [Errno 5] bad block"
        clock[0] += recorder_module.FAULT_WINDOW_NS + 1  # long past: the pause starts afresh
        rec._fault("flush", OSError(5, "bad block"))
        assert rec._retry_ns == clock[0] + first and rec.fatal is None
        for _ in range(4):
            rec._retry_delay_ns = min(rec._retry_delay_ns * 2, recorder_module.FAULT_RETRY_MAX_NS)
        assert rec._retry_delay_ns == recorder_module.FAULT_RETRY_MAX_NS
        clock[0] += 1
        rec._fault("write", OSError(5, "bad block"))
        assert rec.fatal is None  # two within the window
        clock[0] += 1
        rec._fault("open", OSError(5, "bad block"))
    assert rec.fatal == "3 faults within 60 s: I/O error: [Errno 5] bad block"
    assert rec.faults == 4
    said = [e for e in logged if e["event"] == "recorder fault"]
    assert said == [
        {
            "event": "recorder fault",
            "log_level": "error",
            "reason": "I/O error: [Errno 5] bad block",
            "during": "write",
            "path": None,
            "error": "OSError: [Errno 5] bad block",
        }
    ]
    assert [e for e in logged if e["event"] == "recorder gives up"] == [
        {"event": "recorder gives up", "log_level": "error", "reason": rec.fatal}
    ]


def test_a_full_disk_is_never_fatal(tmp_path: Path) -> None:
    rec = _recorder(tmp_path)
    for _ in range(10):
        rec._fault("write", OSError(28, "No space left on device"))
    assert rec.fatal is None and rec.faults == 10
    assert rec.paused == "recorder fault: disk full: [Errno 28] No space left on device"


def _cut_file(path: Path, n: int = 50) -> None:
    writer = RecordingWriter(path, robot="r1", flush_interval_s=3600)
    for sample in _samples(n):
        writer.write(sample)
    writer.flush()
    writer.write(_samples(1, t0=1_800_000_000_000_000_000)[0])
    copy = path.with_name("copy-" + path.name)
    import shutil as sh

    sh.copy(path, copy)
    writer.close()
    copy.replace(path)


def test_a_cut_file_is_left_alone_without_room_for_its_copy(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _cut_file(tmp_path / "r1_old_000.mcap")
    size_mb = (tmp_path / "r1_old_000.mcap").stat().st_size / 1e6
    rec = _recorder(tmp_path)
    for free in (None, size_mb / 2):
        monkeypatch.setattr(Recorder, "_free_mb", lambda self, free=free: free)
        with capture_logs() as logged:
            rec._recover([tmp_path / "r1_old_000.mcap"])
        (said,) = logged
        assert said["event"] == "cut recording not recovered: not enough free space"
        assert said["path"] == str(tmp_path / "r1_old_000.mcap")
        assert said["size_mb"] == round(size_mb, 1)
        assert said["free_mb"] == (None if free is None else round(free, 1))
    assert rec.recovered == []
    assert not (tmp_path / "r1_old_000.recovered.mcap").exists()


def test_a_cut_file_that_cannot_be_recovered_is_said_and_skipped(tmp_path: Path) -> None:
    from baromap.recording.recover import MCAP_MAGIC

    broken = tmp_path / "r1_broken_000.mcap"
    broken.write_bytes(MCAP_MAGIC + b"\x01\xff")  # cut inside its header
    good = tmp_path / "r1_good_000.mcap"
    _cut_file(good)
    rec = _recorder(tmp_path)
    with capture_logs() as logged:
        rec._recover(recorder_module.cut_recordings(tmp_path))
    failed, recovered = logged
    assert failed["event"] == "cut recording not recovered"
    assert failed["path"] == str(broken) and "header" in failed["error"]
    assert recovered["event"] == "cut recording recovered"
    assert recovered["path"] == str(good)
    assert recovered["recovered"] == str(tmp_path / "r1_good_000.recovered.mcap")
    assert recovered["messages"] == 50
    assert recovered["size"] == good.stat().st_size
    assert 0 < recovered["cut_at"] < recovered["size"]
    assert "length is unset" in recovered["reason"]
    assert rec.recovered == [tmp_path / "r1_good_000.recovered.mcap"]


def test_percentiles_at_their_edges() -> None:
    empty = LatencyHistogram()
    assert empty.percentile_ns(50) == 0
    assert len(empty.bins) == recorder_module.LATENCY_BINS + 1
    hist = LatencyHistogram()
    for _ in range(50):
        hist.add(10_000)  # bin 0
    for _ in range(50):
        hist.add(50_000)  # bin 2
    assert hist.percentile_ns(50) == 20_000  # half the samples are in bin 0: its upper edge
    assert hist.percentile_ns(51) == 50_000  # bin 2's edge is 60 us, no sample above 50 us
    one = LatencyHistogram()
    one.add(30_000)
    assert one.percentile_ns(50) == 30_000
    edge = LatencyHistogram()
    for _ in range(100):
        edge.add(0)
    edge.add(110_000)
    assert edge.percentile_ns(100) == 110_000
    assert (edge.count, edge.max_ns, edge.bins[0], edge.bins[5]) == (101, 110_000, 100, 1)


def test_health_says_each_state_with_its_counters(tmp_path: Path) -> None:
    rec = _recorder(tmp_path)
    fresh = rec.health(7)
    assert (fresh.t_ns, fresh.device, fresh.port) == (7, "recorder", str(tmp_path))
    assert (fresh.state, fresh.detail) == (DeviceState.UP, "recording none yet")
    assert fresh.counters == {"messages": 0, "files": 0, "backlog": 0, "faults": 0}
    rec.files.append(tmp_path / "r1_test_000.mcap")
    rec.written.update({topics.BARO: 3, topics.SCAN: 2})
    rec.latency[topics.BARO] = LatencyHistogram()
    rec.latency[topics.BARO].add(45_000)
    up = rec.health(0)
    assert (up.state, up.detail) == (DeviceState.UP, "recording r1_test_000.mcap")
    assert up.counters == {
        "messages": 5,
        "files": 1,
        "backlog": 0,
        "faults": 0,
        f"latency_p50_us{topics.BARO}": 45,
        f"latency_p99_us{topics.BARO}": 45,
    }
    rec.dropped["LaserScan"] = 4
    degraded = rec.health(0)
    assert degraded.state is DeviceState.DEGRADED
    assert degraded.detail == "queue overflowed: messages dropped"
    assert degraded.counters["dropped_queue_LaserScan"] == 4
    rec.lost["PressureSample"] = 2
    rec.paused = "disk guard: 5 MB free, below min_free_mb 10"
    paused = rec.health(0)
    assert (paused.state, paused.detail) == (DeviceState.DOWN, rec.paused)
    assert paused.counters["dropped_paused_PressureSample"] == 2
    rec.fatal = "3 faults within 60 s: I/O error"
    assert rec.health(0).detail == "recorder gave up: 3 faults within 60 s: I/O error"
    rec.error = "ValueError: bug"
    assert rec.health(0).detail == "writer thread failed: ValueError: bug"
    assert rec.health(0).state is DeviceState.DOWN


def test_the_guard_and_the_resumption_at_their_edges(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import shutil as sh
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(sh, "disk_usage", lambda path: usage(0, 0, 5_000_000))
    assert _recorder(tmp_path)._free_mb() == 5.0

    free: list[float | None] = [100.0]
    monkeypatch.setattr(Recorder, "_free_mb", lambda self: free[0])
    config = RecordingConfig(directory=tmp_path, min_free_mb=100.0)
    rec = Recorder(config, robot="r1", metadata={}, run_name="r1_edges")
    rec._open()
    rec._guard_disk()  # exactly the limit: still writing
    assert rec._writer is not None
    free[0] = 99.9
    rec._guard_disk()
    assert rec._writer is None and rec.paused is not None
    free[0] = 119.9  # the limit with 20 % headroom is 120
    rec._guard_disk()
    assert rec._writer is None
    free[0] = 120.0
    with capture_logs() as logged:
        rec._guard_disk()
    assert rec._writer is not None and rec.paused is None
    (resumed,) = [e for e in logged if e["event"] == "recording resumes"]
    assert resumed["after"] == "disk guard: 100 MB free, below min_free_mb 100"
    assert resumed["free_mb"] == 120.0
    # a full disk with no guard: 1 MB and its headroom before a new file
    rec._fault("write", OSError(28, "No space left on device"))
    rec.config = RecordingConfig(directory=tmp_path, min_free_mb=0.0)
    free[0] = 1.19
    rec._guard_disk()
    assert rec._writer is None
    free[0] = 1.2
    rec._guard_disk()
    assert rec._writer is not None and rec.fault is None
    # another fault: retried when its pause is over, not before
    rec._fault("write", OSError(5, "bad block"))
    free[0] = None
    due = rec._retry_ns
    monkeypatch.setattr(recorder_module.time, "monotonic_ns", lambda: due - 1)
    rec._guard_disk()
    assert rec._writer is None
    monkeypatch.setattr(recorder_module.time, "monotonic_ns", lambda: due)
    with capture_logs() as logged:
        rec._guard_disk()
    assert rec._writer is not None
    (resumed,) = [e for e in logged if e["event"] == "recording resumes"]
    assert resumed["after"] == "recorder fault: I/O error: [Errno 5] bad block"
    assert resumed["free_mb"] is None
    rec._close()


def test_a_failed_flush_is_a_fault_too(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(writer: RecordingWriter) -> bool:
        raise RecordingWriteError("cannot flush", OSError(5, "bad block"))

    rec = _recorder(tmp_path, flush_interval_s=0.05)
    rec._open()
    monkeypatch.setattr(RecordingWriter, "flush_if_due", refuse)
    with capture_logs() as logged:
        rec._flush_if_due()
    (fault,) = [e for e in logged if e["event"] == "recorder fault"]
    assert fault["during"] == "flush" and fault["reason"] == "I/O error: cannot flush"
    assert fault["error"] == "RecordingWriteError: cannot flush"
    assert rec._writer is None and rec.faults == 1


def test_latency_is_kept_per_topic_from_the_read(tmp_path: Path) -> None:
    rec = _recorder(tmp_path)
    rec.start()
    sample = _samples(1)[0]
    rec.offer_received(sample, time.monotonic_ns() - 5_000_000)  # read 5 ms ago
    rec.offer_received(sample, time.monotonic_ns() - 5_000_000)
    rec.close()
    hist = rec.latency[topics.BARO]
    assert hist.count == 2 and list(rec.latency) == [topics.BARO]
    assert 5_000_000 <= hist.max_ns < 60_000_000_000
    assert rec.health(0).counters[f"latency_p50_us{topics.BARO}"] >= 5_000


def test_the_syncer_fsyncs_what_it_is_asked_on_its_own_daemon_thread(tmp_path: Path) -> None:
    from baromapd.recorder import Syncer

    present = tmp_path / "a.mcap"
    present.write_bytes(b"x")
    with capture_logs() as logged:
        syncer = Syncer()
        assert (syncer._thread.name, syncer._thread.daemon) == ("baromapd-fsync", True)
        assert (syncer.syncs, syncer.errors) == (0, 0)
        syncer.request(present)
        _wait(lambda: syncer.syncs == 1)
        syncer.request(tmp_path / "moved-away.mcap")
        _wait(lambda: syncer.errors == 1)
        syncer.close(2.0)
    assert not syncer._thread.is_alive()
    assert (syncer.syncs, syncer.errors) == (1, 1)
    (warning,) = [e for e in logged if e["event"] == "fsync failed"]
    assert (
        warning["path"] == str(tmp_path / "moved-away.mcap") and "No such file" in warning["error"]
    )
    assert warning["log_level"] == "warning"


def test_closing_a_file_that_fails_is_a_fault_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def refuse(writer: RecordingWriter) -> None:
        raise RecordingWriteError("cannot close", OSError(28, "No space left on device"))

    rec = _recorder(tmp_path)
    rec._open()
    monkeypatch.setattr(RecordingWriter, "close", refuse)
    with capture_logs() as logged:
        rec._close()  # a close that fails while all was well: the fault, said
        rec._open()
        rec._close()  # and again while in that fault: only noted
    (fault,) = [e for e in logged if e["event"] == "recorder fault"]
    assert fault["during"] == "close" and fault["reason"] == "disk full: cannot close"
    (noted,) = [e for e in logged if e["event"] == "faulted recording left unfinished"]
    assert noted == {
        "event": "faulted recording left unfinished",
        "log_level": "debug",
        "path": str(rec.files[-1]),
    }


def test_an_unreadable_file_is_said_and_the_others_still_looked_at(tmp_path: Path) -> None:
    locked = tmp_path / "a_000.mcap"
    locked.mkdir()  # a directory by a recording's name: opening it fails
    _cut_file(tmp_path / "b_000.mcap")
    with capture_logs() as logged:
        assert recorder_module.cut_recordings(tmp_path) == [tmp_path / "b_000.mcap"]
    (said,) = logged
    assert said["event"] == "recording not readable" and said["path"] == str(locked)
    assert "Is a directory" in said["error"] and said["log_level"] == "warning"


def test_each_file_says_its_part_the_run_and_the_laser_mount(tmp_path: Path) -> None:
    """Every file stands alone: the run's metadata with the file's part number, and where
    the laser sits; each opening is logged with the file and its part."""
    mount = LaserMount(0.12, -0.03, 0.05)
    config = RecordingConfig(directory=tmp_path, min_free_mb=0.0)
    rec = Recorder(
        config, robot="r1", metadata={"role": "robot"}, run_name="r1_parts", laser_mount=mount
    )
    with capture_logs() as logged:
        for _ in range(2):
            rec._open()
            rec._close()
    assert [p.name for p in rec.files] == ["r1_parts_000.mcap", "r1_parts_001.mcap"]
    for part, path in enumerate(rec.files):
        meta = read_metadata(path)[topics.METADATA_NAME]
        assert (meta["part"], meta["run"], meta["role"]) == (str(part), "r1_parts", "robot")
        assert LaserMount.from_json(meta[LASER_MOUNT_KEY]) == mount
    opened = [e for e in logged if e["event"] == "recording file opened"]
    assert opened == [
        {"event": "recording file opened", "log_level": "info", "path": str(p), "part": k}
        for k, p in enumerate(rec.files)
    ]


def test_a_file_that_cannot_be_opened_is_a_fault_and_what_comes_meanwhile_is_lost(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def refuse(*args: object, **kwargs: object) -> RecordingWriter:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(recorder_module, "RecordingWriter", refuse)
    rec = _recorder(tmp_path)
    with capture_logs() as logged:
        rec._open()
        rec.handle(_samples(1)[0], None)
    (fault,) = [e for e in logged if e["event"] == "recorder fault"]
    assert fault["during"] == "open" and fault["reason"].startswith("disk full")
    assert fault["error"] == "OSError: [Errno 28] No space left on device"
    assert rec.files == [] and rec.faults == 1 and rec.lost == {"PressureSample": 1}
    assert rec.health(0).state is DeviceState.DOWN


def test_the_writer_thread_is_named_for_the_recorder(tmp_path: Path) -> None:
    """Its name is what ps, top and a thread dump show of the recorder (the worker names its
    thread baromapd-NAME), and the device its health is reported as."""
    rec = _recorder(tmp_path)
    assert rec.name == "recorder"
    assert rec.health(0).device == "recorder"


def test_a_syncer_asked_nothing_syncs_nothing(tmp_path: Path) -> None:
    from baromapd.recorder import Syncer

    with capture_logs() as logged:
        syncer = Syncer()
        syncer.close(2.0)
    assert not syncer._thread.is_alive()
    assert (syncer.syncs, syncer.errors) == (0, 0)
    assert [e for e in logged if e["event"] == "fsync failed"] == []


def test_a_recorder_that_never_started_finishes_cleanly(tmp_path: Path) -> None:
    """The worker finishes a recorder whose thread failed before its first file (its fsync
    thread could not start): nothing to close, nothing raised over the first failure."""
    rec = _recorder(tmp_path)
    rec.finished()
    assert rec.files == [] and rec.faults == 0


def test_after_a_guard_pause_below_a_megabyte_the_guard_alone_sets_the_resumption(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The full disk's resumption level (FULL_DISK_RESUME_MB) is for a disk that filled; a
    pause of the guard resumes at min_free_mb and its headroom, however small."""
    limit = recorder_module.FULL_DISK_RESUME_MB / 2
    free = [limit]
    monkeypatch.setattr(Recorder, "_free_mb", lambda self: free[0])
    config = RecordingConfig(directory=tmp_path, min_free_mb=limit)
    rec = Recorder(config, robot="r1", metadata={}, run_name="r1_small")
    rec._open()
    free[0] = limit / 2
    rec._guard_disk()
    assert rec._writer is None and rec.paused is not None
    free[0] = limit * recorder_module.RESUME_HEADROOM
    assert free[0] < recorder_module.FULL_DISK_RESUME_MB
    rec._guard_disk()
    assert rec._writer is not None and rec.paused is None and len(rec.files) == 2
    rec._close()


def test_a_recorder_whose_first_file_could_not_be_opened_opens_one_when_it_can(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The disk was full as the recorder started: it goes on waking (its flush and free
    space checks run with no file yet) and opens its first file once there is room."""

    def refuse(*args: object, **kwargs: object) -> RecordingWriter:
        raise OSError(28, "No space left on device")

    free = [0.0]
    monkeypatch.setattr(Recorder, "_free_mb", lambda self: free[0])
    monkeypatch.setattr(recorder_module, "RecordingWriter", refuse)
    rec = _recorder(tmp_path, flush_interval_s=0.05)
    rec._open()
    assert rec.fault is not None and rec.files == []
    rec.idle()
    assert rec.files == []
    monkeypatch.setattr(recorder_module, "RecordingWriter", RecordingWriter)
    free[0] = 100.0

    def opened() -> bool:
        rec.idle()
        return len(rec.files) == 1

    _wait(opened)
    assert rec.fault is None and rec.paused is None
    rec._close()


def test_the_flush_and_the_free_space_check_come_exactly_one_flush_interval_after_opening(
    tmp_path: Path, clock: list[int], free_space_looks: list[int]
) -> None:
    rec = _recorder(tmp_path)
    rec._open()
    opened = clock[0]
    flush_ns = round(rec.config.flush_interval_s * 1e9)
    clock[0] = opened + flush_ns - recorder_module.IDLE_CHECK_NS
    rec.idle()
    assert free_space_looks == []
    clock[0] = opened + flush_ns
    rec.idle()
    assert free_space_looks == [opened + flush_ns]
    rec._close()


def test_a_file_is_rotated_exactly_rotate_minutes_after_it_was_opened(
    tmp_path: Path, clock: list[int]
) -> None:
    rec = _recorder(tmp_path)
    rec._open()
    rotate_ns = round(rec.config.rotate_minutes * 60 * 1_000_000_000)
    assert not rec._rotation_due(clock[0] + rotate_ns - 1)
    assert rec._rotation_due(clock[0] + rotate_ns)
    rec._close()


def test_health_gives_each_topics_latency_percentiles_in_whole_microseconds(
    tmp_path: Path,
) -> None:
    rec = _recorder(tmp_path)
    hist = rec.latency["/t"] = LatencyHistogram()
    bin_ns = recorder_module.LATENCY_BIN_NS
    for i in range(99):  # one latency in each of the first 99 bins
        hist.add(i * bin_ns + 1)
    hist.add(5_000_123)  # and one far out
    counters = rec.health(0).counters
    p50, p99 = counters["latency_p50_us/t"], counters["latency_p99_us/t"]
    assert (p50, p99) == (50 * bin_ns // 1000, 99 * bin_ns // 1000)
    assert isinstance(p50, int) and isinstance(p99, int)


def test_every_message_a_failing_writer_refuses_is_counted_lost(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    failing = _FailingWrites(monkeypatch, RuntimeError("FoxgloveError: MCAP error: I/O error"))
    failing.failing = True
    rec = _recorder(tmp_path)
    for _ in range(2):  # a file refuses a message; the next file refuses one too
        rec._open()
        rec.handle(_samples(1)[0], None)
    assert rec.lost == {"PressureSample": 2} and rec.faults == 2


def test_a_message_is_written_on_the_topic_it_was_offered_on(tmp_path: Path) -> None:
    rec = _recorder(tmp_path)
    rec._open()
    rec.handle(_samples(1)[0], None, topic=topics.REFERENCE_PRESSURE)
    rec._close()
    (record,) = read_messages(rec.files[0], [topics.REFERENCE_PRESSURE])
    assert record.message == _samples(1)[0]


def test_a_pause_of_the_guard_is_logged_as_an_error_with_its_reason(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(Recorder, "_free_mb", lambda self: 5.0)
    config = RecordingConfig(directory=tmp_path, min_free_mb=10.0)
    rec = Recorder(config, robot="r1", metadata={}, run_name="r1_paused")
    rec._open()
    with capture_logs() as logged:
        rec._guard_disk()
    (paused,) = [e for e in logged if e["event"] == "recording paused"]
    assert paused["log_level"] == "error"
    assert paused["reason"] == "disk guard: 5 MB free, below min_free_mb 10" == rec.paused


def test_a_fault_names_the_file_it_stopped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    failing = _FailingWrites(monkeypatch, RuntimeError("FoxgloveError: MCAP error: I/O error"))
    rec = _recorder(tmp_path)
    rec._open()
    failing.failing = True
    with capture_logs() as logged:
        rec.handle(_samples(1)[0], None)
    (fault,) = [e for e in logged if e["event"] == "recorder fault"]
    assert fault["path"] == str(rec.files[0])


def test_a_metadata_record_the_writer_refuses_is_a_fault_during_its_write(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def refuse(writer: RecordingWriter, record: str, data: object) -> None:
        raise RuntimeError("FoxgloveError: MCAP error: I/O error")

    rec = _recorder(tmp_path)
    rec._open()
    monkeypatch.setattr(RecordingWriter, "write_metadata", refuse)
    rec.set_device_metadata("laser", {"serial": "1"})
    with capture_logs() as logged:
        rec.idle()
    (fault,) = [e for e in logged if e["event"] == "recorder fault"]
    assert fault["during"] == "write metadata"
    assert fault["error"] == "RuntimeError: FoxgloveError: MCAP error: I/O error"
    assert rec.faults == 1 and rec._writer is None


def test_recording_resumes_saying_the_free_space_to_a_tenth_of_a_megabyte(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """After the guard's pause and after a fault's retry alike."""
    free = [120.04]
    monkeypatch.setattr(Recorder, "_free_mb", lambda self: free[0])
    config = RecordingConfig(directory=tmp_path, min_free_mb=100.0)
    rec = Recorder(config, robot="r1", metadata={}, run_name="r1_free")
    rec.paused = "disk guard: 99 MB free, below min_free_mb 100"
    with capture_logs() as logged:
        rec._guard_disk()
    rec._fault("write", OSError(5, "bad block"))
    free[0] = 237.26
    clock = [rec._retry_ns]
    monkeypatch.setattr(recorder_module.time, "monotonic_ns", lambda: clock[0])
    with capture_logs() as retried:
        rec._guard_disk()
    said = [e["free_mb"] for e in logged + retried if e["event"] == "recording resumes"]
    assert said == [120.0, 237.3]
    rec._close()


def test_after_a_full_disk_was_resumed_a_guard_pause_resumes_at_the_guards_level(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    limit = recorder_module.FULL_DISK_RESUME_MB / 2
    free = [0.0]
    monkeypatch.setattr(Recorder, "_free_mb", lambda self: free[0])
    config = RecordingConfig(directory=tmp_path, min_free_mb=limit)
    rec = Recorder(config, robot="r1", metadata={}, run_name="r1_full")
    rec._open()
    rec._fault("write", OSError(28, "No space left on device"))
    free[0] = recorder_module.FULL_DISK_RESUME_MB * recorder_module.RESUME_HEADROOM
    rec._guard_disk()
    assert rec._writer is not None
    free[0] = limit / 2
    rec._guard_disk()
    assert rec._writer is None and rec.paused is not None
    free[0] = limit * recorder_module.RESUME_HEADROOM
    rec._guard_disk()
    assert rec._writer is not None and len(rec.files) == 3
    rec._close()


def test_the_syncer_counts_every_sync_and_every_failure(tmp_path: Path) -> None:
    from baromapd.recorder import Syncer

    present = tmp_path / "a.mcap"
    present.write_bytes(b"x")
    syncer = Syncer()
    for k in (1, 2):
        syncer.request(present)
        _wait(lambda k=k: syncer.syncs == k)  # type: ignore[misc]
    with capture_logs():
        for k in (1, 2):
            syncer.request(tmp_path / "gone.mcap")
            _wait(lambda k=k: syncer.errors == k)  # type: ignore[misc]
    syncer.close(2.0)
    assert (syncer.syncs, syncer.errors) == (2, 2)


def test_a_chunk_ends_more_often_than_the_flush_interval() -> None:
    """What a power cut loses is at most the flush interval: the writer ends its chunks
    CHUNKS_PER_FLUSH_INTERVAL times as often."""
    for flush_s in (0.05, 1.0):
        chunk_s = recorder_module.chunk_interval_s(flush_s)
        assert chunk_s == pytest.approx(flush_s / recorder_module.CHUNKS_PER_FLUSH_INTERVAL)
        assert chunk_s < flush_s


def test_cut_files_are_looked_for_past_one_already_recovered(tmp_path: Path) -> None:
    _cut_file(tmp_path / "r1_a_000.mcap")
    _cut_file(tmp_path / "r1_b_000.mcap")
    (tmp_path / "r1_a_000.recovered.mcap").write_bytes(b"")
    assert recorder_module.cut_recordings(tmp_path) == [tmp_path / "r1_b_000.mcap"]


def test_a_cut_file_too_big_for_the_free_space_is_skipped_and_the_next_recovered(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A copy needs the file's size free, beyond min_free_mb (here 0): a file exactly that
    size is recovered; a bigger one is skipped, saying its size to a tenth of a megabyte, and
    the next one is still looked at."""
    big, small = tmp_path / "r1_big_000.mcap", tmp_path / "r1_small_000.mcap"
    _cut_file(big, n=20_000)
    _cut_file(small)
    big_mb, small_mb = (p.stat().st_size / 1e6 for p in (big, small))
    assert round(big_mb, 1) not in (round(big_mb, 2), round(big_mb))
    monkeypatch.setattr(Recorder, "_free_mb", lambda self: small_mb)
    rec = _recorder(tmp_path)
    with capture_logs() as logged:
        rec._recover([big, small])
    skipped, recovered = logged
    assert skipped["event"] == "cut recording not recovered: not enough free space"
    assert skipped["path"] == str(big) and skipped["size_mb"] == round(big_mb, 1)
    assert recovered["event"] == "cut recording recovered" and recovered["path"] == str(small)
    assert rec.recovered == [tmp_path / "r1_small_000.recovered.mcap"]


def test_a_cut_file_left_for_want_of_space_says_the_free_space_to_a_tenth(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _cut_file(tmp_path / "r1_old_000.mcap")
    monkeypatch.setattr(Recorder, "_free_mb", lambda self: 12.345)
    config = RecordingConfig(directory=tmp_path, min_free_mb=50.0)
    rec = Recorder(config, robot="r1", metadata={}, run_name="r1_free")
    with capture_logs() as logged:
        rec._recover([tmp_path / "r1_old_000.mcap"])
    (said,) = logged
    assert said["event"] == "cut recording not recovered: not enough free space"
    assert said["free_mb"] == 12.3


def test_the_size_is_looked_at_once_a_size_check_and_rotates_at_exactly_rotate_size_mb(
    tmp_path: Path, clock: list[int], monkeypatch: pytest.MonkeyPatch
) -> None:
    rec = _recorder(tmp_path)
    rec._open()
    limit = round(rec.config.rotate_size_mb * recorder_module.MB)
    sizes = [limit - 1]
    looked: list[int] = []

    def size(self: Recorder) -> int:
        looked.append(clock[0])
        return sizes[0]

    monkeypatch.setattr(Recorder, "_size", size)
    t0 = clock[0]
    check = min(recorder_module.SIZE_CHECK_NS, round(rec.config.flush_interval_s * 1e9))

    def due(at: int) -> bool:
        clock[0] = at
        return rec._rotation_due(at)

    assert not due(t0)
    assert not due(t0 + check - 1)
    sizes[0] = limit
    assert due(t0 + check)
    assert looked == [t0, t0 + check]
    rec._close()


def test_a_fault_exactly_a_window_after_the_last_keeps_the_doubled_pause(
    tmp_path: Path, clock: list[int]
) -> None:
    """The retry pause starts afresh only after a fault more than FAULT_WINDOW_NS past;
    FATAL_FAULTS faults within the window, its edge included, are fatal."""
    first = recorder_module.FAULT_RETRY_NS
    window = recorder_module.FAULT_WINDOW_NS
    with capture_logs():
        rec = _recorder(tmp_path)
        rec._fault("write", OSError(5, "bad block"))
        clock[0] += 1
        rec._fault("write", OSError(5, "bad block"))
        assert rec._retry_ns == clock[0] + 2 * first  # the second pause is twice the first
        clock[0] += window
        rec._fault("write", OSError(5, "bad block"))
        assert rec._retry_ns == clock[0] + 4 * first and rec.fatal is None
        fatal = _recorder(tmp_path)
        start = clock[0]
        for k in range(recorder_module.FATAL_FAULTS):
            clock[0] = start + (window if k == recorder_module.FATAL_FAULTS - 1 else k)
            fatal._fault("write", OSError(5, "bad block"))
    assert fatal.fatal is not None


def test_an_idle_recorder_wakes_its_checks_once_an_idle_check_and_syncs_when_a_flush_is_due(
    tmp_path: Path, clock: list[int], free_space_looks: list[int]
) -> None:
    rec = _recorder(tmp_path)
    rec.started()
    opened = clock[0]
    flush_ns = round(rec.config.flush_interval_s * 1e9)
    check = recorder_module.IDLE_CHECK_NS
    assert check < flush_ns
    try:
        clock[0] = opened + flush_ns - 1
        rec.idle()  # not due: the next check comes an idle check later
        clock[0] = opened + flush_ns
        rec.idle()
        assert free_space_looks == [] and rec._syncer is not None and rec._syncer.syncs == 0
        clock[0] = opened + flush_ns - 1 + check
        rec.idle()
        assert free_space_looks == [clock[0]]
        syncer = rec._syncer
        _wait(lambda: syncer.syncs == 1)
    finally:
        rec.finished()


def test_cut_files_are_recovered_on_a_daemon_thread_named_for_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """ps and a thread dump show it; it never holds up the daemon's exit."""
    import threading

    _cut_file(tmp_path / "r1_old_000.mcap")
    seen: list[tuple[str, bool]] = []

    def recover(self: Recorder, paths: list[Path]) -> None:
        seen.append((threading.current_thread().name, threading.current_thread().daemon))

    monkeypatch.setattr(Recorder, "_recover", recover)
    rec = _recorder(tmp_path)
    rec.start()
    try:
        _wait(lambda: seen)
    finally:
        rec.close()
    assert seen == [("baromapd-recover", True)]


def test_a_reference_stations_sample_is_recorded_on_its_topic(tmp_path: Path) -> None:
    rec = _recorder(tmp_path)
    sample = _samples(1)[0]
    rec.start()
    rec.offer_reference(sample)
    rec.close()
    (record,) = read_messages(rec.files[0], [topics.REFERENCE_PRESSURE])
    assert record.message == sample


def _stalled_fsync(
    monkeypatch: pytest.MonkeyPatch,
) -> tuple[threading.Event, threading.Event, threading.Timer]:
    """Makes the fsync thread's fsync hang until the returned release is set (by the test, or
    by the timer after 5 s, so that a close that waits for it ends); returns (entered,
    release, timer)."""
    entered, release = threading.Event(), threading.Event()
    real = recorder_module.fsync_path

    def stalling(path: Path) -> None:
        if threading.current_thread().name != "baromapd-fsync":
            real(path)
            return
        entered.set()
        release.wait(10.0)

    monkeypatch.setattr(recorder_module, "fsync_path", stalling)
    timer = threading.Timer(5.0, release.set)
    timer.daemon = True
    timer.start()
    return entered, release, timer


def _let_go(release: threading.Event, timer: threading.Timer, thread: threading.Thread) -> None:
    release.set()
    timer.cancel()
    timer.join(2.0)
    thread.join(2.0)


def test_closing_the_syncer_leaves_a_stalled_fsync_behind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from baromapd.recorder import Syncer

    entered, release, timer = _stalled_fsync(monkeypatch)
    syncer = Syncer()
    try:
        syncer.request(tmp_path)
        assert entered.wait(5.0)
        syncer.close(0.2)
        assert syncer._thread.is_alive()
    finally:
        _let_go(release, timer, syncer._thread)


def test_a_recorder_finishing_leaves_a_stalled_fsync_behind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Its join is bounded by SYNCER_JOIN_S: the daemon exits within its stop timeout."""
    monkeypatch.setattr(recorder_module, "SYNCER_JOIN_S", 0.2)
    entered, release, timer = _stalled_fsync(monkeypatch)
    rec = _recorder(tmp_path)
    rec.started()
    syncer = rec._syncer
    assert syncer is not None
    try:
        syncer.request(rec.files[0])
        assert entered.wait(5.0)
        rec.finished()
        assert syncer._thread.is_alive()
    finally:
        _let_go(release, timer, syncer._thread)
