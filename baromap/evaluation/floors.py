"""The floor-detection evaluation: both methods over the real IPIN logs and simulated runs.

Each case is a pressure series with its truth (and odometry, a reference station, when it
has them). Each method's post-run segmentation is scored on it
(:mod:`baromap.floors.evaluation`); for the online method the live decisions are scored
apart (:mod:`baromap.evaluation.floor_live`): what was published when, corrections applied,
and whether that equals the post-run transitions. Nothing here prints: results are returned
(and handed to ``on_result`` as they come) for the command to show.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from baromap.errors import ConfigError
from baromap.evaluation.floor_live import LiveScore, RideScore, live_score
from baromap.floors.config import FloorDetectorConfig
from baromap.floors.detection import FloorDetection, detect_floors
from baromap.floors.evaluation import (
    DetectionRates,
    FloorTruth,
    Score,
    score,
    truth_from_series,
    with_settle_times,
)
from baromap.floors.inputs import OdometrySeries as Odometry

if TYPE_CHECKING:
    from baromap.sim.scenario import Scenario


@dataclass(frozen=True, slots=True, eq=False)
class Case:
    name: str
    kind: str  # "real", "sim" or "input"
    t_ns: npt.NDArray[np.int64]
    pressure_pa: npt.NDArray[np.float64]
    temperature_c: npt.NDArray[np.float64] | None
    truth: FloorTruth
    reference: tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]] | None = None
    #: ``(t_ns, x_m, y_m)`` of the robot's odometry, when the case has any.
    odometry: Odometry | None = None


@dataclass(frozen=True, slots=True)
class SimSettings:
    """How the simulated runs of a report are made."""

    drift_hpa_per_h: float = 1.5
    minutes: float = 46.0
    use_reference: bool = False
    use_odometry: bool = True
    stops: str = "none"
    route: tuple[int, ...] | None = None


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


def sim_case(seed: int, settings: SimSettings | None = None) -> Case:
    from baromap.sim.scenario import make_scenario, scenario_pressure_run

    s = settings or SimSettings()
    scenario = make_scenario(
        seed, minutes=s.minutes, drift_hpa_per_h=s.drift_hpa_per_h, stops=s.stops, route=s.route
    )
    run = scenario_pressure_run(scenario)
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
    reference = (run.t_ns, np.asarray(run.reference_pa)) if s.use_reference else None
    return Case(
        f"sim seed {seed}",
        "sim",
        np.asarray(run.t_ns),
        np.asarray(run.pressure_pa),
        np.asarray(run.temperature_c),
        truth,
        reference,
        sim_odometry(scenario) if s.use_odometry else None,
    )


def sim_odometry(scenario: Scenario) -> Odometry:
    """The odometry a simulated run's robot reports: its true motion through the robot's own
    error model, one pose per SIP (what ``sim record`` writes on /odom, before the wire)."""
    from baromap.odometry.errors import OdometryErrorModel
    from baromap.sim.odometry import SIP_PERIOD_S, OdometryModel, true_increments
    from baromap.sim.scenario import STREAM_ODOMETRY

    t = np.arange(SIP_PERIOD_S / 2, scenario.duration_s, SIP_PERIOD_S)
    truth = scenario.truth(t)
    rng = scenario.rng(STREAM_ODOMETRY)
    model = OdometryModel(OdometryErrorModel.random(rng), rng)
    start = scenario.moves.start[0]
    ds, dth = true_increments(
        truth.x, truth.y, truth.theta, (float(start[0]), float(start[1]), float(start[2]))
    )
    x, y, _ = model.step(ds, dth)
    return scenario.t_ns(t), x, y


def evaluate(
    case: Case, method: str, config: FloorDetectorConfig | None = None
) -> tuple[FloorDetection, Score]:
    """The post-run segmentation of a case, scored."""
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


@dataclass(frozen=True, slots=True)
class CaseResult:
    """One case and method: the post-run score, and for the online method the live one."""

    name: str
    kind: str
    method: str
    post_run: Score
    live: LiveScore | None


def evaluate_case(case: Case, method: str, config: FloorDetectorConfig | None = None) -> CaseResult:
    detection, post = evaluate(case, method, config)
    live = live_score(detection, case.truth) if method == "online" else None
    return CaseResult(case.name, case.kind, method, post, live)


@dataclass
class Totals(DetectionRates):
    """Scores summed over cases (one method, one kind of figure)."""

    true: int = 0
    found: int = 0
    false: int = 0
    direction: int = 0
    storeys: int = 0
    cases: int = 0
    accuracy_sum: float = 0.0
    height_max: float = 0.0
    heights: int = 0
    delays: list[float] = field(default_factory=list)
    settled_delays: list[float] = field(default_factory=list)

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

    @property
    def mean_accuracy(self) -> float:
        return self.accuracy_sum / max(self.cases, 1)


def percentile(values: Sequence[float], q: float) -> float:
    return float(np.percentile(values, q)) if len(values) else float("nan")


@dataclass
class MethodTotals:
    """One method over the simulated cases: post-run and (online) live figures."""

    post_run: Totals = field(default_factory=Totals)
    live: Totals = field(default_factory=Totals)
    events: int = 0
    corrections: int = 0
    #: corrections that sent the robot to another floor, and transitions withdrawn
    moves: int = 0
    retractions: int = 0
    agreeing: int = 0
    live_cases: int = 0
    rides: list[RideScore] = field(default_factory=list)

    def add(self, result: CaseResult) -> None:
        self.post_run.add(result.post_run)
        if result.live is not None:
            self.live.add(result.live.score)
            self.events += result.live.events
            self.corrections += result.live.corrections
            self.moves += result.live.moves
            self.retractions += result.live.retractions
            self.agreeing += result.live.agrees
            self.live_cases += 1
            if result.live.rides is not None:
                self.rides.append(result.live.rides)


@dataclass
class Report:
    real: list[CaseResult] = field(default_factory=list)
    sim: list[CaseResult] = field(default_factory=list)
    totals: dict[str, MethodTotals] = field(default_factory=dict)


def run_report(
    real_dir: str | Path | None,
    seeds: Sequence[int],
    methods: Sequence[str] = ("online", "paper"),
    *,
    sim: SimSettings | None = None,
    config: FloorDetectorConfig | None = None,
    on_result: Callable[[CaseResult], None] | None = None,
) -> Report:
    """Score every real log and simulated seed; totals are over the simulated seeds."""
    report = Report(totals={method: MethodTotals() for method in methods})
    cases = real_cases(real_dir) if real_dir is not None else []
    for real in cases:
        for method in methods:
            result = evaluate_case(real, method, config)
            report.real.append(result)
            if on_result is not None:
                on_result(result)
    for seed in seeds:
        case = sim_case(seed, sim)
        for method in methods:
            result = evaluate_case(case, method, config)
            report.sim.append(result)
            report.totals[method].add(result)
            if on_result is not None:
                on_result(result)
    return report


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


@dataclass(frozen=True, slots=True)
class SweepResult:
    cases: int
    #: ``(setting, value) -> (combinations meeting the bar, combinations tried)``.
    passed: dict[tuple[str, float], tuple[int, int]]


def real_sweep(directory: str | Path) -> SweepResult:
    """How robust the online method's bar on the real logs is to its settings.

    For each value of each setting: in how many combinations of the others every true
    transition was found with the right storey count and none was false on any log.
    """
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
    return SweepResult(len(cases), {k: (v[0], v[1]) for k, v in passed.items()})
