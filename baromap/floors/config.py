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
- ``stop_s = 1.5``, ``stop_band_m = 1.0``, ``stop_rate_m_s = 0.4``: when the robot rode a
  change standing in a car (odometry), the car's stop is decided on this looser test: the
  smoothed pressure within a metre of itself and the slope of the raw pressure under 0.4 m/s
  for a second and a half, after a ride no faster than a car can make it (from rest to rest
  with at most 1.5 m/s² of acceleration: two spikes in a row rise as far in a second). It
  leaves room for what follows a car's stop with no vertical motion at all: the doors' seal
  (a car is kept a few pascals above its shaft while closed) letting go as they open, the
  barometer's own filter catching up (a BMP280 set for indoor navigation lags about 0.6 s,
  0.6 m at 1 m/s), a ventilation spike fading; elevators ride at 0.5 m/s or faster, above the
  slope. The still test above still decides every change that is no car ride. A pause of the
  pressure mid-ride (a spike's decay cancelling the car's motion for a second) can pass this
  test, and the car going on corrects it: a shorter or looser window decides sooner and is
  fooled more often. These three values were chosen on the simulator
  (``bench/floors_live.py``, docs/floors.md), not from physics alone.
- ``ride_m = 0.5``: a ride is announced once the pressure moved half a metre from the floor's
  level with the smoothed rate the same way (as a change begins at ``start_m``); a car's
  piston effect and the sensor's filter delay it by a second or so after the car starts.
- ``level_tau_s = 0.5`` / ``trend_tau_s = 1.5``: the smoothers' time constants. The level
  constant smooths the pressure the settle band is judged on (and the Holt level); the trend
  constant only sets how fast the Holt rate that starts a change reacts. A shorter trend
  constant makes that rate noisy on a hand-held phone.
- ``drift_tau_s = 60``: while the robot stays on a floor, slow changes are weather (up to
  ~3 hPa/h, i.e. 0.08 Pa/s) and the floor's level follows them with this time constant (a
  critically damped tracker: level and drift rate, both from this one constant).
- ``landing_s = 15``: a stop shorter than this between two legs of vertical motion in the same
  direction (a stair landing) is part of one trip, which is then dated from its first leg; if
  a visit was decided on such a stop (only possible with ``min_visit_s`` below ``landing_s``)
  and the trip goes on, the decision is corrected to where the trip ended.
- ``min_visit_s = 15``: without odometry, a stop at a storey's height between two legs in the
  same direction is a visit only once it lasted this long; until then it is "stopped at a level
  during a ride". An elevator stopping at a passing floor stands still for its door cycle:
  opening (2-3 s), open for at least 3 s (the minimum dwell that accessibility codes such as
  ADA 407.3.4 require, longer for hall calls), closing (3-4 s), about 8-12 s in all; 15 s
  covers that with a margin, as ``landing_s`` covers a stair landing. A stop followed by a leg
  the other way is a visit whatever its length (it was where the trip went).
- ``leave_m = 1.0``: an elevator car is 1.4-2.1 m deep and a P3-AT 0.63 m long, so about a
  metre of travel is where staying in the car ends. With odometry, a robot that moved less
  than this during a change rode it in a car, and its stop is decided as the car stops; one
  that moved more (a ramp) is at a stop that becomes a visit once the robot moved this far
  from where it stood when the pressure came to rest, and never before.
- ``start_floor = "0"``: the start floor's name (the paper starts on floor 5). With a
  ``building`` model (:mod:`baromap.floors.building_model`) it must be one of its floors, and
  floors are named after the model floor at their measured height; without one, names are
  counted in storeys (:mod:`baromap.floors.names`) of ``storey_m = 3.5`` (floor to floor in
  offices and public buildings, 2.7-3 m in housing) or of the smallest spacing between the
  floors seen, whichever is less, from the nearest named floor.
- The paper's constants (``paper_alpha``, ``paper_gamma``, ``paper_sigmas``) are per sample, as
  the paper states them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from baromap.errors import ConfigError
from baromap.floors.building_model import BuildingModel
from baromap.floors.height import STANDARD_TEMPERATURE_C

#: Air temperatures a barometer can plausibly report; outside them a reading is a glitch.
MIN_AIR_C, MAX_AIR_C = -80.0, 80.0


#: Settings that must be finite positive numbers.
_POSITIVE = (
    "min_transition_m",
    "start_m",
    "start_rate_m_s",
    "settle_rate_m_s",
    "settle_s",
    "level_tau_s",
    "trend_tau_s",
    "drift_tau_s",
    "reference_tau_s",
    "max_gap_s",
    "paper_sigmas",
    "leave_m",
    "storey_m",
    "stop_s",
    "stop_band_m",
    "stop_rate_m_s",
    "ride_m",
)
#: Settings that must be finite numbers of at least zero.
_NOT_NEGATIVE = ("landing_s", "min_visit_s")


@dataclass(frozen=True, slots=True)
class FloorDetectorConfig:
    """Floor-detection settings (see the module docstring for the reasons behind defaults).

    Invalid values raise :class:`~baromap.errors.ConfigError` naming the field.
    """

    # What is a floor change (m), and when one begins (m, m/s) and ends (m/s over s).
    min_transition_m: float = 1.8
    start_m: float = 0.5
    start_rate_m_s: float = 0.15
    settle_rate_m_s: float = 0.1
    settle_s: float = 1.5

    # Time constants (s) of the smoothers.
    level_tau_s: float = 0.5  # the level (and the Holt level)
    trend_tau_s: float = 1.5  # the Holt rate that starts a change
    drift_tau_s: float = 60.0  # the weather, while on a floor
    reference_tau_s: float = 10.0  # a reference station's pressure

    # A car's stop with the robot in it (s, m, m/s), and when a ride is announced (m).
    stop_s: float = 1.5
    stop_band_m: float = 1.0
    stop_rate_m_s: float = 0.4
    ride_m: float = 0.5

    # Trips, stops and visits (s, m); a gap in the data longer than max_gap_s ends a trip.
    landing_s: float = 15.0
    min_visit_s: float = 15.0
    leave_m: float = 1.0
    max_gap_s: float = 10.0

    # Names: of the start floor, and how the others are found.
    start_floor: str = "0"
    storey_m: float = 3.5
    building: BuildingModel | None = None

    # Air temperature when the sensor gives none.
    default_temperature_c: float = STANDARD_TEMPERATURE_C
    # The paper's method: its smoothing constants (per sample) and threshold (sigmas).
    paper_alpha: float = 0.1
    paper_gamma: float = 0.1
    paper_sigmas: float = 2.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("start_floor", "building"):
                continue
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not math.isfinite(value)
            ):
                raise ConfigError(f"{f.name} must be a finite number, not {value!r}")
        for name in _POSITIVE:
            if getattr(self, name) <= 0:
                raise ConfigError(f"{name} must be positive, not {getattr(self, name)}")
        for name in _NOT_NEGATIVE:
            if getattr(self, name) < 0:
                raise ConfigError(f"{name} must not be negative, not {getattr(self, name)}")
        if self.start_m >= self.min_transition_m:
            raise ConfigError("start_m must be below min_transition_m, or no change could start")
        if self.settle_rate_m_s > self.start_rate_m_s:
            raise ConfigError("settle_rate_m_s must not exceed start_rate_m_s")
        if self.ride_m >= self.min_transition_m:
            raise ConfigError("ride_m must be below min_transition_m, or no ride is announced")
        for name in ("paper_alpha", "paper_gamma"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ConfigError(f"{name} must be in (0, 1], not {getattr(self, name)}")
        if not MIN_AIR_C < self.default_temperature_c < MAX_AIR_C:
            raise ConfigError("default_temperature_c must be a plausible air temperature")
        self._check_names()

    def _check_names(self) -> None:
        if not isinstance(self.start_floor, str) or not self.start_floor.strip():
            raise ConfigError(f"start_floor must be a floor name, not {self.start_floor!r}")
        model = self.building
        if model is None:
            return
        if not isinstance(model, BuildingModel):
            raise ConfigError(f"building must be a BuildingModel, not {type(model).__name__}")
        if model.elevation_of(self.start_floor) is None:
            names = ", ".join(f.name for f in model.floors)
            raise ConfigError(
                f"start_floor {self.start_floor!r} is not a floor of the building model ({names})"
            )
        if model.closest_gap_m() < self.min_transition_m:
            raise ConfigError(
                f"building: two floors {model.closest_gap_m():.2f} m apart, closer than "
                f"min_transition_m ({self.min_transition_m} m): they cannot both be floors"
            )
