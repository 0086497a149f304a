"""Replay a recorded run through the live detector, exactly as it would have run live.

The robot's pressure, a reference station's pressure and the robot's odometry are fed in one
time order (at equal stamps: reference, then odometry, then the robot's sample, i.e. what
the robot's sample could have known), so a replay of a recording decides what the live
detector decided, event ids included.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from baromap.floors.config import FloorDetectorConfig
from baromap.floors.online import OnlineFloorDetector
from baromap.messages import Odometry, PressureSample


def replay(
    t_ns: npt.ArrayLike,
    pressure_pa: npt.ArrayLike,
    temperature_c: npt.ArrayLike | None = None,
    config: FloorDetectorConfig | None = None,
    *,
    reference: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
    odometry: tuple[npt.ArrayLike, npt.ArrayLike, npt.ArrayLike] | None = None,
) -> tuple[OnlineFloorDetector, npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Run the detector over a run; returns it (its ``events``, ``transitions``, ``registry``)
    with the Holt level and rate after each pressure sample."""
    detector = OnlineFloorDetector(config)
    times = np.asarray(t_ns, dtype=np.int64).tolist()
    pressures = np.asarray(pressure_pa, dtype=np.float64).tolist()
    temps = (
        [math.nan] * len(times)
        if temperature_c is None
        else np.asarray(temperature_c, dtype=np.float64).tolist()
    )
    ref_t: list[int] = []
    ref_p: list[float] = []
    if reference is not None:
        ref_t = np.asarray(reference[0], dtype=np.int64).tolist()
        ref_p = np.asarray(reference[1], dtype=np.float64).tolist()
    odo_t: list[int] = []
    odo_x: list[float] = []
    odo_y: list[float] = []
    if odometry is not None:
        odo_t = np.asarray(odometry[0], dtype=np.int64).tolist()
        odo_x = np.asarray(odometry[1], dtype=np.float64).tolist()
        odo_y = np.asarray(odometry[2], dtype=np.float64).tolist()
    smoothed = np.empty(len(times))
    rate = np.empty(len(times))
    r = o = 0
    for i, (ti, pi, ci) in enumerate(zip(times, pressures, temps, strict=True)):
        while r < len(ref_t) and ref_t[r] <= ti:
            detector.update_reference(PressureSample(ref_t[r], ref_p[r]))
            r += 1
        while o < len(odo_t) and odo_t[o] <= ti:
            detector.update_odometry(Odometry(odo_t[o], odo_x[o], odo_y[o], 0.0))
            o += 1
        detector.update(PressureSample(ti, pi, None if math.isnan(ci) else ci))
        smoothed[i] = detector.level
        rate[i] = detector.rate
    detector.finish()
    return detector, smoothed, rate
