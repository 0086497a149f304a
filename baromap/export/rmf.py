"""``baromap export rmf``: build-maps' building as an Open-RMF building map.

The output is the ``.building.yaml`` that traffic-editor edits and rmf_building_map_tools'
``Building`` loads (``coordinate_system: reference_image``): every position on a level is in
the pixels of that level's drawing, x right and y down, and the loader turns pixels into metres
with the reference level's measurements and aligns the other levels to it with the fiducials
they share.

- One level per floor, named ``floor_<k>``, ``elevation`` from the barometer (building.yaml).
- Drawing: the floor's map image, written pixel for pixel from the map_server PGM as
  ``<site>_floor_<k>.png`` beside the site file (build-maps' ``floor_<k>.png`` is a plot with
  axes and margins, so it has no exact scale); a measurement between two vertices states its
  scale (the map's resolution).
- Fiducials: all floors share one map frame, so the same three world points (corners of the
  union of all maps) are named on every level, each at its own pixels; the loader's fiducial
  fit then reproduces that frame.
- A lift where the robot rode: ``trajectory.tum`` carries every scan's pose with z at its
  floor's elevation and z between two floors while riding; the cabin is centred on the median
  of the ride positions, sized by their spread, with one door on the side the robot entered
  and left by, serving every floor a ride started or ended on. Its yaw is 0 (the map frame):
  nothing in the outputs says how the shaft is turned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import structlog
import yaml

from baromap.arrays import FloatArray
from baromap.building import Building, read_building
from baromap.errors import InputFormatError
from baromap.export.map_yaml import read_yaml_mapping
from baromap.mapping.export import read_pgm, read_tum

log = structlog.get_logger(__name__)


#: traffic-editor's parameter type code for a double.
PARAM_DOUBLE = 3
#: A pose is riding when its z is this far from every floor's elevation.
RIDE_Z_TOLERANCE_M = 0.02
#: Cabin size bounds: a person-sized lift up to a goods lift.
MIN_CABIN_M = 1.2
MAX_CABIN_M = 4.0
#: Margin around the robot's ride positions: a P3-AT is about 0.6 x 0.5 m, plus clearance.
CABIN_MARGIN_M = 0.9
#: Ride positions further than this from the median are another shaft or a bad pose.
SAME_SHAFT_M = 3.0
DOOR_WIDTH_M = 1.0


@dataclass(frozen=True, slots=True)
class MapLevel:
    index: int
    name: str
    elevation_m: float
    resolution: float
    origin_xy: tuple[float, float]
    image: npt.NDArray[np.uint8]

    @property
    def height_px(self) -> int:
        return int(self.image.shape[0])

    def to_pixels(self, x: float, y: float) -> tuple[float, float]:
        """World metres to drawing pixels (x right, y down, from the top-left corner)."""
        col = (x - self.origin_xy[0]) / self.resolution
        row = self.height_px - (y - self.origin_xy[1]) / self.resolution
        return col, row

    def extent(self) -> tuple[float, float, float, float]:
        h, w = self.image.shape
        ox, oy = self.origin_xy
        return ox, oy, ox + w * self.resolution, oy + h * self.resolution


@dataclass(frozen=True, slots=True)
class Lift:
    x_m: float
    y_m: float
    width_m: float
    depth_m: float
    door_side: str  # "+x", "-x", "+y", "-y"
    floors: list[int]
    rides: int


@dataclass(frozen=True, slots=True)
class RmfSite:
    path: Path
    levels: list[str]
    lift: str | None
    notes: list[str] = field(default_factory=list)


def export_rmf(
    building_yaml: str | Path, out_path: str | Path, *, name: str | None = None
) -> RmfSite:
    """Write an Open-RMF building map for a build-maps output directory."""
    building_yaml = Path(building_yaml)
    out = Path(out_path)
    directory = building_yaml.parent
    levels = _levels(directory, read_building(building_yaml))
    stem = out.name.removesuffix(".yaml").removesuffix(".building")
    site_name = name or stem
    notes: list[str] = []
    lift = _find_lift(directory / "trajectory.tum", levels, notes)
    out.parent.mkdir(parents=True, exist_ok=True)
    fiducials = _fiducial_points(levels)
    site_levels: dict[str, Any] = {}
    for level in levels:
        drawing = out.parent / f"{stem}_floor_{level.index}.png"
        _write_drawing(drawing, level.image)
        site_levels[level.name] = _level_yaml(level, drawing.name, fiducials)
    reference = levels[0]
    site: dict[str, Any] = {
        "name": site_name,
        "coordinate_system": "reference_image",
        "reference_level_name": reference.name,
        "levels": site_levels,
        "lifts": {},
    }
    lift_name = None
    if lift is not None:
        lift_name = "lift_1"
        site["lifts"][lift_name] = _lift_yaml(lift, reference, levels)
    out.write_text(
        "# Open-RMF building map written by baromap export rmf\n"
        + yaml.safe_dump(site, sort_keys=False, default_flow_style=None),
        encoding="utf-8",
    )
    log.info("rmf building written", path=str(out), levels=len(levels), lift=lift_name)
    return RmfSite(out, [lvl.name for lvl in levels], lift_name, notes)


def _levels(directory: Path, building: Building) -> list[MapLevel]:
    levels = []
    for index, map_file, floor in building.floor_maps():
        meta = read_yaml_mapping(directory / map_file)
        elevation = floor.elevation_m
        try:
            resolution = float(meta["resolution"])
            ox, oy = float(meta["origin"][0]), float(meta["origin"][1])
            yaw = float(meta["origin"][2]) if len(meta["origin"]) > 2 else 0.0
            image_name = str(meta["image"])
        except (KeyError, IndexError, TypeError, ValueError) as exc:
            raise InputFormatError(f"{directory}: map of floor {index}: {exc}") from exc
        if yaw != 0.0 or not resolution > 0:
            raise InputFormatError(f"{directory}: map of floor {index} is rotated or unscaled")
        levels.append(
            MapLevel(
                index,
                f"floor_{index}",
                elevation,
                resolution,
                (ox, oy),
                read_pgm(directory / image_name),
            )
        )
    if not levels:
        raise InputFormatError(f"{directory}/building.yaml lists no floor maps")
    return sorted(levels, key=lambda lvl: lvl.elevation_m)


def _fiducial_points(levels: list[MapLevel]) -> list[tuple[str, float, float]]:
    """Three world points every level names: corners of the union of the maps."""
    extents = np.array([lvl.extent() for lvl in levels])
    x0, y0 = float(extents[:, 0].min()), float(extents[:, 1].min())
    x1, y1 = float(extents[:, 2].max()), float(extents[:, 3].max())
    return [("fiducial_sw", x0, y0), ("fiducial_se", x1, y0), ("fiducial_nw", x0, y1)]


def _px(value: float) -> float:
    return round(value, 3)


def _level_yaml(
    level: MapLevel, drawing: str, fiducials: list[tuple[str, float, float]]
) -> dict[str, Any]:
    points = [(name, *level.to_pixels(x, y)) for name, x, y in fiducials]
    (_, ax, ay), (_, bx, by) = points[0], points[1]
    distance_m = math.hypot(bx - ax, by - ay) * level.resolution
    return {
        "drawing": {"filename": drawing},
        "elevation": round(level.elevation_m, 3),
        "fiducials": [[_px(c), _px(r), name] for name, c, r in points],
        "vertices": [
            [_px(ax), _px(ay), 0.0, "scale_a", {}],
            [_px(bx), _px(by), 0.0, "scale_b", {}],
        ],
        "measurements": [[0, 1, {"distance": [PARAM_DOUBLE, round(distance_m, 4)]}]],
        "lanes": [],
        "walls": [],
        "doors": [],
        "models": [],
        "floors": [],
        "layers": {},
    }


def _write_drawing(path: Path, image: npt.NDArray[np.uint8]) -> None:
    from matplotlib import image as mpimg

    mpimg.imsave(path, image, cmap="gray", vmin=0, vmax=255)


def ride_segments(z: FloatArray, elevations: FloatArray) -> list[tuple[int, int]]:
    """[start, end) index ranges of poses whose z is at no floor's elevation."""
    if len(z) == 0 or len(elevations) == 0:
        return []
    off = np.min(np.abs(z[:, None] - elevations[None, :]), axis=1) > RIDE_Z_TOLERANCE_M
    edges = np.diff(np.concatenate([[0], off.astype(np.int8), [0]]))
    starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
    return [(int(s), int(e)) for s, e in zip(starts, ends, strict=True)]


def _find_lift(tum: Path, levels: list[MapLevel], notes: list[str]) -> Lift | None:
    if not tum.exists():
        notes.append(f"no {tum.name}: no lift")
        return None
    _, xyz, _ = read_tum(tum)
    elevations = np.array([lvl.elevation_m for lvl in levels])
    rides = [(s, e) for s, e in ride_segments(xyz[:, 2], elevations) if s > 0 and e < len(xyz)]
    if not rides:
        notes.append("the trajectory shows no ride between floors: no lift")
        return None
    centres = np.array([xyz[s:e, :2].mean(axis=0) for s, e in rides])
    centre = np.median(centres, axis=0)
    near = np.linalg.norm(centres - centre, axis=1) <= SAME_SHAFT_M
    if not near.all():
        notes.append(f"{int((~near).sum())} ride(s) far from the others left out of the lift")
    rides = [r for r, keep in zip(rides, near, strict=True) if keep]
    inside = np.concatenate([xyz[s:e, :2] for s, e in rides])
    spread = np.abs(inside - centre).max(axis=0) * 2
    width, depth = (float(np.clip(v + CABIN_MARGIN_M, MIN_CABIN_M, MAX_CABIN_M)) for v in spread)
    # the door: where the robot was just before and just after each ride
    outside = np.array([xyz[s - 1, :2] for s, _ in rides] + [xyz[e, :2] for _, e in rides])
    direction = (outside - centre).mean(axis=0)
    if abs(direction[0]) >= abs(direction[1]):
        side = "+x" if direction[0] >= 0 else "-x"
    else:
        side = "+y" if direction[1] >= 0 else "-y"
    floors = set()
    for s, e in rides:
        for z in (xyz[s - 1, 2], xyz[e, 2]):
            floors.add(levels[int(np.argmin(np.abs(elevations - z)))].index)
    return Lift(float(centre[0]), float(centre[1]), width, depth, side, sorted(floors), len(rides))


def _lift_yaml(lift: Lift, reference: MapLevel, levels: list[MapLevel]) -> dict[str, Any]:
    col, row = reference.to_pixels(lift.x_m, lift.y_m)
    door_width = min(DOOR_WIDTH_M, (lift.depth_m if lift.door_side[1] == "x" else lift.width_m))
    axis, sign = lift.door_side[1], 1.0 if lift.door_side[0] == "+" else -1.0
    door = {
        "door_type": "double_sliding",
        "x": round(sign * lift.width_m / 2, 3) if axis == "x" else 0.0,
        "y": round(sign * lift.depth_m / 2, 3) if axis == "y" else 0.0,
        "motion_axis_orientation": round(math.pi / 2, 6) if axis == "x" else 0.0,
        "width": round(door_width, 3),
    }
    names = {lvl.index: lvl.name for lvl in levels}
    served = [names[k] for k in lift.floors if k in names]
    height = {lvl.name: lvl.elevation_m for lvl in levels}
    by_height = sorted(served, key=height.__getitem__)
    return {
        "x": _px(col),
        "y": _px(row),
        "yaw": 0.0,
        "width": round(lift.width_m, 3),
        "depth": round(lift.depth_m, 3),
        "reference_floor_name": reference.name,
        "initial_floor_name": by_height[0] if by_height else reference.name,
        "lowest_floor": by_height[0] if by_height else reference.name,
        "highest_floor": by_height[-1] if by_height else reference.name,
        "plugins": True,
        "doors": {"door1": door},
        "level_doors": {name: ["door1"] for name in by_height},
    }
