"""The air the barometer sits in: weather, height, temperature, and elevator ventilation.

Why each part is here:
- Weather drift: outside pressure moves by up to about 1.5 hPa per hour (fronts), more than
  one storey (about 0.4 hPa) in an hour, so floors cannot be told by absolute pressure. The
  drift rate oscillates slowly (a trend plus a sine of 30-120 min period), and wind adds
  small gusts of a few tenths of a pascal to a pascal that every sensor in the building
  feels at once (which a reference station cancels).
- Height: hydrostatic, p(z) = p(0) exp(-g z / (R_d T)) with the indoor air temperature,
  about 11.8 Pa per metre.
- Ventilation: a moving elevator car pushes air (a piston effect proportional to its
  speed), its fan and door seals make spikes of 5-25 Pa that last a second or two, and the
  car is slightly pressurised between door close and door open. These are what make naive
  rate-of-change detectors fire twice per ride.
- Temperature: each floor has its own air temperature; the sensor follows it slowly (it sits
  in a box on the robot, warmed by the electronics), and its temperature moves its
  pressure offset (BMP280: 1.5 Pa/K).

Every quantity is a closed-form function of time, so the same model serves a whole recording
in one vectorised call and a real-time twin one sample at a time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray
from baromap.sim.motion import Move, Moves

R_DRY_AIR = 287.05  # J / (kg K)
GRAVITY = 9.80665  # m / s^2
KELVIN = 273.15


def hydrostatic_pa(p_ground_pa: npt.ArrayLike, z_m: npt.ArrayLike, air_c: float) -> FloatArray:
    """Pressure ``z_m`` above a level where it is ``p_ground_pa``, in air at ``air_c``."""
    out: FloatArray = np.asarray(p_ground_pa, dtype=np.float64) * np.exp(
        -GRAVITY * np.asarray(z_m, dtype=np.float64) / (R_DRY_AIR * (air_c + KELVIN))
    )
    return out


def height_m(p_pa: npt.ArrayLike, p_ref_pa: npt.ArrayLike, air_c: float) -> FloatArray:
    """Inverse of :func:`hydrostatic_pa`: height of ``p_pa`` above the ``p_ref_pa`` level."""
    out: FloatArray = (R_DRY_AIR * (air_c + KELVIN) / GRAVITY) * np.log(
        np.asarray(p_ref_pa, dtype=np.float64) / np.asarray(p_pa, dtype=np.float64)
    )
    return out


@dataclass(frozen=True, slots=True)
class Weather:
    """Outside pressure at floor-0 level: a drifting front plus wind gusts."""

    p0_pa: float
    drift_max_pa_s: float
    trend: float  # mean drift as a fraction of the maximum, in [-1, 1]
    period_s: float
    phase: float
    gust_amp_pa: FloatArray
    gust_omega: FloatArray
    gust_phase: FloatArray

    @classmethod
    def random(cls, rng: np.random.Generator, drift_hpa_per_h: float) -> Weather:
        n = 24
        periods = np.exp(rng.uniform(np.log(4.0), np.log(120.0), n))
        amps = rng.rayleigh(1.0, n) * np.sqrt(periods / periods.max())
        amps *= 0.8 / np.sqrt(0.5 * np.sum(amps**2))  # about 0.8 Pa RMS of gusts in total
        return cls(
            p0_pa=float(rng.uniform(99_500.0, 102_500.0)),
            drift_max_pa_s=drift_hpa_per_h * 100.0 / 3600.0,
            trend=float(rng.choice([-1.0, 1.0]) * rng.uniform(0.3, 0.9)),
            period_s=float(rng.uniform(30.0, 120.0) * 60.0),
            phase=float(rng.uniform(0.0, math.tau)),
            gust_amp_pa=amps,
            gust_omega=math.tau / periods,
            gust_phase=rng.uniform(0.0, math.tau, n),
        )

    def drift_rate_pa_s(self, t_s: npt.ArrayLike) -> FloatArray:
        """Slope of the front; its magnitude never exceeds ``drift_max_pa_s``."""
        t = np.asarray(t_s, dtype=np.float64)
        swing = 1.0 - abs(self.trend)
        out: FloatArray = self.drift_max_pa_s * (
            self.trend + swing * np.sin(math.tau * t / self.period_s + self.phase)
        )
        return out

    def drift_pa(self, t_s: npt.ArrayLike) -> FloatArray:
        t = np.asarray(t_s, dtype=np.float64)
        swing = 1.0 - abs(self.trend)
        w = math.tau / self.period_s
        out: FloatArray = self.drift_max_pa_s * (
            self.trend * t - swing / w * (np.cos(w * t + self.phase) - math.cos(self.phase))
        )
        return out

    def gusts_pa(self, t_s: npt.ArrayLike) -> FloatArray:
        t = np.asarray(t_s, dtype=np.float64)
        out: FloatArray = (
            np.sin(np.multiply.outer(t, self.gust_omega) + self.gust_phase) @ self.gust_amp_pa
        )
        return out

    def ground_pa(self, t_s: npt.ArrayLike) -> FloatArray:
        out: FloatArray = self.p0_pa + self.drift_pa(t_s) + self.gusts_pa(t_s)
        return out


@dataclass(frozen=True, slots=True)
class Ventilation:
    """Pressure disturbances inside the elevator car, tied to the rides of a plan."""

    piston_pa_per_mps: float
    seal_start_s: FloatArray
    seal_end_s: FloatArray
    seal_pa: FloatArray
    spike_t_s: FloatArray
    spike_pa: FloatArray
    spike_width_s: FloatArray

    @classmethod
    def for_moves(cls, moves: Moves, rng: np.random.Generator) -> Ventilation:
        rides = np.nonzero(moves.kind == Move.RIDE)[0]
        seal_start, seal_end, seal, spike_t, spike_pa, width = [], [], [], [], [], []
        for i in rides:
            # Doors close during the wait before the ride and open during the wait after.
            closed = moves.t0[i] - (moves.duration[i - 1] if i > 0 else 0.0) * 0.5
            opened = (
                moves.t0[i]
                + moves.duration[i]
                + (moves.duration[i + 1] * 0.5 if i + 1 < len(moves) else 0.0)
            )
            seal_start.append(closed)
            seal_end.append(opened)
            seal.append(rng.uniform(1.0, 5.0))
            for _ in range(1 + rng.poisson(1.5)):
                spike_t.append(rng.uniform(closed, opened))
                spike_pa.append(rng.choice([-1.0, 1.0]) * rng.uniform(5.0, 25.0))
                width.append(rng.uniform(0.4, 2.0))
        return cls(
            piston_pa_per_mps=float(rng.choice([-1.0, 1.0]) * rng.uniform(3.0, 8.0)),
            seal_start_s=np.array(seal_start),
            seal_end_s=np.array(seal_end),
            seal_pa=np.array(seal),
            spike_t_s=np.array(spike_t),
            spike_pa=np.array(spike_pa),
            spike_width_s=np.array(width),
        )

    def pa(self, t_s: npt.ArrayLike, vz_mps: npt.ArrayLike) -> FloatArray:
        """Disturbance at times ``t_s`` (seconds of the plan) given the car's vertical speed."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        out = self.piston_pa_per_mps * np.broadcast_to(
            np.asarray(vz_mps, dtype=np.float64), t.shape
        )
        if len(self.seal_pa):
            # Smooth steps (about 1 s) up at door close and down at door open.
            up = 0.5 * (1 + np.tanh(np.subtract.outer(t, self.seal_start_s) * 3.0))
            down = 0.5 * (1 + np.tanh(np.subtract.outer(self.seal_end_s, t).T * 3.0))
            out = out + (up * down) @ self.seal_pa
        if len(self.spike_pa):
            # Fast rise, exponential decay.
            dt = np.subtract.outer(t, self.spike_t_s)
            shape = np.where(
                dt < 0,
                np.exp(-((dt / (0.15 * self.spike_width_s)) ** 2)),
                np.exp(-np.maximum(dt, 0.0) / self.spike_width_s),
            )
            out = out + shape @ self.spike_pa
        result: FloatArray = np.asarray(out, dtype=np.float64)
        return result


@dataclass(frozen=True, slots=True)
class AirTemperature:
    """Air temperature per floor (the hydrostatics use the building's mean)."""

    elevations_m: FloatArray
    floor_c: FloatArray

    @classmethod
    def random(cls, rng: np.random.Generator, elevations_m: FloatArray) -> AirTemperature:
        temps = rng.uniform(20.0, 23.5, len(elevations_m))
        temps[0] = rng.uniform(18.0, 20.5)  # the ground floor, doors to the street
        return cls(np.asarray(elevations_m, dtype=np.float64), temps)

    @property
    def mean_c(self) -> float:
        return float(self.floor_c.mean())

    def at(self, z_m: npt.ArrayLike) -> FloatArray:
        out: FloatArray = np.interp(
            np.asarray(z_m, dtype=np.float64), self.elevations_m, self.floor_c
        )
        return out
