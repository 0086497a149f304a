"""Our protobuf encoding of scans is byte for byte the Foxglove SDK's.

The writer logs ``foxglove.LaserScan`` bytes made by :mod:`baromap.recording.foxglove_wire`
instead of the SDK's message objects; a recording must not tell the difference. Every scan is
compared with what the SDK's own ``LaserScan(...).encode()`` gives for it (the bytes its
``LaserScanChannel`` logs), with one encoder for all examples, as in a recording (its kept
layout and seconds must follow the scans), and a fresh one.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from foxglove.channels import LaserScanChannel
from foxglove.messages import LaserScan, Pose, Quaternion, Timestamp, Vector3
from hypothesis import example, given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from mcap.reader import make_reader

from baromap import messages as m
from baromap.recording import RecordingWriter, foxglove_wire
from baromap.recording import topics as t
from baromap.recording.writer import MAX_T_NS

IDENTITY = Pose(
    position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
)
SHARED = foxglove_wire.LaserScanEncoder(t.LASER_FRAME)


def sdk_bytes(scan: m.LaserScan, frame_id: str = t.LASER_FRAME) -> bytes:
    sec, nsec = divmod(scan.t_ns, 1_000_000_000)
    return LaserScan(
        timestamp=Timestamp(sec=sec, nsec=nsec),
        frame_id=frame_id,
        pose=IDENTITY,
        start_angle=scan.angle_min_rad,
        end_angle=scan.angle_max_rad,
        ranges=scan.ranges_m.tolist(),
        intensities=scan.flags.tolist(),
    ).encode()


angles = st.sampled_from([0.0, -0.0, -math.pi / 2, math.radians(0.5), math.radians(1.0)]) | (
    st.floats(-4.0, 4.0, allow_nan=False)
)


@st.composite
def scans(draw: st.DrawFn) -> m.LaserScan:
    beams = draw(st.sampled_from([0, 1, 181, 361]) | st.integers(0, 400))
    ranges = draw(
        hnp.arrays(
            np.float32,
            beams,
            elements=st.floats(width=32, allow_nan=True, allow_infinity=True)
            | st.sampled_from([np.nan, 0.0, -0.0, 8.183]),
        )
    )
    flags = draw(hnp.arrays(np.uint16, beams))
    t_ns = draw(
        st.integers(0, MAX_T_NS)
        | st.sampled_from([0, 1, 999_999_999, 1_000_000_000, MAX_T_NS])
        | st.integers(0, 2**32 - 1).map(lambda sec: sec * 1_000_000_000)
    )
    return m.LaserScan(
        t_ns=t_ns,
        angle_min_rad=draw(angles),
        angle_increment_rad=draw(angles),
        range_max_m=8.183,
        ranges_m=ranges,
        flags=flags,
    )


def lms_scan(beams: int, t_ns: int, nan_every: int = 7) -> m.LaserScan:
    ranges = np.linspace(0.3, 8.0, beams, dtype=np.float32)
    ranges[::nan_every] = np.nan
    flags = np.zeros(beams, np.uint16)
    flags[::nan_every] = m.BeamFlag.DAZZLE
    return m.LaserScan(t_ns, -math.pi / 2, math.pi / max(beams - 1, 1), 8.183, ranges, flags)


@pytest.mark.slow
@given(scans())
@example(lms_scan(181, 1_764_000_000_123_456_789))
@example(lms_scan(361, MAX_T_NS))
@example(lms_scan(0, 0))
def test_scan_bytes_are_the_sdks(scan: m.LaserScan) -> None:
    expected = sdk_bytes(scan)
    assert SHARED.encode(scan) == expected
    assert foxglove_wire.LaserScanEncoder(t.LASER_FRAME).encode(scan) == expected


@pytest.mark.slow
@given(st.lists(scans(), min_size=2, max_size=6))
def test_one_encoder_follows_changing_scans(batch: list[m.LaserScan]) -> None:
    encoder = foxglove_wire.LaserScanEncoder("laser_2")
    for scan in batch:
        assert encoder.encode(scan) == sdk_bytes(scan, "laser_2")


@given(st.integers(0, 2**64 - 1))
def test_varint_is_protobufs(value: int) -> None:
    # a time stamp's seconds as the SDK encodes them: 0a <length> 08 <varint>
    sec = value % 2**32
    encoded = LaserScan(timestamp=Timestamp(sec=sec, nsec=0)).encode()
    if sec:  # (a zero is left out)
        assert foxglove_wire.varint(sec) == encoded[3:]
    data, shift, decoded = foxglove_wire.varint(value), 0, 0
    for byte in data:
        decoded |= (byte & 0x7F) << shift
        shift += 7
    assert decoded == value
    assert all(b & 0x80 for b in data[:-1]) and not data[-1] & 0x80


def test_a_recorded_scan_channel_is_the_sdks(tmp_path: Path) -> None:
    """Schema, encoding, channel metadata and message bytes: what a ``LaserScanChannel`` gives."""
    import io

    import foxglove

    scan = lms_scan(181, 1_764_000_000_123_456_789)
    ours = tmp_path / "ours.mcap"
    with RecordingWriter(ours, robot="r1") as writer:
        writer.write(scan)
    theirs = tmp_path / "theirs.mcap"
    context = foxglove.Context()
    with io.FileIO(theirs, "w") as file:
        sdk = foxglove.open_mcap(file, context=context)
        channel = LaserScanChannel(
            t.SCAN,
            metadata={
                "range_max_m": repr(scan.range_max_m),
                "range_min_m": repr(scan.range_min_m),
                "intensities": "baromap.BeamFlag bits per beam",
            },
            context=context,
        )
        sec, nsec = divmod(scan.t_ns, 1_000_000_000)
        channel.log(
            LaserScan(
                timestamp=Timestamp(sec=sec, nsec=nsec),
                frame_id=t.LASER_FRAME,
                pose=IDENTITY,
                start_angle=scan.angle_min_rad,
                end_angle=scan.angle_max_rad,
                ranges=scan.ranges_m.tolist(),
                intensities=scan.flags.tolist(),
            ),
            log_time=scan.t_ns,
        )
        sdk.close()

    def records(path: Path) -> list[tuple[object, ...]]:
        with path.open("rb") as f:
            return [
                (s.name, s.encoding, s.data, c.topic, c.message_encoding, c.metadata, msg.data)
                for s, c, msg in make_reader(f).iter_messages(topics=[t.SCAN])
            ]

    assert records(ours) == records(theirs)  # log times, sequences: the writer's own tests
    assert len(records(ours)) == 1
