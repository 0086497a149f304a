"""The live view's channels: a recording's, message for message, plus the live map.

Every message the daemon records goes out here on the same topic, with the same schema, the
same encoding and the same frames (the writer's own builders and encoders,
:mod:`baromap.recording.writer`), so a Foxglove layout made on a recording works live and
back. The live map adds channels a recording does not have:

- ``/live/map``: the current floor's ``foxglove.Grid`` in ``map``, lifted to the floor's
  height, cells as in ``maps.mcap`` (occupancy 0-100, -1 unknown, as int8);
- ``/live/path``: the robot's keyframe poses on it (``foxglove.PosesInFrame``);
- ``/live/map/info``: whose floor it is and how it was built (JSON, :class:`LiveMapInfo`);
- ``map -> odom`` on ``/tf``, as ``maps.mcap`` has it: the scans and the robot land on the map.

One :class:`foxglove.Context` holds them; the caller attaches a sink (the SDK's WebSocket
server). The SDK's channels are thread-safe: a reader of the daemon's messages and the live
map's thread log to them side by side.
"""

from __future__ import annotations

import foxglove
from foxglove.channels import (
    FrameTransformChannel,
    GridChannel,
    OdometryChannel,
    PosesInFrameChannel,
)
from foxglove.messages import (
    FrameTransform,
    Pose,
    PosesInFrame,
    Vector3,
)

from baromap import jsonmsg, messages
from baromap.liveview.floor_map import LiveMapInfo, LiveMapSnapshot
from baromap.mapping.foxglove_maps import grid_message
from baromap.recording import foxglove_wire, topics
from baromap.recording.frames import LaserMount
from baromap.recording.writer import (
    DEFAULT_TOPICS,
    ODOMETRY_CHANNEL_METADATA,
    STATIC_PERIOD_NS,
    json_schema,
    laser_transform,
    odometry_message,
    odometry_transform,
    scan_channel_metadata,
    stamp,
    yaw_quaternion,
)

LIVE_MAP = "/live/map"
LIVE_PATH = "/live/path"
LIVE_MAP_INFO = "/live/map/info"
#: The daemon's JSON messages, their channels made before any viewer joins. A channel made
#: while a viewer was connected was once advertised to it and its subscription then refused
#: ("attempted to subscribe to unknown channel" in the SDK's log), and that viewer got
#: nothing on the topic for the whole run. A simulator's truth stays lazy: a robot has none.
EAGER_JSON = (
    messages.PressureSample,
    messages.FloorState,
    messages.FloorEvent,
    messages.RideEvent,
    messages.DeviceHealth,
)


class ViewChannels:
    """Log the daemon's messages and the live map to one context's channels."""

    def __init__(self, context: foxglove.Context, laser_mount: LaserMount | None = None) -> None:
        self.context = context
        self._mount = laser_mount
        self._last_static_ns = -STATIC_PERIOD_NS
        self._json: dict[type, foxglove.Channel] = {}
        self._scans: dict[float, foxglove.Channel] = {}
        self._scan_encoder = foxglove_wire.LaserScanEncoder(topics.LASER_FRAME)
        self._odom = OdometryChannel(
            topics.ODOM, metadata=ODOMETRY_CHANNEL_METADATA, context=context
        )
        self._tf = FrameTransformChannel(topics.TF, context=context)
        self._static = FrameTransformChannel(topics.TF_STATIC, context=context)
        self._grid = GridChannel(LIVE_MAP, context=context)
        self._path = PosesInFrameChannel(LIVE_PATH, context=context)
        self._info = self._json_channel(LIVE_MAP_INFO, LiveMapInfo)
        for cls in EAGER_JSON:
            self._json[cls] = self._json_channel(DEFAULT_TOPICS[cls], cls)
        #: messages of a type a recording has no channel for (none today; a newer sender)
        self.unknown = 0

    def _json_channel(self, topic: str, cls: type) -> foxglove.Channel:
        return foxglove.Channel(
            topic, schema=json_schema(cls), message_encoding="json", context=self.context
        )

    def log(self, message: messages.Message) -> None:
        """One daemon message on its recording channel."""
        t_ns = message.t_ns
        if self._mount is not None and not 0 <= t_ns - self._last_static_ns < STATIC_PERIOD_NS:
            # base_link -> laser every second, as a recording repeats it: a viewer that joins
            # late has it within a second
            self._last_static_ns = t_ns
            self._static.log(laser_transform(self._mount, t_ns), log_time=t_ns)
        if isinstance(message, messages.LaserScan):
            channel = self._scans.get(message.range_max_m)
            if channel is None:
                channel = foxglove.Channel(
                    topics.SCAN,
                    schema=foxglove_wire.laser_scan_schema(),
                    message_encoding="protobuf",
                    metadata=scan_channel_metadata(message),
                    context=self.context,
                )
                self._scans[message.range_max_m] = channel
            channel.base.log(self._scan_encoder.encode(message), t_ns, None)
        elif isinstance(message, messages.Odometry):
            self._odom.log(odometry_message(message), log_time=t_ns)
            self._tf.log(odometry_transform(message), log_time=t_ns)
        else:
            cls = type(message)
            json_channel = self._json.get(cls)
            if json_channel is None:
                topic = DEFAULT_TOPICS.get(cls)
                if topic is None:
                    self.unknown += 1
                    return
                json_channel = self._json_channel(topic, cls)
                self._json[cls] = json_channel
            json_channel.base.log(jsonmsg.dumps(message), t_ns, None)

    def log_map(self, snapshot: LiveMapSnapshot) -> None:
        """The live map: grid, path, ``map -> odom`` and what the grid is, at one time."""
        info = snapshot.info
        t_ns = info.t_ns
        z = info.height_m
        self._grid.log(grid_message(snapshot.grid, z, t_ns), log_time=t_ns)
        self._path.log(
            PosesInFrame(
                timestamp=stamp(t_ns),
                frame_id=topics.MAP_FRAME,
                poses=[
                    Pose(
                        position=Vector3(x=float(x), y=float(y), z=z),
                        orientation=yaw_quaternion(float(theta)),
                    )
                    for x, y, theta in snapshot.path
                ],
            ),
            log_time=t_ns,
        )
        x, y, theta = (float(v) for v in snapshot.map_to_odom)
        self._tf.log(
            FrameTransform(
                timestamp=stamp(t_ns),
                parent_frame_id=topics.MAP_FRAME,
                child_frame_id=topics.ODOM_FRAME,
                translation=Vector3(x=x, y=y, z=z),
                rotation=yaw_quaternion(theta),
            ),
            log_time=t_ns,
        )
        self._info.base.log(jsonmsg.dumps(info), t_ns, None)
