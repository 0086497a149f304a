"""Settings of floor detection, with defaults chosen from physics rather than from one data set.

Heights and vertical speeds are given in metres and metres per second and converted to pascals
with the hypsometric equation at the measured pressure and temperature, so the same settings
hold at sea level and on a mountain, in winter and in summer.

Why the defaults are what they are:

- ``min_transition_m = 1.8``: the lowest storey in ordinary buildings is above 2.4 m floor to
  floor (the IPIN museum logs have 2.4-3.4 m); 1.8 m leaves room for noise below that while
  staying far above what ventilation, doors and weather do in a few seconds (a few pascals,
  i.e. tens of centimetres).
- ``start_m = 0.5`` and ``start_rate_m_s = 0.15``: a change begins when the smoothed pressure
  leaves the floor's level by half a metre, or moves faster than a slow walk up a ramp. Either
  is far above sensor noise (a few tenths of a pascal for a BMP280 filtered over a second).
- ``settle_rate_m_s = 0.1`` over ``settle_s = 1.5``: "settled" means that over the last second
  and a half the pressure moved as little as a vertical speed of 10 cm/s would move it: the
  smoothed pressure stayed within that band and the least-squares slope of the raw pressure is
  below that speed (one window, so one lag). An elevator moves at 0.5-2 m/s and stairs at
  0.1-0.3 m/s; the short window keeps the decision within a couple of seconds of the pressure
  settling. A person carrying a phone is never still for long.
- ``level_tau_s = 0.5`` / ``trend_tau_s = 1.5``: the smoothers' time constants. The level
  constant smooths the pressure the settle band is judged on (and the Holt level); the trend
  constant only sets how fast the Holt rate that starts a change reacts. A shorter trend
  constant makes that rate noisy on a hand-held phone.
- ``drift_tau_s = 60``: while the robot stays on a floor, slow changes are weather (up to
  ~3 hPa/h, i.e. 0.08 Pa/s) and the floor's level follows them with this time constant; the
  drift rate itself is averaged over ``drift_rate_tau_s``.
- ``landing_s = 15``: a stop shorter than this between two legs of vertical motion in the same
  direction (a stair landing) is part of one trip, which is then dated from its first leg.
  For as long after a transition the trip may still be ending (doors opening, a ventilation
  spike fading, a landing), so the new floor's level follows the pressure within ``start_m``
  and a first visit's level moves to where a continuing leg ends.
- The paper's constants (``paper_alpha``, ``paper_gamma``, ``paper_sigmas``) are per sample, as
  the paper states them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from baromap.errors import ConfigError
from baromap.floors.height import STANDARD_TEMPERATURE_C

#: Air temperatures a barometer can plausibly report; outside them a reading is a glitch.
MIN_AIR_C, MAX_AIR_C = -80.0, 80.0


@dataclass(frozen=True, slots=True)
class FloorDetectorConfig:
    """Floor-detection settings (see the module docstring for the reasons behind defaults)."""

    min_transition_m: float = 1.8
    start_m: float = 0.5
    start_rate_m_s: float = 0.15
    settle_rate_m_s: float = 0.1
    settle_s: float = 1.5
    level_tau_s: float = 0.5
    trend_tau_s: float = 1.5
    drift_tau_s: float = 60.0
    drift_rate_tau_s: float = 300.0
    landing_s: float = 15.0
    reference_tau_s: float = 10.0
    default_temperature_c: float = STANDARD_TEMPERATURE_C
    max_gap_s: float = 10.0
    paper_alpha: float = 0.1
    paper_gamma: float = 0.1
    paper_sigmas: float = 2.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, int | float) or not math.isfinite(value):
                raise ConfigError(f"{f.name} must be a finite number, not {value!r}")
        positive = (
            "min_transition_m",
            "start_m",
            "start_rate_m_s",
            "settle_rate_m_s",
            "settle_s",
            "level_tau_s",
            "trend_tau_s",
            "drift_tau_s",
            "drift_rate_tau_s",
            "reference_tau_s",
            "max_gap_s",
            "paper_sigmas",
        )
        for name in positive:
            if getattr(self, name) <= 0:
                raise ConfigError(f"{name} must be positive, not {getattr(self, name)}")
        if self.landing_s < 0:
            raise ConfigError("landing_s must not be negative")
        if self.start_m >= self.min_transition_m:
            raise ConfigError("start_m must be below min_transition_m, or no change could start")
        if self.settle_rate_m_s > self.start_rate_m_s:
            raise ConfigError("settle_rate_m_s must not exceed start_rate_m_s")
        for name in ("paper_alpha", "paper_gamma"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ConfigError(f"{name} must be in (0, 1], not {getattr(self, name)}")
        if not MIN_AIR_C < self.default_temperature_c < MAX_AIR_C:
            raise ConfigError("default_temperature_c must be a plausible air temperature")
