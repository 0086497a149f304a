"""``building.yaml``: the building model ``baromap build-maps`` writes, in one typed schema.

The writer (:mod:`baromap.mapping.build`) and every reader (the live detector's building
model, the ROS 2 and Open-RMF exports, the scoring of a build, the demo's summary) go through
:class:`Building`, so a key is spelled in one place and a file that does not fit is refused
with the path of what is wrong (``$.floors[2].elevation_m: expected float``) instead of a
``KeyError`` somewhere downstream.

Floors are listed by ``index``, their order in height (0 = the lowest floor the run
visited); ``name`` names them in that order (counted from the start floor's configured name,
so consecutive floors have consecutive names), and ``live_name`` is what the live detector
called the floor while the robot was there, when it differs. A file written by hand (a
building's plans, for the live detector's names) needs only ``floors`` with an
``elevation_m`` each; its ``name`` (or its ``index``, or its place in the list) names it.
"""

from __future__ import annotations

from pathlib import Path

import msgspec
import msgspec.yaml

from baromap.errors import InputFormatError


class BuildingFloor(msgspec.Struct, kw_only=True, omit_defaults=True, frozen=True):
    """One floor: its height above the lowest, how the run knew it, and its map files."""

    index: int | None = None
    name: str | int | None = None
    #: The live detector's name for the floor, when it differs from ``name``.
    live_name: str | None = None
    elevation_m: float
    mean_pressure_pa: float | None = None
    visits: int | None = None
    keyframes: int | None = None
    scans: int | None = None
    #: map_server files of the floor's grid (absent for a floor too short for a map).
    map: str | None = None
    image: str | None = None
    png: str | None = None

    def label(self, position: int) -> str:
        """The floor's name: ``name``, else ``index``, else its place in the list."""
        if self.name is not None:
            return str(self.name)
        return str(self.index if self.index is not None else position)


class BuildingRide(msgspec.Struct, frozen=True):
    """A change of floor as the segmentation dated it (recording clock, Unix ns)."""

    t_start_ns: int
    t_end_ns: int
    from_floor: int
    to_floor: int


class LoopClosures(msgspec.Struct, frozen=True):
    within_floors: int
    cross_floor: int
    elevator_car: int


class UntiedStretch(msgspec.Struct, frozen=True):
    """Consecutive keyframes of a part of the run that only odometry across a gap places."""

    part: int
    t_start_ns: int
    t_end_ns: int
    keyframes: int
    floors: list[int]
    #: The evidence of the gap that cut its part off (an odometry silence, a break, a drive
    #: with no scan); empty in files written before it was said.
    cut_by: str = ""


class Building(msgspec.Struct, kw_only=True, omit_defaults=True, frozen=True):
    """The whole of ``building.yaml``."""

    source: str | None = None
    parts: list[str] | None = None
    frame: str | None = None
    resolution_m: float | None = None
    segmentation: str | None = None
    floors: list[BuildingFloor]
    rides: list[BuildingRide] | None = None
    loop_closures: LoopClosures | None = None
    untied: list[UntiedStretch] | None = None
    keyframes: int | None = None
    scans: int | None = None

    def floor_maps(self) -> list[tuple[int, str, BuildingFloor]]:
        """``(index, map file, floor)`` of the floors that have a map (a build writes the
        index of every floor; one too short for a map has none)."""
        return [(f.index, f.map, f) for f in self.floors if f.map and f.index is not None]


def read_building(path: str | Path) -> Building:
    """The building model in ``path``; InputFormatError naming the file and what is wrong."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputFormatError(f"cannot read {path}: {exc}") from exc
    try:
        building = msgspec.yaml.decode(data, type=Building)
    except msgspec.ValidationError as exc:
        raise InputFormatError(f"{path}: not a baromap building.yaml: {exc}") from exc
    except (msgspec.DecodeError, UnicodeDecodeError) as exc:
        raise InputFormatError(f"{path}: not YAML: {exc}") from exc
    if not building.floors:
        raise InputFormatError(f"{path}: no floors")
    return building


def write_building(path: str | Path, building: Building) -> None:
    Path(path).write_bytes(msgspec.yaml.encode(building))
