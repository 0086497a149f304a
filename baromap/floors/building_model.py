"""A known building: floor names by height, from an earlier run's ``building.yaml``.

The live detector can only measure heights relative to where a run started; names ("3",
"lobby") come from someone who knows the building. ``baromap build-maps`` writes
``building.yaml`` with each floor's ``index`` (0 = lowest) and ``elevation_m`` above the lowest;
an optional ``name`` per floor (written by hand, or by a later build) is used as the name, the
index otherwise. Given which of these floors a run starts on, every floor the robot reaches is
named after the model floor at its measured height.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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
    """Read the floors of a ``building.yaml`` (``floors: [{index, elevation_m[, name]}]``)."""
    import yaml  # here: the daemon imports this module, and reads a model only if configured

    try:
        document = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputFormatError(f"cannot read {path}: {exc}") from exc
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputFormatError(f"{path}: not YAML: {exc}") from exc
    entries = document.get("floors") if isinstance(document, dict) else None
    if not isinstance(entries, list) or not entries:
        raise InputFormatError(f"{path}: no 'floors' list (is it a baromap building.yaml?)")
    floors = []
    for k, entry in enumerate(entries):
        floors.append(_floor(path, k, entry))
    try:
        return BuildingModel(tuple(floors))
    except ConfigError as exc:
        raise InputFormatError(f"{path}: {exc}") from exc


def _floor(path: str | Path, k: int, entry: Any) -> ModelFloor:
    if not isinstance(entry, dict):
        raise InputFormatError(f"{path}: floor entry {k} is not a mapping")
    elevation = entry.get("elevation_m")
    if isinstance(elevation, bool) or not isinstance(elevation, int | float):
        raise InputFormatError(f"{path}: floor entry {k} has no numeric elevation_m")
    name = entry.get("name", entry.get("index", k))
    if isinstance(name, bool) or not isinstance(name, str | int):
        raise InputFormatError(f"{path}: floor entry {k} has a name that is not text")
    return ModelFloor(str(name), float(elevation))
