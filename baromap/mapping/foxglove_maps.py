"""``maps.mcap``: the finished maps and path in Foxglove's standard schemas.

Each floor is a ``foxglove.Grid`` on ``/map/floor_<k>`` whose pose lifts it to the floor's
elevation, so Foxglove's 3D panel shows the building stacked as in ``building.png``; the
corrected path is a ``PosesInFrame`` on ``/path`` (all floors, z = floor elevation) and one per
floor on ``/path/floor_<k>``. Cell values are occupancy percentages (0-100, 255 unknown), the
convention of ROS ``OccupancyGrid`` that Foxglove's "map" colour mode expects when the field is
read as int8 (-1 unknown).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from baromap.mapping.occupancy import OccupancyGrid

FloatArray = npt.NDArray[np.float64]
FRAME = "map"


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
) -> None:
    import foxglove
    from foxglove.channels import GridChannel, PosesInFrameChannel
    from foxglove.messages import (
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

    def pose(x: float, y: float, z: float, theta: float) -> Pose:
        return Pose(
            position=Vector3(x=x, y=y, z=z),
            orientation=Quaternion(x=0.0, y=0.0, z=math.sin(theta / 2), w=math.cos(theta / 2)),
        )

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
        every = max(1, len(scan_poses) // 5000)
        sel = np.arange(0, len(scan_poses), every)
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
    finally:
        writer.close()
