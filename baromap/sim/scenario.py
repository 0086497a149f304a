"""One seeded simulated run: the building, the route, the air, and the barometer readings.

Everything a simulated run is made of derives from ``seed`` through separate random streams
(building, route, weather, ventilation, each sensor), so changing one part (say, the route)
leaves the others as they were, and ``sim record``, the barometer twin and
:func:`pressure_run` agree sample for sample.
"""

from __future__ import annotations

import functools
import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray, IntArray
from baromap.errors import ConfigError
from baromap.messages import NS_PER_S
from baromap.protocols.baro import MAX_RATE_HZ, Q24_8
from baromap.protocols.p2os import HOST_BAUD_CODES
from baromap.protocols.robot_models import DEFAULT_MODEL, RobotModel, robot_model
from baromap.sim.atmosphere import AirTemperature, Ventilation, Weather, hydrostatic_pa
from baromap.sim.bmp280 import Bmp280
from baromap.sim.building import Building, make_building
from baromap.sim.motion import Move, Moves, PoseSamples, sample
from baromap.sim.route import Planner, Visit, check_route, check_stops, default_route

#: Start of every simulated run unless asked otherwise (2023-11-14 22:13:20 UTC).
SIM_EPOCH_NS = 1_700_000_000 * NS_PER_S
#: The barometer board sits this high on the robot.
ROBOT_SENSOR_HEIGHT_M = 0.4
#: The reference station stands on a shelf on floor 0.
REFERENCE_HEIGHT_M = 1.0
#: Longest run simulated: a day (every sample of a run is held in memory at once).
MAX_MINUTES = 24 * 60.0

# Independent random streams of one seed.
_STREAM_ROUTE, _STREAM_WEATHER, _STREAM_VENT, _STREAM_AIR = 1, 2, 3, 4
STREAM_ROBOT_BARO, STREAM_REFERENCE_BARO, STREAM_LASER, STREAM_ODOMETRY = 5, 6, 7, 8
STREAM_FAULTS = 9
_STREAM_STOPS = 10


@dataclass(frozen=True, slots=True)
class Transition:
    """A true floor change: the elevator car moving from one floor to another (halts on the
    way with the robot inside included)."""

    t_start_ns: int
    t_end_ns: int
    from_floor: int
    to_floor: int


@dataclass(frozen=True, slots=True, eq=False)
class Scenario:
    """Everything fixed about one run; sample it at any times."""

    seed: int
    floors: int
    minutes: float
    drift_hpa_per_h: float
    route: tuple[int, ...]
    start_ns: int
    building: Building
    #: What rides past a floor do there (:data:`baromap.sim.route.STOP_KINDS`).
    stops: str
    moves: Moves
    visits: tuple[Visit, ...]
    weather: Weather
    ventilation: Ventilation
    air: AirTemperature
    twins: TwinSettings

    @property
    def duration_s(self) -> float:
        return self.minutes * 60.0

    def rng(self, stream: int) -> np.random.Generator:
        """A fresh random stream of this scenario (same stream, same numbers)."""
        return np.random.default_rng([self.seed, self.floors, stream])

    def t_ns(self, t_s: npt.ArrayLike) -> IntArray:
        out: IntArray = self.start_ns + np.round(
            np.asarray(t_s, dtype=np.float64) * NS_PER_S
        ).astype(np.int64)
        return out

    def truth(self, t_s: npt.ArrayLike) -> PoseSamples:
        return sample(self.moves, t_s)

    def transitions(self) -> list[Transition]:
        rides = np.nonzero(self.moves.kind == Move.RIDE)[0]
        out: list[Transition] = []
        for i in rides:
            t0 = float(self.moves.t0[i])
            t1 = t0 + float(self.moves.duration[i])
            if t1 > self.duration_s:
                continue
            if i > 0 and self.moves.kind[i - 1] == Move.HALT and out:
                # the car halted on the way with the robot inside: one ride
                first = out.pop()
                out.append(
                    Transition(
                        first.t_start_ns,
                        int(self.t_ns(t1)),
                        first.from_floor,
                        int(self.moves.to_floor[i]),
                    )
                )
                continue
            out.append(
                Transition(
                    int(self.t_ns(t0)),
                    int(self.t_ns(t1)),
                    int(self.moves.floor[i]),
                    int(self.moves.to_floor[i]),
                )
            )
        return out

    def true_pressure_pa(self, t_s: npt.ArrayLike, truth: PoseSamples) -> FloatArray:
        """Air pressure at the robot's barometer (before the sensor)."""
        ground = self.weather.ground_pa(t_s)
        p = hydrostatic_pa(ground, truth.z + ROBOT_SENSOR_HEIGHT_M, self.air.mean_c)
        out: FloatArray = p + self.ventilation.pa(t_s, truth.vz)
        return out

    def reference_true_pa(self, t_s: npt.ArrayLike) -> FloatArray:
        ground = self.weather.ground_pa(t_s)
        return hydrostatic_pa(ground, REFERENCE_HEIGHT_M, self.air.mean_c)


@functools.lru_cache(maxsize=32)
def _make_scenario(
    seed: int,
    *,
    floors: int,
    minutes: float,
    drift_hpa_per_h: float,
    route: tuple[int, ...] | None,
    start_ns: int,
    twins: TwinSettings,
    stops: str,
) -> Scenario:
    if seed < 0:
        raise ConfigError(f"seed must not be negative, got {seed}")
    if not 0 < minutes <= MAX_MINUTES:
        raise ConfigError(f"minutes must be above 0 and at most {MAX_MINUTES}, got {minutes}")
    if not 0 <= drift_hpa_per_h < math.inf:
        raise ConfigError(f"drift must be a finite rate of at least 0, got {drift_hpa_per_h}")
    building = make_building(seed, floors)
    chosen = check_route(route if route is not None else default_route(floors), floors)

    def rng(stream: int) -> np.random.Generator:
        return np.random.default_rng([seed, floors, stream])

    moves, visits = Planner(building, rng(_STREAM_ROUTE)).plan(
        chosen, minutes * 60.0, stops=check_stops(stops), stop_rng=rng(_STREAM_STOPS)
    )
    return Scenario(
        seed=seed,
        floors=floors,
        minutes=minutes,
        drift_hpa_per_h=drift_hpa_per_h,
        route=chosen,
        start_ns=start_ns,
        building=building,
        stops=stops,
        moves=moves,
        visits=tuple(visits),
        weather=Weather.random(rng(_STREAM_WEATHER), drift_hpa_per_h),
        ventilation=Ventilation.for_moves(moves, rng(_STREAM_VENT)),
        air=AirTemperature.random(rng(_STREAM_AIR), building.elevations_m),
        twins=twins,
    )


def make_scenario(
    seed: int = 0,
    *,
    floors: int = 6,
    minutes: float = 46.0,
    drift_hpa_per_h: float = 1.5,
    route: Sequence[int] | None = None,
    start_ns: int = SIM_EPOCH_NS,
    twins: TwinSettings | None = None,
    stops: str = "none",
) -> Scenario:
    """The scenario of a seed (cached: the twins and the recorder share one).

    ``stops`` says what rides past a floor do there: ``"none"`` (go straight through),
    ``"stay"`` (halt with the robot inside) or ``"leave"`` (the robot gets out to make room).
    """
    return _make_scenario(
        int(seed),
        floors=int(floors),
        minutes=float(minutes),
        drift_hpa_per_h=float(drift_hpa_per_h),
        route=tuple(int(f) for f in route) if route is not None else None,
        start_ns=int(start_ns),
        twins=twins if twins is not None else TwinSettings(),
        stops=str(stops),
    )


@dataclass(frozen=True, slots=True, eq=False)
class PressureRun:
    """The barometer part of a run, at the board's sample rate."""

    seed: int
    floors: int
    rate_hz: float
    t_ns: IntArray
    pressure_pa: FloatArray
    temperature_c: FloatArray
    #: Floor index (0 = lowest), -1 while the elevator car moves.
    truth_floor: IntArray
    #: Height of the floor the robot stands on (the car's floor during rides) above floor 0.
    truth_z_m: FloatArray
    transitions: tuple[Transition, ...]
    #: What a fixed reference station on floor 0 reads at the same times.
    reference_pa: FloatArray
    reference_temperature_c: FloatArray
    #: Noise-free air pressure at the robot's sensor (for checking, not for detectors).
    true_pressure_pa: FloatArray
    elevations_m: FloatArray

    @property
    def t_s(self) -> FloatArray:
        out: FloatArray = (self.t_ns - self.t_ns[0]) / NS_PER_S
        return out


def sample_times(duration_s: float, rate_hz: float) -> FloatArray:
    if not 0 < rate_hz <= MAX_RATE_HZ:
        raise ConfigError(f"rate must be above 0 and at most {MAX_RATE_HZ} Hz, got {rate_hz}")
    count = int(np.floor(duration_s * rate_hz))
    if count < 2:
        raise ConfigError(f"{duration_s:g} s at {rate_hz:g} Hz is fewer than two samples")
    return np.arange(count) / rate_hz


def pressure_run(
    seed: int,
    *,
    floors: int = 6,
    minutes: float = 46.0,
    drift_hpa_per_h: float = 1.5,
    rate_hz: float = 25.0,
    route: Sequence[int] | None = None,
    start_ns: int = SIM_EPOCH_NS,
    stops: str = "none",
) -> PressureRun:
    """The robot's barometer readings over a whole run, with the truth to score them by."""
    sc = make_scenario(
        seed,
        floors=floors,
        minutes=minutes,
        drift_hpa_per_h=drift_hpa_per_h,
        route=route,
        start_ns=start_ns,
        stops=stops,
    )
    return scenario_pressure_run(sc, rate_hz)


def scenario_pressure_run(sc: Scenario, rate_hz: float = 25.0) -> PressureRun:
    """:func:`pressure_run` of a scenario already made (the recorder needs both)."""
    t = sample_times(sc.duration_s, rate_hz)
    truth = sc.truth(t)
    true_p = sc.true_pressure_pa(t, truth)
    robot = Bmp280.random(sc.rng(STREAM_ROBOT_BARO), rate_hz)
    pressure, temperature = robot.measure(true_p, sc.air.at(truth.z))
    # The firmware sends Q24.8 pascals: the run holds exactly what crosses the wire.
    pressure = np.round(pressure * Q24_8) / Q24_8
    station = Bmp280.random(sc.rng(STREAM_REFERENCE_BARO), rate_hz, heated=False)
    ref_p, ref_t = station.measure(sc.reference_true_pa(t), sc.air.floor_c[0])
    return PressureRun(
        seed=sc.seed,
        floors=sc.floors,
        rate_hz=rate_hz,
        t_ns=sc.t_ns(t),
        pressure_pa=pressure,
        temperature_c=temperature,
        truth_floor=truth.floor,
        truth_z_m=truth.z,
        transitions=tuple(sc.transitions()),
        reference_pa=ref_p,
        reference_temperature_c=ref_t,
        true_pressure_pa=true_p,
        elevations_m=sc.building.elevations_m,
    )


# ---------------------------------------------------------------------------------------------
# Twin settings: what the simulated devices are and what happens to them during the run
# ---------------------------------------------------------------------------------------------

#: Device names the settings and faults refer to (the twins' names).
TWIN_NAMES: Final = ("lms200", "p3at", "baro")
#: Faults a twin can suffer at a set simulated time.
FAULT_KINDS: Final = ("power_cycle", "stall", "garbage", "drop", "unplug")


@dataclass(frozen=True, slots=True)
class Fault:
    """Something that happens to one device ``at_s`` simulated seconds into the run.

    ``power_cycle``: the device loses power for ``duration_s`` and boots again (the LMS200
    then sends its power-on telegram, the barometer board its HELLO, the robot forgets its
    session); ``stall``: silent for ``duration_s``; ``garbage``: ``size`` bytes of noise on the
    line; ``drop``: the next ``size`` bytes it sends are lost; ``unplug``: the port vanishes for
    ``duration_s`` and comes back on a new pty behind the same link.
    """

    device: str
    at_s: float
    kind: str
    duration_s: float = 0.0
    size: int = 0

    def __post_init__(self) -> None:
        if self.device not in TWIN_NAMES:
            raise ConfigError(f"fault device must be one of {TWIN_NAMES}, not {self.device!r}")
        if self.kind not in FAULT_KINDS:
            raise ConfigError(f"fault kind must be one of {FAULT_KINDS}, not {self.kind!r}")
        if not (0 <= self.at_s < math.inf and 0 <= self.duration_s < math.inf):
            raise ConfigError("fault times must be finite and not negative")
        if not 0 <= self.size <= 1 << 20:
            raise ConfigError(f"fault size must be 0..{1 << 20} bytes, not {self.size}")


@dataclass(frozen=True, slots=True)
class TwinSettings:
    """How the simulated devices present themselves, and the faults of the run.

    The robot reports ``robot_subclass`` in its SYNC2 echo and counts positions with that
    model's DistConvFactor (default the ARCOS P3-AT, ``p3at-sh``; ``p3at`` gives the old
    P2OS generation). The laser needs ``laser_boot_s`` simulated seconds from power-on (or a
    reset) to its power-on telegram; real drivers wait up to a minute for it. ``robot_baud``
    is the robot's host port speed (ARCOS' ``HostBaud`` in its FLASH configuration; 9600 from
    the factory): a twin sped up past 2.6x needs a faster line for its 10 Hz SIPs.
    """

    robot_subclass: str = DEFAULT_MODEL.name
    robot_name: str = "baromap-sim"
    robot_baud: int = 9600
    laser_boot_s: float = 2.0
    laser_type: str = "LMS200;30106"
    baro_rate_hz: int = 25
    faults: tuple[Fault, ...] = ()

    def __post_init__(self) -> None:
        robot_model(self.robot_subclass)  # ConfigError for a subclass without parameter set
        if self.robot_baud not in HOST_BAUD_CODES:
            raise ConfigError(f"robot_baud must be one of {sorted(HOST_BAUD_CODES)}")
        if not 0 < self.laser_boot_s <= 120:
            raise ConfigError(f"laser_boot_s must be in (0, 120], not {self.laser_boot_s}")
        if not 1 <= self.baro_rate_hz <= MAX_RATE_HZ:
            raise ConfigError(f"baro_rate_hz must be 1..{MAX_RATE_HZ}, not {self.baro_rate_hz}")
        if any("\x00" in text for text in (self.robot_name, self.robot_subclass)):
            raise ConfigError("robot name and subclass cannot contain NUL")

    @property
    def robot_model(self) -> RobotModel:
        return robot_model(self.robot_subclass)

    def faults_of(self, device: str) -> tuple[Fault, ...]:
        """This device's faults in time order."""
        return tuple(sorted((f for f in self.faults if f.device == device), key=lambda f: f.at_s))


def twin_settings(values: Mapping[str, Any]) -> TwinSettings:
    """Settings from a mapping (a parsed TOML table); unknown keys are a ConfigError.

    ``faults`` is a list of tables with the fields of :class:`Fault`.
    """
    known = {f.name for f in fields(TwinSettings)}
    unknown = set(values) - known
    if unknown:
        raise ConfigError(f"unknown twin settings {sorted(unknown)}; known: {sorted(known)}")
    raw = dict(values)
    faults = []
    for item in raw.pop("faults", ()):
        if not isinstance(item, Mapping):
            raise ConfigError("each fault is a table (device, at_s, kind, ...)")
        try:
            faults.append(Fault(**item))
        except TypeError as exc:
            raise ConfigError(f"bad fault {dict(item)}: {exc}") from exc
    try:
        return TwinSettings(**raw, faults=tuple(faults))
    except TypeError as exc:
        raise ConfigError(f"bad twin settings: {exc}") from exc


def load_twin_settings(path: str | Path) -> TwinSettings:
    """Twin settings from a TOML file (the table ``[twins]``, or the whole file)."""
    path = Path(path)
    try:
        with path.open("rb") as handle:
            document = tomllib.load(handle)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"cannot read twin settings {path}: {exc}") from exc
    table = document.get("twins", document)
    if not isinstance(table, Mapping):
        raise ConfigError(f"{path}: [twins] must be a table")
    return twin_settings(table)
