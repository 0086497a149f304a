"""Write a run into one MCAP file that Foxglove opens without plugins.

Scans go out as ``foxglove.LaserScan`` (per-beam :class:`~baromap.messages.BeamFlag` bits ride
in ``intensities``: the LMS200 reports no intensity in its ranging modes; the range limits ride
in the channel's metadata; the status byte is the session's business, on ``/diagnostics``),
odometry also as a
``foxglove.FrameTransform`` on ``/tf`` so the 3D panel can follow the robot; everything else is
JSON with a JSON Schema (:mod:`baromap.jsonmsg`). Chunks are flushed at least every
``flush_interval_s`` of wall time, so a power cut loses about a second, not a chunk's worth.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType

import foxglove
import structlog
from foxglove.channels import FrameTransformChannel, LaserScanChannel
from foxglove.mcap import MCAPWriteOptions
from foxglove.messages import (
    FrameTransform,
    LaserScan,
    Pose,
    Quaternion,
    Timestamp,
    Vector3,
)

from baromap import __version__, jsonmsg, messages
from baromap.errors import RecordingError
from baromap.recording import topics

log = structlog.get_logger(__name__)

DEFAULT_TOPICS: dict[type, str] = {
    messages.PressureSample: topics.BARO,
    messages.LaserScan: topics.SCAN,
    messages.Odometry: topics.ODOM,
    messages.FloorEvent: topics.FLOOR_EVENT,
    messages.FloorState: topics.FLOOR_STATE,
    messages.DeviceHealth: topics.DIAGNOSTICS,
    messages.TruthPose: topics.TRUTH_POSE,
    messages.TruthFloor: topics.TRUTH_FLOOR,
}


#: Foxglove time stamps hold unsigned 32-bit seconds: the Unix epoch to early 2106.
MAX_T_NS = 2**32 * 1_000_000_000 - 1


def stamp(t_ns: int) -> Timestamp:
    sec, nsec = divmod(t_ns, 1_000_000_000)
    return Timestamp(sec=sec, nsec=nsec)


def yaw_quaternion(theta: float) -> Quaternion:
    return Quaternion(x=0.0, y=0.0, z=math.sin(theta / 2), w=math.cos(theta / 2))


_IDENTITY_POSE = Pose(
    position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
)


class RecordingWriter:
    """One MCAP file of one run.

    Not thread-safe by design: the daemon gives it to one recorder thread fed by a queue.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        robot: str,
        metadata: Mapping[str, str] | None = None,
        flush_interval_s: float = 1.0,
        allow_overwrite: bool = False,
    ) -> None:
        self.path = Path(path)
        self.context = foxglove.Context()
        self._flush_interval_s = flush_interval_s
        self._last_flush = time.monotonic()
        self._json_channels: dict[tuple[str, type], foxglove.Channel] = {}
        self._scan_channels: dict[tuple[str, float], LaserScanChannel] = {}
        self._tf_channel: FrameTransformChannel | None = None
        self.counts: dict[str, int] = {}
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = foxglove.open_mcap(
                str(self.path),
                allow_overwrite=allow_overwrite,
                context=self.context,
                writer_options=MCAPWriteOptions(profile="baromap"),
            )
        except (OSError, RuntimeError, ValueError) as exc:
            raise RecordingError(f"cannot create recording {self.path}: {exc}") from exc
        header = {
            "robot": robot,
            "format_version": topics.FORMAT_VERSION,
            "writer": f"baromap {__version__}",
            "created_ns": str(time.time_ns()),
        }
        header.update(metadata or {})
        self.write_metadata(topics.METADATA_NAME, header)
        self._closed = False
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

    def write_metadata(self, name: str, data: Mapping[str, str]) -> None:
        bad = {k: v for k, v in data.items() if not isinstance(v, str)}
        if bad:
            raise RecordingError(f"metadata {name!r} values must be strings: {sorted(bad)}")
        self._writer.write_metadata(name, dict(data))

    def write(self, message: messages.Message, topic: str | None = None) -> None:
        """Record one message at its own time stamp, on its default topic unless given."""
        cls = type(message)
        if cls not in DEFAULT_TOPICS:
            raise RecordingError(f"cannot record a {cls.__name__}")
        if not 0 <= message.t_ns <= MAX_T_NS:
            raise RecordingError(f"{cls.__name__} time {message.t_ns} ns is outside 1970..2106")
        topic = topic or DEFAULT_TOPICS[cls]
        if isinstance(message, messages.LaserScan):
            self._write_scan(topic, message)
        else:
            self._json_channel(topic, cls).log(jsonmsg.dumps(message), log_time=message.t_ns)
            if isinstance(message, messages.Odometry) and topic == topics.ODOM:
                self._write_tf(message)
        self.counts[topic] = self.counts.get(topic, 0) + 1
        now = time.monotonic()
        if now - self._last_flush >= self._flush_interval_s:
            self.flush()

    def flush(self) -> None:
        """End the current chunk and push it to the file."""
        self._writer.flush()
        self._last_flush = time.monotonic()

    def close(self) -> None:
        if getattr(self, "_closed", True):
            return
        self._closed = True
        self._writer.close()
        log.info("recording closed", path=str(self.path), messages=sum(self.counts.values()))

    def _json_channel(self, topic: str, cls: type) -> foxglove.Channel:
        key = (topic, cls)
        channel = self._json_channels.get(key)
        if channel is None:
            schema = foxglove.Schema(
                name=jsonmsg.schema_name(cls),
                encoding="jsonschema",
                data=jsonmsg.json_schema(cls),
            )
            channel = foxglove.Channel(
                topic, schema=schema, message_encoding="json", context=self.context
            )
            self._json_channels[key] = channel
        return channel

    def _write_scan(self, topic: str, scan: messages.LaserScan) -> None:
        key = (topic, scan.range_max_m)
        channel = self._scan_channels.get(key)
        if channel is None:
            channel = LaserScanChannel(
                topic,
                metadata={
                    "range_max_m": repr(scan.range_max_m),
                    "range_min_m": repr(scan.range_min_m),
                    "intensities": "baromap.BeamFlag bits per beam",
                },
                context=self.context,
            )
            self._scan_channels[key] = channel
        channel.log(
            LaserScan(
                timestamp=stamp(scan.t_ns),
                frame_id=topics.LASER_FRAME,
                pose=_IDENTITY_POSE,
                start_angle=scan.angle_min_rad,
                end_angle=scan.angle_max_rad,
                ranges=scan.ranges_m.tolist(),
                intensities=scan.flags.tolist(),
            ),
            log_time=scan.t_ns,
        )

    def _write_tf(self, odom: messages.Odometry) -> None:
        if self._tf_channel is None:
            self._tf_channel = FrameTransformChannel(topics.TF, context=self.context)
        self._tf_channel.log(
            FrameTransform(
                timestamp=stamp(odom.t_ns),
                parent_frame_id=topics.ODOM_FRAME,
                child_frame_id=topics.BASE_FRAME,
                translation=Vector3(x=odom.x_m, y=odom.y_m, z=0.0),
                rotation=yaw_quaternion(odom.theta_rad),
            ),
            log_time=odom.t_ns,
        )
