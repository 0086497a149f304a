"""Topic names of a baromap recording (DESIGN.md), in one place."""

BARO = "/baro"
SCAN = "/scan"
ODOM = "/odom"
TF = "/tf"
FLOOR_EVENT = "/floor/event"
FLOOR_STATE = "/floor/state"
DIAGNOSTICS = "/diagnostics"
TRUTH_POSE = "/truth/pose"
TRUTH_FLOOR = "/truth/floor"
REFERENCE_PRESSURE = "/reference/pressure"

#: Metadata record every recording starts with (robot id, format, configuration, devices).
METADATA_NAME = "baromap"
FORMAT_VERSION = "1"

#: Frames: odometry is published as odom -> base_link; scans are in the laser frame.
ODOM_FRAME = "odom"
BASE_FRAME = "base_link"
LASER_FRAME = "laser"
