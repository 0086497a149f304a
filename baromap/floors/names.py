"""Names for live floors: decided once, when a floor is first visited, and never changed.

With a building model the name is the model floor at the measured height (relative to the
start floor, placed on the model at the configured start floor), if one lies within half the
minimum transition height: model floors are at least that far apart, so at most one can
match. Otherwise the name is counted in storeys from the nearest floor already named, with a
nominal storey height (``storey_m``): a guess that a tall lobby can put off by one, which is
why a building model is the way to get names right. A numeric start name gives numbers
("5" -> "6", "4"); any other gives offsets ("G" -> "G+1", "G-2").
"""

from __future__ import annotations

from collections.abc import Mapping

from baromap.floors.building_model import BuildingModel


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

    def name(self, height_m: float, named: Mapping[str, float]) -> str:
        """A name for a new floor ``height_m`` above the start, unused by ``named``.

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
                return best
        return self._counted(height_m, named)

    def _counted(self, height_m: float, named: Mapping[str, float]) -> str:
        if not named:
            return self._start
        # Count storeys from the nearest floor with a counted name (else from the start).
        nearest, nearest_h = min(named.items(), key=lambda item: abs(item[1] - height_m))
        origin = self._offset(nearest)
        if origin is None:
            nearest_h, origin = 0.0, 0
        step = height_m - nearest_h
        direction = 1 if step > 0 else -1
        k = origin + direction * max(1, round(abs(step) / self._storey_m))
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
        if storeys == 0:
            return self._start
        if self._numeric is not None:
            return str(self._numeric + storeys)
        return f"{self._start}{storeys:+d}"
