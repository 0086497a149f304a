"""Scripted barometer traces with known answers: stays at heights, rides between them, and
the robot's odometry, for the floor-detection failure cases that a whole simulated run may
never show (a landing near a known floor, a short stop at a passing floor with and without
the robot driving off)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from baromap.floors.config import FloorDetectorConfig
from baromap.floors.height import scale_height_m
from baromap.floors.online import OnlineFloorDetector
from baromap.floors.replay import replay
from baromap.messages import NS_PER_S

#: Where scripted runs start: a Monday morning in 2023 (any epoch would do).
TRACE_EPOCH_NS = 1_700_000_000 * NS_PER_S
#: Odometry rate of a P3-AT (one SIP every 100 ms).
ODOMETRY_HZ = 10.0
#: How fast the robot drives when a stay says it drives (a cautious indoor speed).
DRIVE_M_S = 0.5


@dataclass(frozen=True, slots=True)
class Stay:
    """``seconds`` at ``height_m``; the robot drives ``drive_m`` straight ahead, starting
    ``drive_after_s`` into the stay (0 = it stays put, as in an elevator car)."""

    height_m: float
    seconds: float
    drive_m: float = 0.0
    drive_after_s: float = 2.0


@dataclass(frozen=True, slots=True, eq=False)
class Trace:
    t_ns: npt.NDArray[np.int64]
    pressure_pa: npt.NDArray[np.float64]
    temperature_c: npt.NDArray[np.float64]
    #: ``(t_ns, x_m, y_m)`` of the robot's odometry.
    odometry: tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64]]
    #: When each stay began and ended (s from the start).
    stays_s: tuple[tuple[float, float], ...]

    def seconds(self) -> npt.NDArray[np.float64]:
        out: npt.NDArray[np.float64] = (self.t_ns - self.t_ns[0]) / NS_PER_S
        return out

    def detected(
        self, config: FloorDetectorConfig | None = None, *, odometry: bool = True
    ) -> OnlineFloorDetector:
        """The live detector after the whole trace, sample by sample as the daemon feeds it:
        with the robot's odometry, or without it (a base that publishes none)."""
        detector, _, _ = replay(
            self.t_ns,
            self.pressure_pa,
            self.temperature_c,
            config,
            odometry=self.odometry if odometry else None,
        )
        return detector


def trace(
    stays: Sequence[Stay],
    *,
    rate_hz: float = 10.0,
    ride_m_s: float = 1.0,
    noise_pa: float = 0.3,
    drift_pa_s: float = 0.0,
    seed: int = 0,
    p0_pa: float = 97_700.0,
    temperature_c: float = 15.0,
) -> Trace:
    """Pressure and odometry of a robot that stays, rides at ``ride_m_s``, stays, ..."""
    heights: list[float] = []
    bounds: list[tuple[float, float]] = []
    drive: list[tuple[float, float, float]] = []  # (start s, end s, metres)
    for k, stay in enumerate(stays):
        if k:
            previous = stays[k - 1].height_m
            steps = max(1, int(abs(stay.height_m - previous) / ride_m_s * rate_hz))
            heights.extend(np.linspace(previous, stay.height_m, steps, endpoint=False)[1:].tolist())
        begin = len(heights) / rate_hz
        heights.extend([stay.height_m] * int(stay.seconds * rate_hz))
        bounds.append((begin, len(heights) / rate_hz))
        if stay.drive_m > 0.0:
            start = begin + stay.drive_after_s
            drive.append((start, start + stay.drive_m / DRIVE_M_S, stay.drive_m))
    z = np.asarray(heights)
    t_s = np.arange(z.size) / rate_hz
    rng = np.random.default_rng(seed)
    p = p0_pa * np.exp(-z / scale_height_m(temperature_c))
    p = p + drift_pa_s * t_s + rng.normal(0.0, noise_pa, z.size)
    odo_s = np.arange(0.0, t_s[-1] + 1e-9, 1.0 / ODOMETRY_HZ)
    x = np.zeros(odo_s.size)
    for start, end, metres in drive:
        x += np.clip((odo_s - start) / (end - start), 0.0, 1.0) * metres
    return Trace(
        t_ns=TRACE_EPOCH_NS + np.round(t_s * NS_PER_S).astype(np.int64),
        pressure_pa=p,
        temperature_c=np.full(z.size, temperature_c),
        odometry=(
            TRACE_EPOCH_NS + np.round(odo_s * NS_PER_S).astype(np.int64),
            x,
            np.zeros(odo_s.size),
        ),
        stays_s=tuple(bounds),
    )
