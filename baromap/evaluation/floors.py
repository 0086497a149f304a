"""The side-by-side evaluation report: both methods over the real IPIN logs and simulated runs.

Each case is a pressure series with its truth; each method is scored on it
(:mod:`baromap.floors.evaluation`) and one line per case and method is printed, then totals
over the simulated seeds.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from baromap.errors import ConfigError
from baromap.floors.config import FloorDetectorConfig
from baromap.floors.detection import FloorDetection, detect_floors
from baromap.floors.evaluation import (
    FloorTruth,
    Score,
    score,
    truth_from_series,
    with_settle_times,
)

if TYPE_CHECKING:
    from baromap.sim.scenario import Scenario

Print = Callable[[str], None]


@dataclass(frozen=True, slots=True, eq=False)
class Case:
    name: str
    kind: str  # "real" or "sim"
    t_ns: npt.NDArray[np.int64]
    pressure_pa: npt.NDArray[np.float64]
    temperature_c: npt.NDArray[np.float64] | None
    truth: FloorTruth
    reference: tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]] | None = None
    #: ``(t_ns, x_m, y_m)`` of the robot's odometry, when the case has any.
    odometry: (
        tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64]] | None
    ) = None


def real_cases(directory: str | Path) -> list[Case]:
    """Every IPIN log with waypoints in ``directory``; none at all is an error, not a pass."""
    from baromap.floors.inputs import load_input

    folder = Path(directory)
    if not folder.is_dir():
        raise ConfigError(f"{folder} is not a directory of IPIN logs")
    cases = []
    for path in sorted(folder.glob("*.txt")):
        data = load_input(path)
        if data.truth is None:
            continue
        cases.append(
            Case(path.stem, "real", data.series.t_ns, data.series.pressure_pa, None, data.truth)
        )
    if not cases:
        raise ConfigError(f"{folder} holds no IPIN log (*.txt) with POSI waypoints")
    return cases


def sim_case(
    seed: int,
    *,
    drift_hpa_per_h: float = 1.5,
    minutes: float = 46.0,
    use_reference: bool = False,
) -> Case:
    from baromap.sim.scenario import make_scenario, pressure_run

    run = pressure_run(seed, minutes=minutes, drift_hpa_per_h=drift_hpa_per_h)
    scenario = make_scenario(seed, minutes=minutes, drift_hpa_per_h=drift_hpa_per_h)
    floor = np.where(np.asarray(run.truth_floor) < 0, np.nan, np.asarray(run.truth_floor))
    truth = truth_from_series(run.t_ns, floor)
    truth = FloorTruth(
        truth.transitions,
        truth.t_ns,
        truth.floor,
        {k: float(z) for k, z in enumerate(np.asarray(run.elevations_m))},
    )
    # Weather and gusts reach the reference station too: the difference of the noise-free
    # pressures is the robot's own. (The station's *reading* would bring its sensor's noise
    # and filter lag, up to 1 Pa, into the 1.2 Pa settling band and date settles late.)
    own = np.asarray(run.true_pressure_pa) - scenario.reference_true_pa(run.t_s)
    truth = with_settle_times(truth, np.asarray(run.t_ns), own)
    reference = (run.t_ns, np.asarray(run.reference_pa)) if use_reference else None
    return Case(
        f"sim seed {seed}",
        "sim",
        np.asarray(run.t_ns),
        np.asarray(run.pressure_pa),
        np.asarray(run.temperature_c),
        truth,
        reference,
        sim_odometry(scenario),
    )


def sim_odometry(
    scenario: Scenario,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The odometry a simulated run's robot reports: its true motion through the robot's own
    error model, one pose per SIP (what ``sim record`` writes on /odom, before the wire)."""
    from baromap.sim.odometry import (
        SIP_PERIOD_S,
        OdometryErrors,
        OdometryModel,
        true_increments,
    )
    from baromap.sim.scenario import STREAM_ODOMETRY

    t = np.arange(SIP_PERIOD_S / 2, scenario.duration_s, SIP_PERIOD_S)
    truth = scenario.truth(t)
    rng = scenario.rng(STREAM_ODOMETRY)
    model = OdometryModel(OdometryErrors.random(rng), rng)
    start = scenario.moves.start[0]
    ds, dth = true_increments(
        truth.x, truth.y, truth.theta, (float(start[0]), float(start[1]), float(start[2]))
    )
    x, y, _ = model.step(ds, dth)
    return scenario.t_ns(t), x, y


def evaluate(
    case: Case, method: str, config: FloorDetectorConfig | None = None
) -> tuple[FloorDetection, Score]:
    detection = detect_floors(
        case.t_ns,
        case.pressure_pa,
        case.temperature_c,
        method=method,
        reference=case.reference,
        config=config,
        odometry=case.odometry,
    )
    return detection, score(detection, case.truth)


HEADER = (
    f"{'case':34s} {'method':6s} {'true':>4s} {'found':>5s} {'miss':>4s} {'false':>5s} "
    f"{'dir':>4s} {'stor':>4s} {'acc%':>6s} {'delay med/max s':>16s} {'height err m':>12s}"
)


def line(name: str, method: str, s: Score) -> str:
    delay = f"{s.median_delay_s:6.1f}/{s.max_delay_s:6.1f}" if s.delays_s else f"{'-':>13s}"
    height = f"{s.height_error_m:12.2f}" if s.height_error_m is not None else f"{'-':>12s}"
    accuracy = f"{100 * s.accuracy:6.1f}" if np.isfinite(s.accuracy) else f"{'-':>6s}"
    flushed = " (last at end of log)" if s.flushed else ""
    return (
        f"{name:34s} {method:6s} {s.true:4d} {s.found:5d} {s.missed:4d} {s.false:5d} "
        f"{s.direction_right:4d} {s.storeys_right:4d} {accuracy} {delay:>16s} {height}{flushed}"
    )


@dataclass
class Totals:
    true: int = 0
    found: int = 0
    false: int = 0
    direction: int = 0
    storeys: int = 0
    cases: int = 0
    accuracy_sum: float = 0.0
    height_max: float = 0.0
    heights: int = 0

    def __post_init__(self) -> None:
        self.delays: list[float] = []
        self.settled_delays: list[float] = []

    def add(self, s: Score) -> None:
        self.true += s.true
        self.found += s.found
        self.false += s.false
        self.direction += s.direction_right
        self.storeys += s.storeys_right
        self.cases += 1
        self.accuracy_sum += s.accuracy if np.isfinite(s.accuracy) else 0.0
        self.delays.extend(s.delays_s)
        self.settled_delays.extend(s.settled_delays_s)
        if s.height_error_m is not None:
            self.heights += 1
            self.height_max = max(self.height_max, s.height_error_m)

    def summary(self, method: str) -> str:
        recall = self.found / self.true if self.true else 1.0
        detected = self.found + self.false
        precision = self.found / detected if detected else 1.0
        median = float(np.median(self.delays)) if self.delays else float("nan")
        settled = float(np.median(self.settled_delays)) if self.settled_delays else float("nan")
        return (
            f"  {method:6s} recall {100 * recall:5.1f} %  precision {100 * precision:5.1f} %  "
            f"({self.found}/{self.true} found, {self.false} false)  direction right "
            f"{self.direction}/{self.found}  storeys right {self.storeys}/{self.found}  "
            f"mean accuracy {100 * self.accuracy_sum / max(self.cases, 1):5.1f} %  "
            f"median delay {median:4.1f} s after the car stops, {settled:4.1f} s after the "
            f"pressure settles  worst height error {self.height_max:.2f} m"
        )


def run_report(
    real_dir: str | Path | None,
    seeds: Sequence[int],
    methods: Sequence[str] = ("online", "paper"),
    *,
    drift_hpa_per_h: float = 1.5,
    minutes: float = 46.0,
    use_reference: bool = False,
    config: FloorDetectorConfig | None = None,
    out: Print = print,
    progress: bool = False,
) -> dict[str, Totals]:
    """Print the report; returns the simulated totals per method."""
    cases = real_cases(real_dir) if real_dir is not None else []
    out(HEADER)
    for real in cases:
        for method in methods:
            out(line(real.name[-34:], method, evaluate(real, method, config)[1]))
    totals = {method: Totals() for method in methods}
    iterator: Iterable[int] = seeds
    if progress:
        from tqdm import tqdm

        iterator = tqdm(seeds, desc="simulated runs", unit="run", leave=False)
    for seed in iterator:
        case = sim_case(
            seed, drift_hpa_per_h=drift_hpa_per_h, minutes=minutes, use_reference=use_reference
        )
        for method in methods:
            s = evaluate(case, method, config)[1]
            totals[method].add(s)
            out(line(case.name, method, s))
    if seeds:
        out(
            f"simulated: {len(seeds)} seeds x {minutes:g} min, drift {drift_hpa_per_h:g} hPa/h"
            + (", reference station used" if use_reference else ", no reference station")
        )
        for method in methods:
            out(totals[method].summary(method))
    return totals


#: Settings varied by :func:`real_sweep`, around the defaults, by physically sensible amounts.
SWEEP_GRID: dict[str, tuple[float, ...]] = {
    "min_transition_m": (1.6, 1.8, 1.9, 2.0),
    "settle_s": (1.2, 1.5, 2.0, 3.0),
    "trend_tau_s": (1.0, 1.5),
    "start_m": (0.4, 0.5, 0.7),
    "start_rate_m_s": (0.12, 0.15, 0.2),
    "settle_rate_m_s": (0.07, 0.1),
    "level_tau_s": (0.5, 0.7, 1.0),
}


def real_sweep(directory: str | Path, out: Print = print) -> None:
    """How robust the online method's bar on the real logs is to its settings.

    Prints, for each value of each setting, in how many combinations of the others every true
    transition was found with the right storey count and none was false on any log.
    """
    import itertools

    cases = list(real_cases(directory))
    keys = list(SWEEP_GRID)
    passed: dict[tuple[str, float], list[int]] = {}
    for values in itertools.product(*SWEEP_GRID.values()):
        settings: dict[str, Any] = dict(zip(keys, values, strict=True))
        try:
            config = FloorDetectorConfig(**settings)
        except ConfigError:
            continue
        ok = True
        for case in cases:
            s = evaluate(case, "online", config)[1]
            ok = ok and s.found == s.true and s.false == 0 and s.storeys_right == s.true
        for key, value in settings.items():
            tally = passed.setdefault((key, value), [0, 0])
            tally[0] += ok
            tally[1] += 1
    out(f"online method on {len(cases)} real logs: combinations meeting the bar, per setting")
    for (key, value), (good, total) in passed.items():
        out(f"  {key:18s} {value:5g}: {good:4d}/{total}")
