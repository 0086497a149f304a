"""Floor identity: which known floor is a settled pressure level, in spite of the weather?

Absolute pressure is useless for this over an hour: weather moves it by 1-3 hPa/h, i.e. one to
three storeys. Pressure *differences between floors* do not drift (they change by well under
one percent with temperature), so the registry keeps each floor's level relative to the first
floor seen, measured across transitions, which last seconds to a minute and see little drift.
Whoever uses it tracks the weather on the current floor and asks with a relative level.

A revisit is recognised when the level lands within one minimum transition height of a known
floor: two distinct floors are at least that far apart by definition, so the nearest known
floor inside that distance is the only candidate. Floors are kept under stable ids (order of
discovery); their public indices are ranked by height, 0 = lowest, and may shift when a lower
floor is found.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(slots=True)
class _Floor:
    relative_pa: float
    visits: int = 1


class FloorRegistry:
    """Known floors by id with levels relative to floor id 0 (Pa; higher pressure = lower)."""

    __slots__ = ("_floors",)

    def __init__(self) -> None:
        self._floors: list[_Floor] = []

    def __len__(self) -> int:
        return len(self._floors)

    def add(self, relative_pa: float) -> int:
        self._floors.append(_Floor(relative_pa))
        return len(self._floors) - 1

    def relative_pa(self, floor_id: int) -> float:
        return self._floors[floor_id].relative_pa

    def visits(self, floor_id: int) -> int:
        return self._floors[floor_id].visits

    def match(self, relative_pa: float, tolerance_pa: float, exclude: int | None) -> int | None:
        """The known floor nearest to ``relative_pa`` within ``tolerance_pa``, if any."""
        best: int | None = None
        best_distance = tolerance_pa
        for floor_id, floor in enumerate(self._floors):
            if floor_id == exclude:
                continue
            distance = abs(floor.relative_pa - relative_pa)
            if distance < best_distance:
                best, best_distance = floor_id, distance
        return best

    def revisit(self, floor_id: int) -> None:
        """Count a return to a known floor; its level stays as first measured.

        Averaging revisits in sounds better than it is: a walker's revisit may be decided on
        a stair landing a metre short of the floor, and one such value drags the level
        towards the next floor. One clean measurement across a short transition is good to
        a pascal or two, far inside the matching tolerance.
        """
        self._floors[floor_id].visits += 1

    def move(self, floor_id: int, delta_pa: float) -> None:
        """The first measurement of a floor was taken before the trip had ended: correct it."""
        self._floors[floor_id].relative_pa += delta_pa

    def index(self, floor_id: int) -> int:
        """Height rank of a floor: how many known floors are below it (higher pressure)."""
        level = self._floors[floor_id].relative_pa
        return sum(
            1
            for other_id, other in enumerate(self._floors)
            if other.relative_pa > level or (other.relative_pa == level and other_id < floor_id)
        )
