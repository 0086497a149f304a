"""The coordinate frames of a run and the one static transform the robot carries.

The frame tree (docs/design.md): ``laser`` -> ``base_link`` (static, from the laser mount) ->
``odom`` (odometry, on ``/tf``) -> ``map`` (the SLAM correction, in maps.mcap). The robot is
planar, so every transform here is (x, y, yaw); quaternions are only the wire form.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass

from baromap.errors import InputFormatError

MAP_FRAME = "map"
ODOM_FRAME = "odom"
BASE_FRAME = "base_link"
LASER_FRAME = "laser"

#: Metadata key (in the ``baromap`` record) holding the mount as JSON, the spelling the
#: simulator and the daemon's configuration use.
LASER_MOUNT_KEY = "laser_mount"
#: The CARMEN importer's spelling: ``"x y theta"``.
LASER_OFFSET_KEY = "laser_offset"


@dataclass(frozen=True, slots=True)
class LaserMount:
    """Where the laser sits on the base: its origin and heading in ``base_link``."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) for v in (self.x_m, self.y_m, self.yaw_rad)):
            raise InputFormatError(f"laser mount {self} is not finite")

    def to_json(self) -> str:
        return json.dumps({"x_m": self.x_m, "y_m": self.y_m, "yaw_rad": self.yaw_rad})

    @classmethod
    def from_json(cls, text: str) -> LaserMount:
        try:
            data = json.loads(text)
            return cls(
                float(data.get("x_m", 0.0)),
                float(data.get("y_m", 0.0)),
                float(data.get("yaw_rad", 0.0)),
            )
        except (ValueError, TypeError, AttributeError) as exc:
            raise InputFormatError(f"{LASER_MOUNT_KEY} metadata {text!r}: {exc}") from exc

    @classmethod
    def from_record(cls, record: Mapping[str, str]) -> LaserMount | None:
        """The mount one metadata record states, in either spelling, if it does."""
        text = record.get(LASER_MOUNT_KEY)
        if text:
            return cls.from_json(text)
        offset = record.get(LASER_OFFSET_KEY)
        if offset:
            try:
                x, y, yaw = (float(v) for v in offset.replace(",", " ").split())
            except ValueError as exc:
                raise InputFormatError(f"{LASER_OFFSET_KEY} {offset!r} is not 'x y theta'") from exc
            return cls(x, y, yaw)
        return None

    @classmethod
    def from_metadata(cls, metadata: Mapping[str, Mapping[str, str]]) -> LaserMount | None:
        """The mount a recording states in any metadata record, if one does."""
        for record in metadata.values():
            mount = cls.from_record(record)
            if mount is not None:
                return mount
        return None


def yaw_to_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation about z."""
    return 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)


def quaternion_to_yaw(x: float, y: float, z: float, w: float) -> float:
    """Heading of a rotation (exact for rotations about z; the z component of others)."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
