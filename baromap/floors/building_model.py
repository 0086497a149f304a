"""A known building: floor names by height, from an earlier run's ``building.yaml``.

The live detector can only measure heights relative to where a run started; names ("3",
"lobby") come from someone who knows the building. ``baromap build-maps`` writes
``building.yaml`` (:mod:`baromap.building`) with each floor's ``index`` (0 = lowest),
``elevation_m`` above the lowest and ``name`` (by order in height); a file written by hand
needs only the elevations, and a floor without a name is called by its index. Given which
of these floors a run starts on, every floor the robot reaches is named after the model
floor at its measured height.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path

from baromap.errors import ConfigError, InputFormatError

#: Floors a model may list: far above any building, small enough to check pairwise.
MAX_MODEL_FLOORS = 500


@dataclass(frozen=True, slots=True)
class ModelFloor:
    name: str
    elevation_m: float


@dataclass(frozen=True, slots=True)
class BuildingModel:
    """Floors of a known building by elevation (any common origin), names unique."""

    floors: tuple[ModelFloor, ...]

    def __post_init__(self) -> None:
        if not self.floors:
            raise ConfigError("building model: no floors")
        if len(self.floors) > MAX_MODEL_FLOORS:
            raise ConfigError(f"building model: more than {MAX_MODEL_FLOORS} floors")
        names = [f.name for f in self.floors]
        if len(set(names)) != len(names):
            raise ConfigError(f"building model: floor names are not unique: {names}")
        for f in self.floors:
            if not f.name or not math.isfinite(f.elevation_m):
                raise ConfigError(f"building model: floor {f.name!r} needs a name and a height")

    def elevation_of(self, name: str) -> float | None:
        for f in self.floors:
            if f.name == name:
                return f.elevation_m
        return None

    def closest_gap_m(self) -> float:
        """Smallest height difference between two model floors (inf for one floor)."""
        heights = sorted(f.elevation_m for f in self.floors)
        return min((b - a for a, b in itertools.pairwise(heights)), default=math.inf)


def load_building_model(path: str | Path) -> BuildingModel:
    """Read the floors of a ``building.yaml`` (:class:`baromap.building.Building`: each floor
    an ``elevation_m`` and a ``name``, else its ``index``, else its place in the list)."""
    from baromap.building import read_building  # the daemon reads a model only if configured

    building = read_building(path)
    floors = [
        ModelFloor(floor.label(k), float(floor.elevation_m))
        for k, floor in enumerate(building.floors)
    ]
    try:
        return BuildingModel(tuple(floors))
    except ConfigError as exc:
        raise InputFormatError(f"{path}: {exc}") from exc
