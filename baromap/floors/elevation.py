"""Floor elevations that survive weather drift: least squares over the steps of transitions.

The mean pressure of a floor over an hour moves with the weather by several metres' worth, so
it cannot give a floor's height. The *step* across one transition can: it lasts seconds to a
minute. Each step is measured by fitting, around the transition, one level before, one level
after and a common drift slope shared by both sides (the weather does not care which floor the
robot is on), and evaluating the two levels at the transition's midpoint. Steps become heights
with the hypsometric equation at the measured temperature, and every floor's height follows
from all steps by least squares: revisits and loops average the errors out instead of
accumulating them along a chain.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from baromap.floors.height import height_difference_m
from baromap.messages import NS_PER_S

#: How much floor time on each side of a transition the step fit uses: long enough to average
#: gusts and estimate the drift slope, short next to the minutes over which the sensor's own
#: temperature offset (BMP280: 1.5 Pa/K) creeps in after arriving on a warmer or colder floor.
STEP_WINDOW_S = 30.0
#: Left out before the transition: elevator doors closing seal the car (a few pascals of
#: overpressure) several seconds before it moves, and the detector notices the departure only
#: once the pressure has moved. After it, the detector's end is the start of a quiet stretch,
#: but the last door and ventilation transients may still be fading.
STEP_GUARD_S = 8.0
STEP_GUARD_AFTER_S = 5.0
#: Fewer samples than this on a side and the step is taken from the detector's own estimate.
MIN_SIDE_SAMPLES = 5


@dataclass(frozen=True, slots=True)
class Step:
    """Pressure change across one transition between two floors (by any stable id)."""

    from_id: int
    to_id: int
    delta_pa: float
    height_m: float


def measure_step(
    t_ns: npt.NDArray[np.int64],
    pressure_pa: npt.NDArray[np.float64],
    before: tuple[int, int],
    after: tuple[int, int],
) -> tuple[float, float] | None:
    """Levels ``(before, after)`` at the midpoint between the two windows, drift removed.

    ``before`` and ``after`` are ``(t_from_ns, t_to_ns)`` windows on the two floors. Returns
    None when a window holds too few samples.
    """
    i0, i1 = np.searchsorted(t_ns, before)
    j0, j1 = np.searchsorted(t_ns, after)
    if i1 - i0 < MIN_SIDE_SAMPLES or j1 - j0 < MIN_SIDE_SAMPLES:
        return None
    mid = (before[1] + after[0]) // 2
    tb = (t_ns[i0:i1] - mid) / NS_PER_S
    ta = (t_ns[j0:j1] - mid) / NS_PER_S
    design = np.zeros((tb.size + ta.size, 3))
    design[: tb.size, 0] = 1.0
    design[tb.size :, 1] = 1.0
    design[:, 2] = np.concatenate((tb, ta))
    values = np.concatenate((pressure_pa[i0:i1], pressure_pa[j0:j1]))
    solution, *_ = np.linalg.lstsq(design, values, rcond=None)
    return float(solution[0]), float(solution[1])


def solve_levels(steps: Sequence[Step], n_floors: int, value: str) -> npt.NDArray[np.float64]:
    """Least-squares values (``"height_m"`` or ``"delta_pa"``) per floor id, floor 0 at 0.

    Floors that no step reaches stay at NaN (they cannot be placed).
    """
    result = np.full(n_floors, np.nan)
    if n_floors == 0:
        return result
    result[0] = 0.0
    if not steps:
        return result
    rows = np.zeros((len(steps) + 1, n_floors))
    rhs = np.zeros(len(steps) + 1)
    for k, step in enumerate(steps):
        rows[k, step.to_id] += 1.0
        rows[k, step.from_id] -= 1.0
        rhs[k] = getattr(step, value)
    rows[-1, 0] = 1.0  # gauge: floor id 0 at zero
    solution, *_ = np.linalg.lstsq(rows, rhs, rcond=None)
    reached = _reachable(steps, n_floors)
    result[reached] = solution[reached]
    return result


def _reachable(steps: Sequence[Step], n_floors: int) -> npt.NDArray[np.bool_]:
    seen = np.zeros(n_floors, dtype=bool)
    seen[0] = True
    changed = True
    while changed:
        changed = False
        for step in steps:
            if seen[step.from_id] != seen[step.to_id]:
                seen[step.from_id] = seen[step.to_id] = True
                changed = True
    return seen


def step_height_m(level_before: float, level_after: float, temperature_c: float) -> float:
    return height_difference_m(level_before, level_after, temperature_c)
