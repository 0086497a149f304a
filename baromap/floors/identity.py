"""Floor identity: which known floor is a settled pressure level, in spite of the weather?

Absolute pressure is useless for this over an hour: weather moves it by 1-3 hPa/h, i.e. one to
three storeys. Pressure *differences between floors* do not drift (they change by well under
one percent with temperature), so the registry keeps each floor's level relative to the start
floor, measured across transitions, which last seconds to a minute and see little drift.
Whoever uses it tracks the weather on the current floor and asks with a relative level.

A revisit is recognised when the level lands within one minimum transition height of a known
floor: two distinct floors are at least that far apart by definition, so the nearest known
floor inside that distance is the only candidate. Floors keep stable ids for the whole run
(the start floor is 0, then the order of first visits); a floor found to be another one is
*merged* into it and its id is never used again. :meth:`FloorRegistry.index` ranks the floors
by height (0 = lowest) for post-run outputs; that rank moves when a lower floor turns up, the
id never does.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(slots=True)
class _Floor:
    relative_pa: float
    height_m: float
    name: str
    #: The name was counted in storeys, not read from a building model.
    estimated: bool = False
    visits: int = 1
    merged_into: int | None = None


class FloorRegistry:
    """Known floors by stable id, with levels relative to the start floor (Pa; higher pressure
    = lower) and heights above it (m)."""

    __slots__ = ("_floors",)

    def __init__(self) -> None:
        self._floors: list[_Floor] = []

    def __len__(self) -> int:
        """Ids handed out so far (merged ones included)."""
        return len(self._floors)

    @property
    def known(self) -> int:
        """Distinct floors (merged ids not counted)."""
        return sum(1 for f in self._floors if f.merged_into is None)

    def ids(self) -> list[int]:
        """Ids of the distinct floors, in order of discovery."""
        return [i for i, f in enumerate(self._floors) if f.merged_into is None]

    def add(self, relative_pa: float, height_m: float, name: str, *, estimated: bool) -> int:
        self._floors.append(_Floor(relative_pa, height_m, name, estimated))
        return len(self._floors) - 1

    def relative_pa(self, floor_id: int) -> float:
        return self._floors[floor_id].relative_pa

    def height_m(self, floor_id: int) -> float:
        return self._floors[floor_id].height_m

    def name(self, floor_id: int) -> str:
        return self._floors[floor_id].name

    def estimated(self, floor_id: int) -> bool:
        return self._floors[floor_id].estimated

    def visits(self, floor_id: int) -> int:
        return self._floors[floor_id].visits

    def names(self, exclude: int | None = None) -> dict[str, float]:
        """Names in use (but ``exclude``'s), with their floors' heights above the start."""
        return {
            f.name: f.height_m
            for floor_id, f in enumerate(self._floors)
            if f.merged_into is None and floor_id != exclude
        }

    def resolve(self, floor_id: int) -> int:
        """The floor an id stands for now (itself, or the floor it was merged into)."""
        while (into := self._floors[floor_id].merged_into) is not None:
            floor_id = into
        return floor_id

    def match(self, relative_pa: float, tolerance_pa: float, exclude: int | None) -> int | None:
        """The known floor nearest to ``relative_pa`` within ``tolerance_pa``, if any."""
        best: int | None = None
        best_distance = tolerance_pa
        for floor_id, floor in enumerate(self._floors):
            if floor_id == exclude or floor.merged_into is not None:
                continue
            distance = abs(floor.relative_pa - relative_pa)
            if distance < best_distance:
                best, best_distance = floor_id, distance
        return best

    def revisit(self, floor_id: int) -> None:
        """Count a return to a known floor; its level stays as first measured.

        Averaging revisits in sounds better than it is: one level taken on a landing or with
        the car still sealed drags the floor towards its neighbour. One clean measurement
        across a short transition is good to a pascal or two, far inside the matching
        tolerance.
        """
        self._floors[floor_id].visits += 1

    def move(self, floor_id: int, relative_pa: float, height_m: float) -> None:
        """A floor's first measurement was taken before its trip had ended: correct it."""
        floor = self._floors[floor_id]
        floor.relative_pa = relative_pa
        floor.height_m = height_m

    def rename(self, floor_id: int, name: str, estimated: bool) -> None:
        """A floor first measured before its trip had ended gets the name of where it is."""
        floor = self._floors[floor_id]
        floor.name = name
        floor.estimated = estimated

    def merge(self, floor_id: int, into: int) -> None:
        """``floor_id`` was ``into`` all along: its visits go there, its id is retired."""
        floor = self._floors[floor_id]
        self._floors[into].visits += floor.visits
        floor.visits = 0
        floor.merged_into = into

    def index(self, floor_id: int) -> int:
        """Height rank of a floor among the distinct ones: how many are below it."""
        level = self._floors[floor_id].relative_pa
        return sum(
            1
            for other_id, other in enumerate(self._floors)
            if other.merged_into is None
            and (other.relative_pa > level or (other.relative_pa == level and other_id < floor_id))
        )
