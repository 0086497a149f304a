"""Foxglove's protobuf messages encoded from ours directly, the bytes the SDK would write.

The writer records scans as ``foxglove.LaserScan`` (protobuf, the SDK's own schema). Built
through the SDK, a scan becomes two Python lists of 181 floats, a tree of message objects and
a protobuf encoding in Rust. Here the fixed fields (frame, pose, angles) are bytes made once,
the time stamp a few bytes a message, and the ranges and flags one packed ``repeated double``
each, straight from their numpy arrays: half the CPU in a loop, and less on the daemon's
recorder, whose caches are cold at every scan (``bench/writer.py``; docs/decisions.md).

The bytes are the SDK's (prost's proto3 encoding), which the tests check on random messages:
fields in tag order, scalars equal to zero left out (``-0.0`` too: it compares equal to
zero), sub-messages written even when empty, packed repeated fields left out when empty.
Sans-I/O: bytes out, the writer logs them on a plain ``foxglove.Channel`` that carries the
SDK's schema (:func:`laser_scan_schema`).
"""

from __future__ import annotations

import math
import struct
from typing import Final

import foxglove
import foxglove.messages
import numpy as np

from baromap import messages

_DOUBLE: Final = struct.Struct("<d")
_LITTLE_F64: Final = np.dtype("<f8")

#: Wire types.
_I64: Final = 1
_LEN: Final = 2


def varint(value: int) -> bytes:
    """An unsigned base-128 varint (protobuf's ``uint64``, and ``int64`` >= 0)."""
    if value < 0x80:
        return bytes((value,))
    out = bytearray()
    while value > 0x7F:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def _key(field: int, wire_type: int) -> bytes:
    return varint(field << 3 | wire_type)


def length_delimited(field: int, payload: bytes) -> bytes:
    return _key(field, _LEN) + varint(len(payload)) + payload


def double(field: int, value: float) -> bytes:
    """A ``double`` field; proto3 leaves a zero out (-0.0 compares equal, so it goes too)."""
    return _key(field, _I64) + _DOUBLE.pack(value) if value != 0.0 else b""


def vector3(x: float, y: float, z: float) -> bytes:
    return double(1, x) + double(2, y) + double(3, z)


def quaternion(x: float, y: float, z: float, w: float) -> bytes:
    return double(1, x) + double(2, y) + double(3, z) + double(4, w)


def pose(
    position: tuple[float, float, float], orientation: tuple[float, float, float, float]
) -> bytes:
    """A ``foxglove.Pose`` (its two sub-messages always written, as the SDK does)."""
    return length_delimited(1, vector3(*position)) + length_delimited(2, quaternion(*orientation))


IDENTITY_POSE: Final = pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))


def laser_scan_schema() -> foxglove.Schema:
    """The SDK's own ``foxglove.LaserScan`` schema (name, protobuf, its descriptor set)."""
    return foxglove.messages.LaserScan.get_schema()


class LaserScanEncoder:
    """``foxglove.LaserScan`` bytes of our scans, for one frame and pose.

    Written for a thread whose caches are cold at every scan, so a scan touches little: a
    scanner's angles and beam count are the same scan after scan, so the fields from
    ``frame_id`` to ``end_angle`` and the packed fields' keys are encoded when they change
    and kept, and so is the time stamp's seconds field (it changes once a second).
    """

    __slots__ = (
        "_beams",
        "_fixed",
        "_flags_key",
        "_frame_and_pose",
        "_ranges_key",
        "_sec",
        "_sec_field",
        "_start",
        "_step",
    )

    def __init__(self, frame_id: str, pose_bytes: bytes = IDENTITY_POSE) -> None:
        self._frame_and_pose = length_delimited(2, frame_id.encode()) + length_delimited(
            3, pose_bytes
        )
        self._start = self._step = math.nan  # matches no scan: the first one lays out
        self._beams = -1
        self._fixed = self._ranges_key = self._flags_key = b""
        self._sec = -1
        self._sec_field = b""

    def encode(self, scan: messages.LaserScan) -> bytes:
        ranges = scan.ranges_m
        if (
            ranges.shape[0] != self._beams
            or scan.angle_min_rad != self._start
            or scan.angle_increment_rad != self._step
        ):
            self._lay_out(scan)
        sec, nsec = divmod(scan.t_ns, 1_000_000_000)
        if sec != self._sec:
            self._sec = sec
            self._sec_field = b"\x08" + varint(sec) if sec else b""
        stamp = self._sec_field + b"\x10" + varint(nsec) if nsec else self._sec_field
        if not self._beams:  # packed fields are left out when empty
            return b"\x0a" + bytes((len(stamp),)) + stamp + self._fixed
        return b"".join(
            (
                b"\x0a",  # field 1, length-delimited; a time stamp is under 128 bytes
                bytes((len(stamp),)),
                stamp,
                self._fixed,
                self._ranges_key,
                ranges.astype(_LITTLE_F64).tobytes(),
                self._flags_key,
                scan.flags.astype(_LITTLE_F64).tobytes(),
            )
        )

    def _lay_out(self, scan: messages.LaserScan) -> None:
        self._start, self._step = scan.angle_min_rad, scan.angle_increment_rad
        self._beams = scan.ranges_m.shape[0]
        self._fixed = (
            self._frame_and_pose + double(4, scan.angle_min_rad) + double(5, scan.angle_max_rad)
        )
        size = varint(8 * self._beams)
        self._ranges_key = _key(6, _LEN) + size
        self._flags_key = _key(7, _LEN) + size
