"""The recorder: one writer thread fed by a bounded queue, rotating files, guarding the disk.

It uses the library's :class:`~baromap.recording.RecordingWriter` for everything MCAP; what it
adds is what a long unattended run needs:

- Durability: SIGKILL loses at most ``flush_interval_s`` of any stream: the writer ends a chunk
  twice an interval (:func:`chunk_interval_s`), because what is lost is the time since the
  last chunk plus the age of the last message in it (up to 0.1 s for the base's 10 Hz
  odometry) plus the queue's latency, which on a loaded machine is tenths of a second. The
  file is fsynced once an interval, off this thread, for a power cut.
- Rotation by size and duration. One thread writes in order, so a split falls between two
  messages: nothing is lost or written twice. Each file is self-contained: it starts with the
  run's metadata record and every device identity known so far.
- A disk guard: below ``min_free_mb`` free the file is finished and writing pauses (the drops
  are counted, health and logs say why); it resumes into a new file with 20 % headroom.
- Faults: any failure of the writer, whatever it raises (the MCAP library's own errors too), is
  a recorder fault: logged once with its reason (disk full, I/O error), shown as the recorder
  DOWN in health (``/diagnostics``, systemd's ``STATUS=``, Zenoh), the file closed as far as it
  goes (``baromap recover`` or the next start repairs it). A full disk is waited out: writing
  resumes in a new file once there is room again. Other faults are retried in a new file
  after a pause; :data:`FATAL_FAULTS` of them within :data:`FAULT_WINDOW_NS` make the recorder
  give up (:attr:`Recorder.fatal`), and the daemon exits so that systemd restarts it.
- Latency: from the read of a frame's last byte to the message reaching this thread.
- Repair: files an earlier run left cut (SIGKILL, power cut) are rewritten whole at start-up,
  next to the original (``*.recovered.mcap``; :mod:`baromap.recording.recover`), on a thread
  of their own while this run records.
"""

from __future__ import annotations

import errno
import shutil
import threading
import time
from collections import Counter, deque
from collections.abc import Mapping
from pathlib import Path
from typing import Final

import structlog

from baromap import messages
from baromap.errors import RecordingWriteError
from baromap.recording import RecordingWriter, topics
from baromap.recording.frames import LaserMount
from baromap.recording.recover import RECOVERED_SUFFIX, is_cut, recover
from baromap.recording.writer import DEFAULT_TOPICS, fsync_path
from baromapd.config import RecordingConfig
from baromapd.fanout import QueueWorker
from baromapd.osthread import name_os_thread

log = structlog.get_logger(__name__)

MB: Final = 1_000_000
#: Chunks the writer ends per ``flush_interval_s``.
CHUNKS_PER_FLUSH_INTERVAL: Final = 2
RESUME_HEADROOM: Final = 1.2
#: How often (at most) the current file's size is checked for rotation.
SIZE_CHECK_NS: Final = 250_000_000
#: How often (at most) the idle work runs while messages flow: the fsync request, the disk
#: guard, the flush of a quiet writer. It runs after each message, so it starts with a clock
#: read and a comparison and is done (the writer flushes on its own as it writes).
IDLE_CHECK_NS: Final = 50_000_000
#: After a full disk, writing resumes once this much is free (or ``min_free_mb``, if larger),
#: with the guard's headroom: a file needs room for its header and a chunk or two.
FULL_DISK_RESUME_MB: Final = 1.0
#: Other faults are retried in a new file after this pause, doubled on each fault up to the cap.
FAULT_RETRY_NS: Final = 1_000_000_000
FAULT_RETRY_MAX_NS: Final = 8_000_000_000
#: This many faults other than a full disk within the window: the recorder gives up.
FATAL_FAULTS: Final = 3
FAULT_WINDOW_NS: Final = 60_000_000_000
#: How long the fsync thread is waited for at the end (a stalled disk must not hold the exit).
SYNCER_JOIN_S: Final = 2.0
#: errno values that mean the disk has no room (a full file system, a quota).
NO_SPACE: Final = frozenset({errno.ENOSPC, errno.EDQUOT})
#: Latency histogram: 20 us bins up to 200 ms, then one overflow bin.
LATENCY_BIN_NS: Final = 20_000
LATENCY_BINS: Final = 10_000


class LatencyHistogram:
    """Fixed-bin latency histogram: O(1) per sample, percentiles on demand."""

    def __init__(self) -> None:
        self.bins = [0] * (LATENCY_BINS + 1)
        self.count = 0
        self.max_ns = 0

    def add(self, latency_ns: int) -> None:
        index = min(max(latency_ns, 0) // LATENCY_BIN_NS, LATENCY_BINS)
        self.bins[index] += 1
        self.count += 1
        self.max_ns = max(self.max_ns, latency_ns)

    def percentile_ns(self, q: float) -> int:
        """Upper edge of the bin holding the q-th percentile (0 with no samples)."""
        if not self.count:
            return 0
        target = q / 100.0 * self.count
        seen = 0
        for index, n in enumerate(self.bins):
            seen += n
            if seen >= target:
                return min((index + 1) * LATENCY_BIN_NS, max(self.max_ns, LATENCY_BIN_NS))
        return self.max_ns


class Recorder(QueueWorker):
    """Writes everything offered into rotating MCAP files under ``config.directory``."""

    def __init__(
        self,
        config: RecordingConfig,
        *,
        robot: str,
        metadata: Mapping[str, str],
        run_name: str,
        laser_mount: LaserMount | None = None,
    ) -> None:
        super().__init__("recorder", config.queue_size, idle_s=min(0.2, config.flush_interval_s))
        self.config = config
        self.robot = robot
        self.metadata = dict(metadata)
        self.run_name = run_name
        self.laser_mount = laser_mount
        self.files: list[Path] = []
        #: Cut files of earlier runs rewritten whole at start-up (the copies' paths).
        self.recovered: list[Path] = []
        self.written: Counter[str] = Counter()
        self.latency: dict[str, LatencyHistogram] = {}
        self._writer: RecordingWriter | None = None
        self._opened_ns = 0
        self._size_checked_ns = 0
        self._flush_ns = round(config.flush_interval_s * 1e9)
        self._size_check_ns = min(SIZE_CHECK_NS, self._flush_ns)
        self._idle_check_ns = min(IDLE_CHECK_NS, self._flush_ns // 10)
        self._rotate_ns = round(config.rotate_minutes * 60e9)
        self._last_flush_ns = 0
        self._idle_due_ns = 0
        self._devices: dict[str, dict[str, str]] = {}
        self._pending_devices: dict[str, dict[str, str]] = {}
        self._lock = threading.Lock()
        self.paused: str | None = None  # why writing is paused (disk guard, write error)
        self.lost: Counter[str] = Counter()
        self._syncer: Syncer | None = None
        #: The reason of the current fault (None while recording or paused by the guard).
        self.fault: str | None = None
        #: Set once the recorder has given up (repeated faults): the daemon exits.
        self.fatal: str | None = None
        self.faults = 0
        self._fault_times: deque[int] = deque(maxlen=FATAL_FAULTS)
        self._full_disk = False
        self._retry_ns = 0
        self._retry_delay_ns = FAULT_RETRY_NS

    # ---- from other threads -----------------------------------------------------------------
    def set_device_metadata(self, device: str, data: Mapping[str, str]) -> None:
        """Record a device's identity (now, and at the start of every later file)."""
        self.set_metadata(f"baromap.device.{device}", data)

    def set_metadata(self, record: str, data: Mapping[str, str]) -> None:
        """Record a named metadata record (now, and at the start of every later file): a
        device's identity, or what a reader needs to interpret it (``baromap.robot``)."""
        with self._lock:
            self._pending_devices[record] = dict(data)

    def offer_reference(self, sample: messages.PressureSample) -> None:
        """A reference station's sample (from a Zenoh thread), recorded on
        ``/reference/pressure`` so post-run detection can correct with the station too."""
        self._put((sample, None, topics.REFERENCE_PRESSURE))

    def health(self, t_ns: int) -> messages.DeviceHealth:
        counters: dict[str, int] = {
            "messages": sum(self.written.values()),
            "files": len(self.files),
        }
        counters.update({f"dropped_queue_{k}": v for k, v in self.dropped.items()})
        counters.update({f"dropped_paused_{k}": v for k, v in self.lost.items()})
        counters["backlog"] = self.backlog
        counters["faults"] = self.faults
        for topic, hist in list(self.latency.items()):
            counters[f"latency_p50_us{topic}"] = hist.percentile_ns(50) // 1000
            counters[f"latency_p99_us{topic}"] = hist.percentile_ns(99) // 1000
        if self.error:
            state, detail = messages.DeviceState.DOWN, f"writer thread failed: {self.error}"
        elif self.fatal:
            state, detail = messages.DeviceState.DOWN, f"recorder gave up: {self.fatal}"
        elif self.paused:
            state, detail = messages.DeviceState.DOWN, self.paused
        elif self.dropped:
            state, detail = messages.DeviceState.DEGRADED, "queue overflowed: messages dropped"
        else:
            current = self.files[-1].name if self.files else "none yet"
            state, detail = messages.DeviceState.UP, f"recording {current}"
        return messages.DeviceHealth(
            t_ns, "recorder", state, str(self.config.directory), detail, counters
        )

    def start(self) -> None:
        # Looked for before this run's first file exists: that one is not closed either.
        cut = cut_recordings(self.config.directory)
        super().start()
        if cut:
            threading.Thread(
                target=self._recover, args=(cut,), name="baromapd-recover", daemon=True
            ).start()

    def _recover(self, paths: list[Path]) -> None:
        name_os_thread()
        for path in paths:
            target = recovered_path(path)
            try:
                size_mb = path.stat().st_size / MB
                free = self._free_mb()
                if free is None or free - size_mb < self.config.min_free_mb:
                    log.warning(
                        "cut recording not recovered: not enough free space",
                        path=str(path),
                        size_mb=round(size_mb, 1),
                        free_mb=None if free is None else round(free, 1),
                    )
                    continue
                result = recover(path, target)
            except Exception as exc:
                log.warning("cut recording not recovered", path=str(path), error=str(exc))
                continue
            self.recovered.append(target)
            log.info(
                "cut recording recovered",
                path=str(path),
                recovered=str(target),
                messages=result.messages,
                cut_at=result.cut_at,
                size=result.size,
                reason=result.reason,
            )

    # ---- the writer thread --------------------------------------------------------------------
    def started(self) -> None:
        self._syncer = Syncer()
        self._open()

    def handle(
        self, message: messages.Message, received_ns: int | None, topic: str | None = None
    ) -> None:
        """Write ``message`` on ``topic`` (its type's usual one when None)."""
        now = time.monotonic_ns()
        if topic is None:
            topic = DEFAULT_TOPICS.get(type(message)) or type(message).__name__
        if received_ns is not None:
            hist = self.latency.get(topic)
            if hist is None:
                hist = self.latency[topic] = LatencyHistogram()
            hist.add(now - received_ns)
        if self._writer is None:
            self.lost[type(message).__name__] += 1
            return
        if self._rotation_due(now):
            self._rotate("rotation")
        try:
            assert self._writer is not None
            self._writer.write(message, topic)
            self.written[topic] += 1
        except Exception as exc:  # whatever the writer raises: a fault, never the thread's end
            self.lost[type(message).__name__] += 1
            self._fault("write", exc)

    def idle(self) -> None:
        now = time.monotonic_ns()
        if now < self._idle_due_ns and not self._pending_devices:
            return
        self._idle_due_ns = now + self._idle_check_ns
        if self._pending_devices:
            self._write_pending_devices()
        if self._writer is not None:
            self._flush_if_due()
        if now - self._last_flush_ns >= self._flush_ns:
            self._last_flush_ns = now
            if self._writer is not None and self._syncer is not None:
                # The writer flushes inside write() too; make whatever it handed over durable.
                self._syncer.request(self._writer.path)
            self._guard_disk()

    def finished(self) -> None:
        try:
            self._close()
        finally:
            if self._syncer is not None:
                self._syncer.close(SYNCER_JOIN_S)

    # ---- files -------------------------------------------------------------------------------
    def _path(self) -> Path:
        return self.config.directory / f"{self.run_name}_{len(self.files):03d}.mcap"

    def _open(self) -> None:
        path = self._path()
        header = dict(self.metadata)
        header["part"] = str(len(self.files))
        header["run"] = self.run_name
        try:
            self._writer = RecordingWriter(
                path,
                robot=self.robot,
                metadata=header,
                laser_mount=self.laser_mount,
                flush_interval_s=chunk_interval_s(self.config.flush_interval_s),
                fsync=False,  # the Syncer does it, off this thread
                compression=self.config.compression,
            )
        except Exception as exc:
            self._writer = None
            self._fault("open", exc)
            return
        self.files.append(path)
        self._opened_ns = time.monotonic_ns()
        self._last_flush_ns = self._opened_ns
        with self._lock:
            self._pending_devices = {**self._devices, **self._pending_devices}
        self._write_pending_devices()
        log.info("recording file opened", path=str(path), part=len(self.files) - 1)

    def _close(self) -> None:
        """Finish the current file as far as it goes; never raises (a failure is a fault)."""
        writer, self._writer = self._writer, None
        if writer is None:
            return
        try:
            writer.close()
            fsync_path(writer.path)
        except Exception as exc:
            if self.fault is None:
                self._fault("close", exc)
            else:  # the fault that stopped the file already said why it cannot be finished
                log.debug("faulted recording left unfinished", path=str(writer.path))

    def _rotate(self, why: str) -> None:
        log.info("rotating recording", reason=why)
        self._close()
        self._open()

    def _rotation_due(self, now_ns: int) -> bool:
        if now_ns - self._opened_ns >= self._rotate_ns:
            return True
        # The file grows by the flushed chunks: its size is looked at (a stat) about once a
        # flush, not for every message.
        if now_ns - self._size_checked_ns < self._size_check_ns:
            return False
        self._size_checked_ns = now_ns
        return bool(self.files) and self._size() >= self.config.rotate_size_mb * MB

    def _size(self) -> int:
        try:
            return self.files[-1].stat().st_size
        except OSError:
            return 0

    def _flush_if_due(self) -> None:
        assert self._writer is not None
        try:
            self._writer.flush_if_due()
        except Exception as exc:
            self._fault("flush", exc)

    def _write_pending_devices(self) -> None:
        with self._lock:
            pending, self._pending_devices = self._pending_devices, {}
            self._devices.update(pending)
        if self._writer is None:
            return
        for record, data in pending.items():
            try:
                self._writer.write_metadata(record, data)
            except Exception as exc:
                self._fault("write metadata", exc)
                return

    def _free_mb(self) -> float | None:
        """Free space where the files go, or None when it cannot be found out."""
        try:
            return shutil.disk_usage(self.config.directory).free / MB
        except OSError:
            return None

    def _guard_disk(self) -> None:
        if self.fatal is not None:
            return
        free = self._free_mb()
        limit = self.config.min_free_mb
        if self._writer is not None:
            if free is not None and free < limit:
                self._pause(f"disk guard: {free:.0f} MB free, below min_free_mb {limit:g}")
            return
        if self.fault is not None and not self._full_disk:
            if time.monotonic_ns() >= self._retry_ns:
                self._resume(free)
            return
        needed = max(limit, FULL_DISK_RESUME_MB) if self._full_disk else limit
        if free is not None and free >= needed * RESUME_HEADROOM:
            self._resume(free)

    def _resume(self, free_mb: float | None) -> None:
        log.info(
            "recording resumes",
            after=self.paused,
            free_mb=None if free_mb is None else round(free_mb, 1),
        )
        self.paused = None
        self.fault = None
        self._full_disk = False
        self._open()

    def _pause(self, why: str) -> None:
        log.error("recording paused", reason=why)
        self.paused = why
        self._close()

    def _fault(self, action: str, exc: Exception) -> None:
        """A writer failure: say it once, close the file as far as it goes, plan the way on."""
        reason = fault_reason(exc)
        new = self.fault is None
        self.faults += 1
        self.fault = reason
        self.paused = f"recorder fault: {reason}"
        self._full_disk = reason.startswith("disk full")
        path = str(self._writer.path) if self._writer is not None else None
        if new:
            log.error(
                "recorder fault",
                reason=reason,
                during=action,
                path=path,
                error=f"{type(exc).__name__}: {exc}",
            )
        self._close()
        now = time.monotonic_ns()
        if self._full_disk:
            return  # waited out in _guard_disk, however long: it is not the recorder's fault
        if self._fault_times and now - self._fault_times[-1] > FAULT_WINDOW_NS:
            self._retry_delay_ns = FAULT_RETRY_NS  # the last fault is long past: start afresh
        self._fault_times.append(now)
        if len(self._fault_times) == FATAL_FAULTS and now - self._fault_times[0] <= FAULT_WINDOW_NS:
            self.fatal = (
                f"{FATAL_FAULTS} faults within {FAULT_WINDOW_NS // 1_000_000_000} s: {reason}"
            )
            log.error("recorder gives up", reason=self.fatal)
            return
        self._retry_ns = now + self._retry_delay_ns
        self._retry_delay_ns = min(self._retry_delay_ns * 2, FAULT_RETRY_MAX_NS)


def fault_reason(exc: BaseException) -> str:
    """Why a write failed, in a few words first (disk full, I/O error, ...), then the detail."""
    os_error: OSError | None = None
    if isinstance(exc, RecordingWriteError):
        os_error = exc.os_error
    elif isinstance(exc, OSError):
        os_error = exc
    else:
        cause = exc.__cause__ or exc.__context__
        if isinstance(cause, OSError):
            os_error = cause
    if os_error is None:
        return f"writer error: {type(exc).__name__}: {exc}"
    code = os_error.errno
    if code in NO_SPACE:
        kind = "disk full"
    elif code == errno.EIO:
        kind = "I/O error"
    elif code == errno.EROFS:
        kind = "read-only file system"
    elif code in (errno.EACCES, errno.EPERM):
        kind = "permission denied"
    else:
        kind = "OS error"
    return f"{kind}: {exc}"


class Syncer:
    """fsyncs the current file on its own thread, so a slow disk never holds up the writer.

    The writer hands every flushed chunk to the OS at once; the wait until the disk has it
    (tens of milliseconds on an SD card or a busy disk) happens here, while the writer goes
    on taking messages from the queue.
    """

    def __init__(self) -> None:
        self._wanted: Path | None = None
        self._cond = threading.Condition()
        self._stopped = False
        self.syncs = 0
        self.errors = 0
        self._thread = threading.Thread(target=self._run, name="baromapd-fsync", daemon=True)
        self._thread.start()

    def request(self, path: Path) -> None:
        with self._cond:
            self._wanted = path
            self._cond.notify()

    def close(self, timeout: float | None = None) -> None:
        """Stop the thread; wait for it at most ``timeout`` s (a stalled fsync is left behind:
        the thread is a daemon thread, the process may end without it)."""
        with self._cond:
            self._stopped = True
            self._cond.notify()
        self._thread.join(timeout)

    def _run(self) -> None:
        name_os_thread()
        while True:
            with self._cond:
                while self._wanted is None and not self._stopped:
                    self._cond.wait()
                path, self._wanted = self._wanted, None
                if path is None:
                    return
            try:
                fsync_path(path)
                self.syncs += 1
            except OSError as exc:  # the file may have been finished and moved meanwhile
                self.errors += 1
                log.warning("fsync failed", path=str(path), error=str(exc))


def chunk_interval_s(flush_interval_s: float) -> float:
    """How often the writer ends a chunk, so that no stream loses more than the interval."""
    return flush_interval_s / CHUNKS_PER_FLUSH_INTERVAL


def recovered_path(path: Path) -> Path:
    """Where the repaired copy of a cut ``path`` goes: beside it, the original kept."""
    return path.with_name(path.name.removesuffix(".mcap") + RECOVERED_SUFFIX)


def cut_recordings(directory: Path) -> list[Path]:
    """The MCAP files in ``directory`` left cut and not yet recovered, oldest name first."""
    try:
        candidates = sorted(directory.glob("*.mcap"))
    except OSError:
        return []
    cut = []
    for path in candidates:
        if path.name.endswith(RECOVERED_SUFFIX) or recovered_path(path).exists():
            continue
        try:
            if is_cut(path):
                cut.append(path)
        except OSError as exc:
            log.warning("recording not readable", path=str(path), error=str(exc))
    return cut
