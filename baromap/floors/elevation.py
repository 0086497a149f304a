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

from baromap.messages import NS_PER_S

#: How much floor time on each side of a transition the step fit uses (less where the visit
#: is shorter): long enough to average wind gusts (about 1.5 Pa RMS, correlated over tens of
#: seconds) and to pin down the drift slope. Measured on 8 simulated runs, the step error is
#: 0.18 m RMS with 30 s windows, 0.06 m with 120 s.
STEP_WINDOW_S = 120.0
#: Left out before the transition: elevator doors closing seal the car (a few pascals of
#: overpressure) several seconds before it moves, and the detector notices the departure only
#: once the pressure has moved. After it, the detector's end is the start of a quiet stretch,
#: but the last door and ventilation transients may still be fading.
STEP_GUARD_S = 8.0
STEP_GUARD_AFTER_S = 5.0
#: The temperature term is fitted only if the sensor's temperature moved at least this much.
MIN_TEMPERATURE_SPAN_C = 0.2
#: Fewer samples than this on a side and the step is taken from the detector's own estimate.
MIN_SIDE_SAMPLES = 5


@dataclass(frozen=True, slots=True)
class Step:
    """Pressure change across one transition between two floors (by any stable id), and the
    height it stands for (hypsometric, at the temperature measured around it)."""

    from_id: int
    to_id: int
    delta_pa: float  # after minus before: negative going up
    height_m: float


def measure_step(
    t_ns: npt.NDArray[np.int64],
    pressure_pa: npt.NDArray[np.float64],
    before: tuple[int, int],
    after: tuple[int, int],
    temperature_c: npt.NDArray[np.float64] | None = None,
) -> tuple[float, float] | None:
    """Levels ``(before, after)`` at the midpoint between the two windows, drift removed.

    ``before`` and ``after`` are ``(t_from_ns, t_to_ns)`` windows on the two floors. When the
    sensor's temperature is given and moves within the windows, a pressure-per-kelvin term is
    fitted too: a barometer's offset follows its own temperature (BMP280: up to 1.5 Pa/K), and
    on a floor of another temperature that offset creeps in over minutes. Returns None when a
    window holds too few samples.
    """
    i0, i1 = np.searchsorted(t_ns, before)
    j0, j1 = np.searchsorted(t_ns, after)
    if i1 - i0 < MIN_SIDE_SAMPLES or j1 - j0 < MIN_SIDE_SAMPLES:
        return None
    mid = (before[1] + after[0]) // 2
    tb = (t_ns[i0:i1] - mid) / NS_PER_S
    ta = (t_ns[j0:j1] - mid) / NS_PER_S
    columns = [
        np.concatenate((np.ones(tb.size), np.zeros(ta.size))),
        np.concatenate((np.zeros(tb.size), np.ones(ta.size))),
        np.concatenate((tb, ta)),
    ]
    if temperature_c is not None:
        temps = np.concatenate((temperature_c[i0:i1], temperature_c[j0:j1]))
        if np.all(np.isfinite(temps)) and np.ptp(temps) >= MIN_TEMPERATURE_SPAN_C:
            columns.append(temps - temps.mean())
    values = np.concatenate((pressure_pa[i0:i1], pressure_pa[j0:j1]))
    solution, *_ = np.linalg.lstsq(np.column_stack(columns), values, rcond=None)
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
    """Floors joined to floor 0 by a chain of steps (the others cannot be placed)."""
    ends = np.array([(step.from_id, step.to_id) for step in steps], dtype=np.int64).reshape(-1, 2)
    # scipy here, not at the top: the daemon imports the floors package for its online
    # detector, which never solves levels, and importing scipy cost it 0.2 s of CPU at start
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(len(ends)), (ends[:, 0], ends[:, 1])), shape=(n_floors, n_floors))
    _, labels = connected_components(graph, directed=False)
    reached: npt.NDArray[np.bool_] = labels == labels[0]
    return reached
