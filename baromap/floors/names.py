"""Names for live floors: decided once, when a floor is first visited, and never changed.

With a building model the name is the model floor at the measured height (relative to the
start floor, placed on the model at the configured start floor), if one lies within half the
minimum transition height: model floors are at least that far apart, so at most one can
match. Otherwise the name is counted in storeys from the nearest floor already named, and is
an estimate (the events say so). A storey is the configured ``storey_m`` or the smallest
spacing between the floors seen so far, whichever is less (a building's usual storey shows
as soon as two neighbouring floors are known); a step up to ``ONE_STOREY_UP_TO`` storeys is
one storey, because the ground floor or lobby is commonly that much taller than the floors
above it, so consecutive floors get consecutive names. A numeric start name gives numbers
("5" -> "6", "4"); any other gives offsets ("G" -> "G+1", "G-2").
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping

from baromap.floors.building_model import BuildingModel

#: A step between two neighbouring floors up to this many storeys is one storey: ground
#: floors and lobbies are commonly 1.3-1.6 times as tall as the storeys above them, and a
#: step of two storeys (a floor passed) is twice one.
ONE_STOREY_UP_TO = 1.65


class FloorNamer:
    """Picks unique names for floors by their height above the start floor."""

    __slots__ = ("_base", "_model", "_numeric", "_start", "_storey_m", "_tolerance_m")

    def __init__(
        self,
        start_name: str,
        *,
        storey_m: float,
        tolerance_m: float,
        model: BuildingModel | None = None,
    ) -> None:
        self._start = start_name
        self._storey_m = storey_m
        self._tolerance_m = tolerance_m
        self._model = model
        base = model.elevation_of(start_name) if model is not None else None
        self._base = 0.0 if base is None else base
        try:
            self._numeric: int | None = int(start_name)
        except ValueError:
            self._numeric = None

    @property
    def start_name(self) -> str:
        return self._start

    def name(self, height_m: float, named: Mapping[str, float]) -> tuple[str, bool]:
        """A name for a new floor ``height_m`` above the start, unused by ``named``, and
        whether it is an estimate (counted, not read from the model).

        ``named`` maps the names already given to their floors' heights above the start.
        """
        if self._model is not None:
            best: str | None = None
            best_distance = self._tolerance_m
            for floor in self._model.floors:
                distance = abs(floor.elevation_m - self._base - height_m)
                if distance < best_distance and floor.name not in named:
                    best, best_distance = floor.name, distance
            if best is not None:
                return best, False
        if not named:
            return self._start, False
        return self._counted(height_m, named), True

    def storey_m(self, named: Mapping[str, float]) -> float:
        """The storey names are counted in: the configured one, or the smallest spacing
        between the floors seen if that is less."""
        heights = sorted(named.values())
        gaps = [b - a for a, b in itertools.pairwise(heights) if b - a >= 2 * self._tolerance_m]
        return min([self._storey_m, *gaps])

    def _counted(self, height_m: float, named: Mapping[str, float]) -> str:
        # Count storeys from the nearest floor with a counted name (else from the start).
        nearest, nearest_h = min(named.items(), key=lambda item: abs(item[1] - height_m))
        origin = self._offset(nearest)
        if origin is None:
            nearest_h, origin = 0.0, 0
        step = height_m - nearest_h
        direction = 1 if step > 0 else -1
        storeys = math.floor(abs(step) / self.storey_m(named) + 2.0 - ONE_STOREY_UP_TO)
        k = origin + direction * max(1, storeys)
        while self._label(k) in named or self._model_name_taken(self._label(k)):
            k += direction
        return self._label(k)

    def _model_name_taken(self, label: str) -> bool:
        return self._model is not None and self._model.elevation_of(label) is not None

    def _offset(self, name: str) -> int | None:
        """Storeys from the start floor a counted name stands for (None if not counted)."""
        if name == self._start:
            return 0
        if self._numeric is not None:
            try:
                return int(name) - self._numeric
            except ValueError:
                return None
        prefix = self._start
        if name.startswith(prefix) and name[len(prefix) :][:1] in ("+", "-"):
            try:
                return int(name[len(prefix) :])
            except ValueError:
                return None
        return None

    def _label(self, storeys: int) -> str:
        return counted_name(self._start, storeys)


def counted_name(start_name: str, storeys: int) -> str:
    """The name ``storeys`` above (below, negative) the floor named ``start_name``."""
    if storeys == 0:
        return start_name
    try:
        return str(int(start_name) + storeys)
    except ValueError:
        return f"{start_name}{storeys:+d}"


def names_by_height(count: int, start_index: int, start_name: str) -> list[str]:
    """Names of ``count`` floors in height order (index 0 the lowest) when the floor at
    ``start_index`` is ``start_name``: consecutive, as a person counts floors."""
    return [counted_name(start_name, index - start_index) for index in range(count)]
