"""One seeded simulated run: the building, the route, the air, and the barometer readings.

Everything a simulated run is made of derives from ``seed`` through separate random streams
(building, route, weather, ventilation, each sensor), so changing one part (say, the route)
leaves the others as they were, and ``sim record``, the barometer twin and
:func:`pressure_run` agree sample for sample.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from baromap.errors import ConfigError
from baromap.messages import NS_PER_S
from baromap.protocols.baro import MAX_RATE_HZ, Q24_8
from baromap.sim.atmosphere import AirTemperature, Ventilation, Weather, hydrostatic_pa
from baromap.sim.bmp280 import Bmp280
from baromap.sim.building import Building, make_building
from baromap.sim.motion import Move, Moves, PoseSamples, sample
from baromap.sim.route import Planner, Visit, check_route, check_stops, default_route

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

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
_STREAM_STOPS = 9


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
    )


def make_scenario(
    seed: int = 0,
    *,
    floors: int = 6,
    minutes: float = 46.0,
    drift_hpa_per_h: float = 1.5,
    route: Sequence[int] | None = None,
    start_ns: int = SIM_EPOCH_NS,
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
        seed=seed,
        floors=floors,
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
