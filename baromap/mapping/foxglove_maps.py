"""``maps.mcap``: the finished maps and path in Foxglove's standard schemas.

Each floor is a ``foxglove.Grid`` on ``/map/floor_<k>`` whose pose lifts it to the floor's
elevation, so Foxglove's 3D panel shows the building stacked as in ``building.png``; the
corrected path is a ``PosesInFrame`` on ``/path`` (all floors, z = floor elevation) and one per
floor on ``/path/floor_<k>``. Cell values are occupancy percentages (0-100, 255 unknown), the
convention of ROS ``OccupancyGrid`` that Foxglove's "map" colour mode expects when the field is
read as int8 (-1 unknown).

``/tf`` carries ``map -> odom`` over the run (``foxglove.FrameTransform``): the SLAM's
correction of odometry, ``corrected pose (+) odometry pose^-1``, lifted to the floor's
elevation. Opened together with the run's recording (``odom -> base_link`` on its ``/tf``,
``base_link -> laser`` on ``/tf_static``), the scans, the robot and the maps overlay in one
frame tree: ``laser -> base_link -> odom -> map``. One transform per keyframe (a few per
second of driving); Foxglove interpolates between them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray
from baromap.mapping import se2
from baromap.mapping.occupancy import OccupancyGrid
from baromap.recording import topics

FRAME = topics.MAP_FRAME


def occupancy_int8(grid: OccupancyGrid) -> npt.NDArray[np.int8]:
    """Occupancy 0..100, -1 for unknown (never observed), rows from the lowest y."""
    pct = np.rint(grid.probability() * 100).astype(np.int8)
    out: npt.NDArray[np.int8] = np.where(grid.log_odds == 0, np.int8(-1), pct).astype(np.int8)
    return out


def write_maps_mcap(
    path: Path,
    t_ns: int,
    *,
    floors: Sequence[int],
    grids: Sequence[OccupancyGrid],
    elevations_m: Sequence[float],
    scan_poses: FloatArray,
    scan_z_m: FloatArray,
    scan_floor: npt.NDArray[np.int64],
    scan_t_ns: npt.NDArray[np.int64],
    odom: FloatArray,
    transform_at: npt.NDArray[np.int64],
    estimated: npt.NDArray[np.bool_] | None = None,
) -> None:
    """``t_ns``: when the maps and paths are stamped (the run's start, so a player shows them
    from the first instant on); ``transform_at``: the scans whose map -> odom is written;
    ``estimated``: the scans whose poses the SLAM estimated (default all). The others are
    only drawn across a gap in the odometry, metres off, so the paths leave them out as
    ``trajectory.tum`` does."""
    import foxglove
    from foxglove.channels import FrameTransformChannel, GridChannel, PosesInFrameChannel
    from foxglove.messages import (
        FrameTransform,
        Grid,
        PackedElementField,
        PackedElementFieldNumericType,
        Pose,
        PosesInFrame,
        Quaternion,
        Timestamp,
        Vector2,
        Vector3,
    )

    def stamp(t: int) -> Timestamp:
        sec, nsec = divmod(int(t), 1_000_000_000)
        return Timestamp(sec=sec, nsec=nsec)

    def yaw(theta: float) -> Quaternion:
        return Quaternion(x=0.0, y=0.0, z=math.sin(theta / 2), w=math.cos(theta / 2))

    def pose(x: float, y: float, z: float, theta: float) -> Pose:
        return Pose(position=Vector3(x=x, y=y, z=z), orientation=yaw(theta))

    context = foxglove.Context()
    writer = foxglove.open_mcap(str(path), allow_overwrite=True, context=context)
    try:
        # channels are named by floor index, which skips a floor that has no map
        for k, grid, z in zip(floors, grids, elevations_m, strict=True):
            w = grid.shape[1]
            channel = GridChannel(f"/map/floor_{k}", context=context)
            channel.log(
                Grid(
                    timestamp=stamp(t_ns),
                    frame_id=FRAME,
                    pose=pose(grid.origin_xy[0], grid.origin_xy[1], float(z), 0.0),
                    column_count=w,
                    cell_size=Vector2(x=grid.resolution, y=grid.resolution),
                    row_stride=w,
                    cell_stride=1,
                    fields=[
                        PackedElementField(
                            name="occupancy", offset=0, type=PackedElementFieldNumericType.Int8
                        )
                    ],
                    data=occupancy_int8(grid).tobytes(),
                ),
                log_time=t_ns,
            )
        shown = np.arange(len(scan_poses)) if estimated is None else np.flatnonzero(estimated)
        sel = shown[:: max(1, len(shown) // 5000)]
        path_channel = PosesInFrameChannel("/path", context=context)
        path_channel.log(
            PosesInFrame(
                timestamp=stamp(t_ns),
                frame_id=FRAME,
                poses=[
                    pose(scan_poses[i, 0], scan_poses[i, 1], float(scan_z_m[i]), scan_poses[i, 2])
                    for i in sel
                ],
            ),
            log_time=t_ns,
        )
        for k, z in zip(floors, elevations_m, strict=True):
            mine = sel[scan_floor[sel] == k]
            PosesInFrameChannel(f"/path/floor_{k}", context=context).log(
                PosesInFrame(
                    timestamp=stamp(t_ns),
                    frame_id=FRAME,
                    poses=[
                        pose(scan_poses[i, 0], scan_poses[i, 1], float(z), scan_poses[i, 2])
                        for i in mine
                    ],
                ),
                log_time=t_ns,
            )
        tf = FrameTransformChannel(topics.TF, context=context)
        correction = se2.compose(scan_poses[transform_at], se2.inverse(odom[transform_at]))
        for k, (x, y, theta) in zip(transform_at, correction, strict=True):
            t = int(scan_t_ns[k])
            tf.log(
                FrameTransform(
                    timestamp=stamp(t),
                    parent_frame_id=topics.MAP_FRAME,
                    child_frame_id=topics.ODOM_FRAME,
                    translation=Vector3(x=float(x), y=float(y), z=float(scan_z_m[k])),
                    rotation=yaw(float(theta)),
                ),
                log_time=t,
            )
    finally:
        writer.close()
