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

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import foxglove
import numpy as np
import numpy.typing as npt
from foxglove.channels import FrameTransformChannel, GridChannel, PosesInFrameChannel
from foxglove.messages import (
    FrameTransform,
    Grid,
    PackedElementField,
    PackedElementFieldNumericType,
    Pose,
    PosesInFrame,
    Vector2,
    Vector3,
)

from baromap.arrays import BoolArray, FloatArray, IntArray
from baromap.mapping import se2
from baromap.mapping.occupancy import OccupancyGrid
from baromap.recording import topics
from baromap.recording.writer import stamp, yaw_quaternion

FRAME = topics.MAP_FRAME


def occupancy_int8(grid: OccupancyGrid) -> npt.NDArray[np.int8]:
    """Occupancy 0..100, -1 for unknown (never observed), rows from the lowest y."""
    pct = np.rint(grid.probability() * 100).astype(np.int8)
    out: npt.NDArray[np.int8] = np.where(grid.log_odds == 0, np.int8(-1), pct).astype(np.int8)
    return out


@dataclass(frozen=True, slots=True)
class FloorMap:
    """One floor's finished grid and the elevation its pose lifts it to."""

    index: int
    grid: OccupancyGrid
    elevation_m: float


@dataclass(frozen=True, slots=True)
class MapsRun:
    """The run as ``maps.mcap`` draws it, one row per scan: its corrected pose, its floor's
    elevation and index (-1 between floors), its stamp and odometry pose; ``transform_at``:
    the scans whose map -> odom is written; ``estimated``: the scans whose poses the SLAM
    estimated (default all). The others are only drawn across a gap in the odometry, metres
    off, so the paths leave them out as ``trajectory.tum`` does."""

    poses: FloatArray
    z_m: FloatArray
    floor: IntArray
    t_ns: IntArray
    odom: FloatArray
    transform_at: IntArray
    estimated: BoolArray | None = None


def write_maps_mcap(path: Path, t_ns: int, floors: Sequence[FloorMap], run: MapsRun) -> None:
    """``t_ns``: when the maps and paths are stamped (the run's start, so a player shows them
    from the first instant on)."""
    context = foxglove.Context()
    writer = foxglove.open_mcap(str(path), allow_overwrite=True, context=context)
    try:
        _log_grids(context, t_ns, floors)
        _log_paths(context, t_ns, floors, run)
        _log_transforms(context, run)
    finally:
        writer.close()


def _pose(x: float, y: float, z: float, theta: float) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=yaw_quaternion(theta))


def grid_message(grid: OccupancyGrid, z_m: float, t_ns: int) -> Grid:
    """A floor's grid as a ``foxglove.Grid`` lifted to ``z_m``: occupancy percentages read
    as int8 (-1 unknown), the convention Foxglove's "map" colour mode expects."""
    h, w = grid.shape
    return Grid(
        timestamp=stamp(t_ns),
        frame_id=FRAME,
        pose=_pose(grid.origin_xy[0], grid.origin_xy[1], z_m, 0.0),
        column_count=w,
        cell_size=Vector2(x=grid.resolution, y=grid.resolution),
        row_stride=w,
        cell_stride=1,
        fields=[
            PackedElementField(name="occupancy", offset=0, type=PackedElementFieldNumericType.Int8)
        ],
        data=occupancy_int8(grid).tobytes() if h and w else b"",
    )


def _log_grids(context: foxglove.Context, t_ns: int, floors: Sequence[FloorMap]) -> None:
    """Each floor's grid on ``/map/floor_<k>``: channels are named by floor index, which
    skips a floor that has no map."""
    for floor in floors:
        channel = GridChannel(f"/map/floor_{floor.index}", context=context)
        channel.log(grid_message(floor.grid, float(floor.elevation_m), t_ns), log_time=t_ns)


def _log_paths(
    context: foxglove.Context, t_ns: int, floors: Sequence[FloorMap], run: MapsRun
) -> None:
    """The estimated poses, at most about 5000 of them, on ``/path`` at their heights and on
    ``/path/floor_<k>`` at their floor's."""
    poses = run.poses
    shown = np.arange(len(poses)) if run.estimated is None else np.flatnonzero(run.estimated)
    sel = shown[:: max(1, len(shown) // 5000)]
    PosesInFrameChannel("/path", context=context).log(
        PosesInFrame(
            timestamp=stamp(t_ns),
            frame_id=FRAME,
            poses=[_pose(poses[i, 0], poses[i, 1], float(run.z_m[i]), poses[i, 2]) for i in sel],
        ),
        log_time=t_ns,
    )
    for floor in floors:
        mine = sel[run.floor[sel] == floor.index]
        z = float(floor.elevation_m)
        PosesInFrameChannel(f"/path/floor_{floor.index}", context=context).log(
            PosesInFrame(
                timestamp=stamp(t_ns),
                frame_id=FRAME,
                poses=[_pose(poses[i, 0], poses[i, 1], z, poses[i, 2]) for i in mine],
            ),
            log_time=t_ns,
        )


def _log_transforms(context: foxglove.Context, run: MapsRun) -> None:
    """``map -> odom`` at each of ``run.transform_at``, lifted to the scan's elevation."""
    tf = FrameTransformChannel(topics.TF, context=context)
    at = run.transform_at
    correction = se2.compose(run.poses[at], se2.inverse(run.odom[at]))
    for k, (x, y, theta) in zip(at, correction, strict=True):
        t = int(run.t_ns[k])
        tf.log(
            FrameTransform(
                timestamp=stamp(t),
                parent_frame_id=topics.MAP_FRAME,
                child_frame_id=topics.ODOM_FRAME,
                translation=Vector3(x=float(x), y=float(y), z=float(run.z_m[k])),
                rotation=yaw_quaternion(float(theta)),
            ),
            log_time=t,
        )
