"""Topic names of a baromap recording (DESIGN.md), in one place."""

from baromap.recording.frames import BASE_FRAME, LASER_FRAME, MAP_FRAME, ODOM_FRAME

BARO = "/baro"
SCAN = "/scan"
ODOM = "/odom"
TF = "/tf"
#: The base_link -> laser transform; repeated at the start of every chunk (see the writer).
TF_STATIC = "/tf_static"
FLOOR_EVENT = "/floor/event"
FLOOR_STATE = "/floor/state"
DIAGNOSTICS = "/diagnostics"
TRUTH_POSE = "/truth/pose"
TRUTH_FLOOR = "/truth/floor"
REFERENCE_PRESSURE = "/reference/pressure"

#: Metadata record every recording starts with (robot id, format, configuration, devices).
METADATA_NAME = "baromap"
#: 2: /odom as foxglove.Odometry (raw counters in its metadata), /tf_static. 1 read too.
FORMAT_VERSION = "2"

__all__ = [
    "BARO",
    "BASE_FRAME",
    "DIAGNOSTICS",
    "FLOOR_EVENT",
    "FLOOR_STATE",
    "FORMAT_VERSION",
    "LASER_FRAME",
    "MAP_FRAME",
    "METADATA_NAME",
    "ODOM",
    "ODOM_FRAME",
    "REFERENCE_PRESSURE",
    "SCAN",
    "TF",
    "TF_STATIC",
    "TRUTH_FLOOR",
    "TRUTH_POSE",
]
