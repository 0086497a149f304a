"""Topic names of a baromap recording (docs/design.md), in one place."""

from baromap.recording.frames import BASE_FRAME, LASER_FRAME, MAP_FRAME, ODOM_FRAME

BARO = "/baro"
SCAN = "/scan"
ODOM = "/odom"
TF = "/tf"
#: The base_link -> laser transform; repeated at the start of every chunk (see the writer).
TF_STATIC = "/tf_static"
FLOOR_EVENT = "/floor/event"
FLOOR_RIDE = "/floor/ride"
FLOOR_STATE = "/floor/state"
DIAGNOSTICS = "/diagnostics"
TRUTH_POSE = "/truth/pose"
TRUTH_FLOOR = "/truth/floor"
REFERENCE_PRESSURE = "/reference/pressure"

#: Metadata record every recording starts with (robot id, format, configuration, devices).
METADATA_NAME = "baromap"
#: A key of that record: "joined" when the recorder kept /odom in one frame across the base's
#: restarts (baromapd joins a base that counts from zero again at its last pose), so a reader
#: need not look for restarts itself.
ODOMETRY_TRACKS_KEY = "odometry_tracks"
ODOMETRY_TRACKS_JOINED = "joined"
#: A key of that record: the daemon that made the recording, "baromapd <version>". Its scans
#: and odometry are stamped as they arrived, upper bounds of when they were sent.
DAEMON_KEY = "daemon"
DAEMON_NAME = "baromapd"
#: 2: /odom as foxglove.Odometry (raw counters in its metadata), /tf_static. 1 read too.
FORMAT_VERSION = "2"

__all__ = [
    "BARO",
    "BASE_FRAME",
    "DAEMON_KEY",
    "DAEMON_NAME",
    "DIAGNOSTICS",
    "FLOOR_EVENT",
    "FLOOR_RIDE",
    "FLOOR_STATE",
    "FORMAT_VERSION",
    "LASER_FRAME",
    "MAP_FRAME",
    "METADATA_NAME",
    "ODOM",
    "ODOMETRY_TRACKS_JOINED",
    "ODOMETRY_TRACKS_KEY",
    "ODOM_FRAME",
    "REFERENCE_PRESSURE",
    "SCAN",
    "TF",
    "TF_STATIC",
    "TRUTH_FLOOR",
    "TRUTH_POSE",
]
