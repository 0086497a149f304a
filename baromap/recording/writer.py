"""Write a run into one MCAP file that Foxglove opens without plugins.

Scans go out as ``foxglove.LaserScan`` in the ``laser`` frame, encoded by
:mod:`~baromap.recording.foxglove_wire` into the bytes the SDK would write (per-beam
:class:`~baromap.messages.BeamFlag` bits ride in ``intensities``: the LMS200 reports no
intensity in its ranging modes; the range limits ride in the channel's metadata; the status
byte is the session's business, on ``/diagnostics``). Odometry goes out as
``foxglove.Odometry`` on ``/odom`` (the P2OS raw counters in its per-message ``metadata``, so
integration can be redone with other conversion factors) and as a ``foxglove.FrameTransform``
``odom -> base_link`` on ``/tf``; the laser mount is the static ``base_link -> laser`` on
``/tf_static``. Everything else is JSON with a JSON Schema (:mod:`baromap.jsonmsg`).

Every file stands on its own, because the daemon rotates files and a player may open any of
them or seek into the middle of one: the metadata record and the static transform are written
into each file, and the static transform is repeated every second of recording time and after
every flush, so any stretch of a file longer than a second, and every flushed chunk, carries it
(a player that seeks finds it within a second before, as Foxglove's backfill does; one that
keeps only recent transforms never loses it).

Durability: chunks end and are fsynced at least every ``flush_interval_s`` of wall time (on a
write, or on :meth:`RecordingWriter.flush_if_due` from an idle recorder loop), so a power cut or
SIGKILL loses about a second; the reader recovers everything up to the last flush.
"""

from __future__ import annotations

import io
import os
import time
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType

import foxglove
import structlog
from foxglove.channels import FrameTransformChannel, OdometryChannel
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from foxglove.messages import (
    FrameTransform,
    KeyValuePair,
    Odometry,
    Pose,
    Quaternion,
    Timestamp,
    Vector3,
)

from baromap import __version__, jsonmsg, messages
from baromap.errors import BaromapError, RecordingError, RecordingWriteError
from baromap.recording import foxglove_wire, topics
from baromap.recording.frames import LASER_MOUNT_KEY, LaserMount, yaw_to_quaternion

log = structlog.get_logger(__name__)

DEFAULT_TOPICS: dict[type, str] = {
    messages.PressureSample: topics.BARO,
    messages.LaserScan: topics.SCAN,
    messages.Odometry: topics.ODOM,
    messages.FloorEvent: topics.FLOOR_EVENT,
    messages.RideEvent: topics.FLOOR_RIDE,
    messages.FloorState: topics.FLOOR_STATE,
    messages.DeviceHealth: topics.DIAGNOSTICS,
    messages.TruthPose: topics.TRUTH_POSE,
    messages.TruthFloor: topics.TRUTH_FLOOR,
}

#: Keys of the P2OS counters in a ``foxglove.Odometry`` message's metadata.
RAW_ODOMETRY_KEYS = ("raw_x", "raw_y", "raw_theta")

#: Chunk compressions a recording may use (what the MCAP SDK writes and the reader reads):
#: zstd is smaller (the default), lz4 is cheaper on the CPU, none is for debugging a file.
COMPRESSIONS: dict[str, MCAPCompression | None] = {
    "zstd": MCAPCompression.Zstd,
    "lz4": MCAPCompression.Lz4,
    "none": None,
}

#: How often (recording time) the static transform is repeated.
STATIC_PERIOD_NS = 1_000_000_000

#: Foxglove time stamps hold unsigned 32-bit seconds: the Unix epoch to early 2106.
MAX_T_NS = 2**32 * 1_000_000_000 - 1


class _File(io.FileIO):
    """The file the MCAP library writes through, keeping what the OS last refused.

    The library reports every failed write as "I/O error"; a recorder must tell a full disk
    (wait for space) from a failing one, so the ``OSError`` itself is kept here.
    """

    error: OSError | None = None

    def write(self, data: bytes, /) -> int:  # type: ignore[override]
        try:
            return super().write(data)
        except OSError as exc:
            self.error = exc
            raise


def stamp(t_ns: int) -> Timestamp:
    sec, nsec = divmod(t_ns, 1_000_000_000)
    return Timestamp(sec=sec, nsec=nsec)


def yaw_quaternion(theta: float) -> Quaternion:
    x, y, z, w = yaw_to_quaternion(theta)
    return Quaternion(x=x, y=y, z=z, w=w)


# What a message becomes on its channel: here, so the daemon's live view (baromapd serving
# the Foxglove WebSocket protocol) sends the very channels, schemas and frames a recording
# holds, and a layout made on one opens the other.

#: The ``/odom`` channel's metadata: where the P2OS counters are.
ODOMETRY_CHANNEL_METADATA: dict[str, str] = {
    "metadata": "P2OS counters: " + ", ".join(RAW_ODOMETRY_KEYS)
}


def json_schema(cls: type) -> foxglove.Schema:
    """The JSON Schema of a message type's JSON channel."""
    return foxglove.Schema(
        name=jsonmsg.schema_name(cls), encoding="jsonschema", data=jsonmsg.json_schema(cls)
    )


def scan_channel_metadata(scan: messages.LaserScan) -> dict[str, str]:
    """A scan channel's metadata: the range limits, and what ``intensities`` carry."""
    return {
        "range_max_m": repr(scan.range_max_m),
        "range_min_m": repr(scan.range_min_m),
        "intensities": "baromap.BeamFlag bits per beam",
    }


def odometry_message(odom: messages.Odometry) -> Odometry:
    """``/odom``'s ``foxglove.Odometry``: the pose in ``odom``, the P2OS counters as metadata."""
    return Odometry(
        timestamp=stamp(odom.t_ns),
        frame_id=topics.ODOM_FRAME,
        body_frame_id=topics.BASE_FRAME,
        pose=Pose(
            position=Vector3(x=odom.x_m, y=odom.y_m, z=0.0),
            orientation=yaw_quaternion(odom.theta_rad),
        ),
        linear_velocity=Vector3(x=odom.v_mps, y=0.0, z=0.0),
        angular_velocity=Vector3(x=0.0, y=0.0, z=odom.omega_radps),
        metadata=[
            KeyValuePair(key="raw_x", value=str(odom.raw_x)),
            KeyValuePair(key="raw_y", value=str(odom.raw_y)),
            KeyValuePair(key="raw_theta", value=str(odom.raw_theta)),
        ],
    )


def odometry_transform(odom: messages.Odometry) -> FrameTransform:
    """``/tf``'s ``odom -> base_link`` at an odometry message."""
    return FrameTransform(
        timestamp=stamp(odom.t_ns),
        parent_frame_id=topics.ODOM_FRAME,
        child_frame_id=topics.BASE_FRAME,
        translation=Vector3(x=odom.x_m, y=odom.y_m, z=0.0),
        rotation=yaw_quaternion(odom.theta_rad),
    )


def laser_transform(mount: LaserMount, t_ns: int) -> FrameTransform:
    """``/tf_static``'s ``base_link -> laser``."""
    return FrameTransform(
        timestamp=stamp(t_ns),
        parent_frame_id=topics.BASE_FRAME,
        child_frame_id=topics.LASER_FRAME,
        translation=Vector3(x=mount.x_m, y=mount.y_m, z=0.0),
        rotation=yaw_quaternion(mount.yaw_rad),
    )


class RecordingWriter:
    """One MCAP file of one run.

    Not thread-safe by design: the daemon gives it to one recorder thread fed by a queue. That
    thread calls :meth:`flush_if_due` when its queue is idle, so the last messages before a
    quiet spell become durable too.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        robot: str,
        metadata: Mapping[str, str] | None = None,
        laser_mount: LaserMount | None = None,
        flush_interval_s: float = 1.0,
        fsync: bool = True,
        allow_overwrite: bool = False,
        compression: str = "zstd",
    ) -> None:
        if compression not in COMPRESSIONS:
            raise RecordingError(
                f"compression must be one of {', '.join(COMPRESSIONS)}, not {compression!r}"
            )
        self.path = Path(path)
        self.compression = compression
        self.context = foxglove.Context()
        self._flush_interval_s = flush_interval_s
        self._fsync = fsync
        self._last_flush = time.monotonic()
        self._dirty = False
        self._json_channels: dict[tuple[str, type], foxglove.Channel] = {}
        self._scan_channels: dict[tuple[str, float], foxglove.Channel] = {}
        self._scan_encoder = foxglove_wire.LaserScanEncoder(topics.LASER_FRAME)
        self._odom_channels: dict[str, OdometryChannel] = {}
        self._tf_channel: FrameTransformChannel | None = None
        self._static_channel: FrameTransformChannel | None = None
        self._laser_mount: LaserMount | None = None
        self._static_due = False
        self._last_static_ns = -1
        self._closed = True
        self.counts: dict[str, int] = {}
        self._file: _File | None = None
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # The SDK writes through this file object, so each write to the disk is a
            # FileIO.write that lets go of the GIL while the kernel takes the bytes. Given the
            # path, the SDK writes from Rust with the GIL held: a disk busy with other work
            # (a flush blocked for 0.3 s, measured) then stopped every thread of the process,
            # the device readers too, and a 500 kbaud line overflowed its pty.
            self._file = _File(self.path, "w" if allow_overwrite else "x")
            self._writer = foxglove.open_mcap(
                self._file,
                context=self.context,
                writer_options=MCAPWriteOptions(
                    profile="baromap", compression=COMPRESSIONS[compression]
                ),
            )
            # fsync works on the file, whichever descriptor wrote it: the SDK keeps its own.
            self._sync_fd = os.open(self.path, os.O_RDONLY) if fsync else -1
            if fsync:
                fsync_path(self.path.parent)
        except (OSError, RuntimeError, ValueError) as exc:
            if self._file is not None:
                self._file.close()
            raise RecordingError(f"cannot create recording {self.path}: {exc}") from exc
        self._closed = False
        if laser_mount is None and metadata:
            # a caller that states the mount in the metadata (the daemon's configuration, the
            # CARMEN importer's laser_offset) gets the transform too
            try:
                laser_mount = LaserMount.from_record(metadata)
            except BaromapError as exc:
                self.close()
                raise RecordingError(f"{self.path}: {exc}") from exc
        header = {
            "robot": robot,
            "format_version": topics.FORMAT_VERSION,
            "writer": f"baromap {__version__}",
            "created_ns": str(time.time_ns()),
        }
        if laser_mount is not None:
            header[LASER_MOUNT_KEY] = laser_mount.to_json()
        header.update(metadata or {})
        self.write_metadata(topics.METADATA_NAME, header)
        if laser_mount is not None:
            self._laser_mount = laser_mount
            self._static_due = True
        log.debug("recording opened", path=str(self.path), robot=robot)

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    @property
    def size_bytes(self) -> int:
        """Bytes on disk so far (what has been flushed), for a recorder that rotates by size."""
        try:
            if self._sync_fd >= 0:
                return os.fstat(self._sync_fd).st_size
            return self.path.stat().st_size
        except OSError as exc:
            raise RecordingError(f"cannot stat recording {self.path}: {exc}") from exc

    @property
    def laser_mount(self) -> LaserMount | None:
        return self._laser_mount

    def set_laser_mount(self, mount: LaserMount) -> None:
        """State the laser mount once it is known (a daemon may learn it after opening).

        Recorded as a ``baromap.frames`` metadata record and as ``/tf_static`` from the next
        message on; a recording states one mount (the mapping reads one), so a second,
        different one is refused.
        """
        if self._laser_mount is not None:
            if mount != self._laser_mount:
                raise RecordingError(
                    f"{self.path} already has laser mount {self._laser_mount}, not {mount}"
                )
            return
        self.write_metadata("baromap.frames", {LASER_MOUNT_KEY: mount.to_json()})
        self._laser_mount = mount
        self._static_due = True

    def write_metadata(self, name: str, data: Mapping[str, str]) -> None:
        bad = {k: v for k, v in data.items() if not isinstance(v, str)}
        if bad:
            raise RecordingError(f"metadata {name!r} values must be strings: {sorted(bad)}")
        try:
            self._writer.write_metadata(name, dict(data))
        except RuntimeError as exc:
            raise self._failed("write metadata to", exc) from exc

    def write(self, message: messages.Message, topic: str | None = None) -> None:
        """Record one message at its own time stamp, on its default topic unless given."""
        cls = type(message)
        if cls not in DEFAULT_TOPICS:
            raise RecordingError(f"cannot record a {cls.__name__}")
        t_ns = message.t_ns
        if not 0 <= t_ns <= MAX_T_NS:
            raise RecordingError(f"{cls.__name__} time {t_ns} ns is outside 1970..2106")
        topic = topic or DEFAULT_TOPICS[cls]
        try:
            if self._laser_mount is not None and (
                self._static_due or not 0 <= t_ns - self._last_static_ns < STATIC_PERIOD_NS
            ):
                self._write_static(t_ns)
            if isinstance(message, messages.LaserScan):
                self._write_scan(topic, message)
            elif isinstance(message, messages.Odometry):
                self._write_odometry(topic, message)
                if topic == topics.ODOM:
                    self._write_tf(message)
            else:
                # the plain channel's own log: Channel.log checks the payload's type first, and
                # every line counts on the recorder's cold caches (bench/writer.py)
                self._json_channel(topic, cls).base.log(jsonmsg.dumps(message), t_ns, None)
        except RuntimeError as exc:  # the MCAP library's errors (FoxgloveError)
            raise self._failed("write to", exc) from exc
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self._dirty = True
        self.flush_if_due()

    def flush_if_due(self) -> bool:
        """Flush when the last flush is ``flush_interval_s`` old and data is waiting."""
        if self._dirty and time.monotonic() - self._last_flush >= self._flush_interval_s:
            self.flush()
            return True
        return False

    def flush(self) -> None:
        """End the current chunk, hand it to the OS and make it durable (fsync).

        After this returns, a SIGKILL or a power cut leaves a file that reads back up to here.
        """
        if self._closed:
            return
        try:
            self._writer.flush()
            if self._sync_fd >= 0:
                os.fsync(self._sync_fd)
        except (RuntimeError, OSError) as exc:
            raise self._failed("flush", exc) from exc
        self._last_flush = time.monotonic()
        self._dirty = False
        # the next chunk starts with the static transform again
        self._static_due = self._laser_mount is not None

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.close()
            if self._sync_fd >= 0:
                os.fsync(self._sync_fd)
        except (RuntimeError, OSError) as exc:
            raise self._failed("close", exc) from exc
        finally:
            if self._file is not None:
                self._file.close()
            if self._sync_fd >= 0:
                os.close(self._sync_fd)
                self._sync_fd = -1
            self._release_channels()
        log.info("recording closed", path=str(self.path), messages=sum(self.counts.values()))

    def _failed(self, action: str, exc: Exception) -> RecordingWriteError:
        """The failure as a :class:`RecordingWriteError` naming what the OS refused, if it did."""
        os_error = exc if isinstance(exc, OSError) else None
        if os_error is None and self._file is not None:
            os_error = self._file.error
        detail = str(exc)
        if os_error is not None and os_error is not exc:
            detail += f" ({os_error.strerror or os_error})"
        return RecordingWriteError(f"cannot {action} {self.path}: {detail}", os_error)

    def _release_channels(self) -> None:
        """Let go of this file's plain channels (JSON, and the scans' protobuf) for good.

        The SDK keeps every ``foxglove.Channel`` ever made in a module-level registry (by id,
        for ``foxglove.log``) and never removes one, closed or not: each file's channels, with
        their schemas, would live as long as the process: a daemon that rotates every minute
        makes four a minute, 1.5 kB each with the SDK's state (``bench/memory.py rotations``
        opens a thousand files in one process). Dropping the
        registry's reference frees them; the SDK's typed channels (scans, odometry,
        transforms) are not in it.
        """
        registry: dict[int, object] | None = getattr(foxglove.channel, "_channels_by_id", None)
        for channel in (*self._json_channels.values(), *self._scan_channels.values()):
            channel.close()
            if registry is not None:
                registry.pop(channel.id(), None)
        self._json_channels.clear()
        self._scan_channels.clear()

    def _json_channel(self, topic: str, cls: type) -> foxglove.Channel:
        key = (topic, cls)
        channel = self._json_channels.get(key)
        if channel is None:
            channel = foxglove.Channel(
                topic, schema=json_schema(cls), message_encoding="json", context=self.context
            )
            self._json_channels[key] = channel
        return channel

    def _write_scan(self, topic: str, scan: messages.LaserScan) -> None:
        """A ``foxglove.LaserScan``, encoded by :mod:`~baromap.recording.foxglove_wire`.

        The bytes are those the SDK's ``LaserScanChannel`` would write, on a channel with the
        same schema and metadata; building the SDK's message objects from two Python lists
        takes twice the CPU a scan (``bench/writer.py``; docs/decisions.md).
        """
        key = (topic, scan.range_max_m)
        channel = self._scan_channels.get(key)
        if channel is None:
            channel = foxglove.Channel(
                topic,
                schema=foxglove_wire.laser_scan_schema(),
                message_encoding="protobuf",
                metadata=scan_channel_metadata(scan),
                context=self.context,
            )
            self._scan_channels[key] = channel
        channel.base.log(self._scan_encoder.encode(scan), scan.t_ns, None)

    def _write_odometry(self, topic: str, odom: messages.Odometry) -> None:
        channel = self._odom_channels.get(topic)
        if channel is None:
            channel = OdometryChannel(
                topic, metadata=ODOMETRY_CHANNEL_METADATA, context=self.context
            )
            self._odom_channels[topic] = channel
        channel.log(odometry_message(odom), log_time=odom.t_ns)

    def _write_tf(self, odom: messages.Odometry) -> None:
        if self._tf_channel is None:
            self._tf_channel = FrameTransformChannel(topics.TF, context=self.context)
        self._tf_channel.log(odometry_transform(odom), log_time=odom.t_ns)

    def _write_static(self, t_ns: int) -> None:
        mount = self._laser_mount
        self._static_due = False
        if mount is None:
            return
        self._last_static_ns = t_ns
        if self._static_channel is None:
            self._static_channel = FrameTransformChannel(topics.TF_STATIC, context=self.context)
        self._static_channel.log(laser_transform(mount, t_ns), log_time=t_ns)
        self.counts[topics.TF_STATIC] = self.counts.get(topics.TF_STATIC, 0) + 1


def fsync_path(path: Path) -> None:
    """Make a file's content, or a directory's entries, durable by path (a new file's directory
    entry too: else a power cut can lose the whole file)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
