"""A build-maps output directory, read back from its files and scored against the true plans.

:func:`baromap.evaluation.mapping.evaluate_sim` scores the mapper's objects in memory; this
scores what a user receives: each ``floor_<k>.pgm`` as map_server would read it (its YAML's
origin, resolution and thresholds), placed in the building by the poses of
``trajectory.tum``. That checks the files themselves (the image is not flipped, the origin is
where the YAML says, the trajectory and the maps share one frame), not only the numbers
behind them.

A floor map is matched to the true floor its scans were taken on (majority of its poses) and
aligned to the building by the rigid transform that best takes its poses onto the true ones;
a second score uses one transform for the whole building, so floors turned against each
other show. Measures: occupied precision (occupied cells within 10 cm of a true wall face, as
in :mod:`baromap.evaluation.mapping`), free precision (free cells that lie in the plan's free
space: a map that sees through walls or smears a room fails it), and the mean pose error at
the elevator lobby under the building-wide transform (how well the floors line up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy import ndimage

from baromap.arrays import BoolArray, FloatArray, IntArray
from baromap.building import read_building
from baromap.errors import InputFormatError
from baromap.evaluation.mapping import LOBBY_RADIUS_M, WALL_TOLERANCE_M
from baromap.evaluation.trajectory import fit_rigid, mean_pose_error
from baromap.mapping import se2
from baromap.mapping.export import read_pgm, read_tum
from baromap.sim.building import Building, FloorPlan

#: A trajectory pose belongs to a floor when its z is that floor's elevation (the TUM file
#: rounds to 0.1 mm, building.yaml to 1 mm); poses in a ride lie in between.
SAME_ELEVATION_M = 0.002
#: Cell size of the plan rasters the maps are compared with.
PLAN_RESOLUTION_M = 0.05


@dataclass(frozen=True, slots=True, eq=False)
class MapFile:
    """One floor map as map_server reads it: row 0 is the lowest y."""

    index: int
    elevation_m: float
    occupied: BoolArray
    free: BoolArray
    origin_xy: tuple[float, float]
    resolution: float

    def cell_centres(self, mask: BoolArray) -> FloatArray:
        rows, cols = np.nonzero(mask)
        out: FloatArray = np.column_stack(
            [
                self.origin_xy[0] + (cols + 0.5) * self.resolution,
                self.origin_xy[1] + (rows + 0.5) * self.resolution,
            ]
        )
        return out


@dataclass(frozen=True, slots=True, eq=False)
class Trajectory:
    t_ns: IntArray
    xyt: FloatArray
    z_m: FloatArray


@dataclass(frozen=True, slots=True)
class MapFileScore:
    floor: int  # index in building.yaml
    true_floor: int
    poses: int
    occupied_precision: float  # own alignment
    free_precision: float
    building_occupied_precision: float  # one transform for the whole building
    building_free_precision: float
    lobby_error_m: float
    lobby_error_deg: float


def read_map(yaml_path: Path, index: int, elevation_m: float) -> MapFile:
    """A map_server map (trinary PGM and its YAML)."""
    try:
        meta: dict[str, Any] = yaml.safe_load(yaml_path.read_text(encoding="utf-8"))
        image = read_pgm(yaml_path.parent / str(meta["image"]))
        resolution = float(meta["resolution"])
        origin = (float(meta["origin"][0]), float(meta["origin"][1]))
        occupied_thresh = float(meta["occupied_thresh"])
        free_thresh = float(meta["free_thresh"])
        negate = bool(meta.get("negate", 0))
    except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError) as exc:
        raise InputFormatError(f"{yaml_path}: not a readable map_server map: {exc}") from exc
    # map_server: p = (255 - v) / 255 (or v / 255 negated); image row 0 is the top (highest y)
    value = image[::-1].astype(np.float64)
    p = value / 255.0 if negate else (255.0 - value) / 255.0
    return MapFile(index, elevation_m, p > occupied_thresh, p < free_thresh, origin, resolution)


def read_trajectory(path: Path) -> Trajectory:
    """A TUM trajectory (time x y z qx qy qz qw) of planar poses."""
    t, xyz, quaternion = read_tum(path)
    theta = 2.0 * np.arctan2(quaternion[:, 2], quaternion[:, 3])
    return Trajectory(t, np.column_stack([xyz[:, 0], xyz[:, 1], theta]), xyz[:, 2])


def read_outputs(out_dir: Path) -> tuple[list[MapFile], Trajectory]:
    """The floor maps named in ``building.yaml`` and the trajectory of a build-maps directory."""
    building = read_building(out_dir / "building.yaml")
    maps = [
        read_map(out_dir / map_file, index, floor.elevation_m)
        for index, map_file, floor in building.floor_maps()
    ]
    return maps, read_trajectory(out_dir / "trajectory.tum")


def _occupied_precision(
    xy: FloatArray, wall_distance: FloatArray, resolution: float = PLAN_RESOLUTION_M
) -> float:
    if not len(xy):
        return 0.0
    cols = np.floor(xy[:, 0] / resolution).astype(np.int64)
    rows = np.floor(xy[:, 1] / resolution).astype(np.int64)
    h, w = wall_distance.shape
    inside = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
    near = np.zeros(len(xy), dtype=bool)
    near[inside] = wall_distance[rows[inside], cols[inside]] <= WALL_TOLERANCE_M
    return float(near.mean())


def _free_precision(xy: FloatArray, plan: FloorPlan) -> float:
    return float(plan.is_free(xy).mean()) if len(xy) else 0.0


def score_outputs(
    out_dir: str | Path,
    building: Building,
    truth_t_ns: IntArray,
    truth_xyt: FloatArray,
    truth_floor: IntArray,
) -> list[MapFileScore]:
    """Score every floor map of ``out_dir`` against the building's true plans.

    The truth is a series on the recording's clock: poses (building frame) and the floor
    (-1 while riding), e.g. :class:`baromap.evaluation.twin_truth.TruthSeries`.
    """
    from baromap.mapping.run_data import interpolate_poses

    maps, trajectory = read_outputs(Path(out_dir))
    true_xyt = interpolate_poses(truth_t_ns, truth_xyt, trajectory.t_ns)
    idx = np.clip(np.searchsorted(truth_t_ns, trajectory.t_ns), 0, len(truth_t_ns) - 1)
    true_floor = truth_floor[idx]
    members = {
        m.index: (np.abs(trajectory.z_m - m.elevation_m) < SAME_ELEVATION_M) & (true_floor >= 0)
        for m in maps
    }
    on_any = np.logical_or.reduce(list(members.values())) if members else np.zeros(0, bool)
    if not on_any.any():
        raise InputFormatError(f"{out_dir}: no trajectory pose lies on a mapped floor")
    building_fit = fit_rigid(trajectory.xyt[on_any, :2], true_xyt[on_any, :2])
    aligned = se2.compose(building_fit[None, :], trajectory.xyt)
    lobby = np.hypot(
        true_xyt[:, 0] - building.lobby_xy[0], true_xyt[:, 1] - building.lobby_xy[1]
    ) < (LOBBY_RADIUS_M)
    scores = []
    for m in maps:
        mine = members[m.index]
        if not mine.any():
            continue
        values, counts = np.unique(true_floor[mine], return_counts=True)
        plan = building.floors[int(values[np.argmax(counts)])]
        walls = plan.occupancy_truth(PLAN_RESOLUTION_M)
        wall_distance = ndimage.distance_transform_edt(~walls) * PLAN_RESOLUTION_M
        own_fit = fit_rigid(trajectory.xyt[mine, :2], true_xyt[mine, :2])
        occupied = m.cell_centres(m.occupied)
        free = m.cell_centres(m.free)
        at_lobby = mine & lobby
        lobby_m, lobby_deg = (
            mean_pose_error(aligned[at_lobby], true_xyt[at_lobby])
            if at_lobby.any()
            else (math.nan, math.nan)
        )
        scores.append(
            MapFileScore(
                floor=m.index,
                true_floor=plan.index,
                poses=int(mine.sum()),
                occupied_precision=_occupied_precision(
                    se2.transform_points(own_fit, occupied), wall_distance
                ),
                free_precision=_free_precision(se2.transform_points(own_fit, free), plan),
                building_occupied_precision=_occupied_precision(
                    se2.transform_points(building_fit, occupied), wall_distance
                ),
                building_free_precision=_free_precision(
                    se2.transform_points(building_fit, free), plan
                ),
                lobby_error_m=lobby_m,
                lobby_error_deg=lobby_deg,
            )
        )
    return scores
