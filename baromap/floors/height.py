"""Pressure differences to heights: the hypsometric equation.

Between two levels in an air column of mean temperature T, ``z2 - z1 = (R_d T / g) ln(p1 / p2)``
(dry air; water vapour would raise T by a fraction of a kelvin, a 0.1 % effect). Near sea level
that is about 8.4 m per percent of pressure, i.e. roughly 12 Pa per metre; at 15 C and
977 hPa one metre is 11.5 Pa. The temperature matters: 10 K make 3.5 % in height, so the
measured temperature is used when the barometer reports one.
"""

from __future__ import annotations

import math

from baromap.errors import BaromapError

#: Specific gas constant of dry air [J/(kg K)].
R_DRY_AIR = 287.05
#: Standard gravity [m/s^2].
G0 = 9.80665
ZERO_CELSIUS_K = 273.15
#: Temperature assumed when the input has none: the ISA sea-level value, 15 C.
STANDARD_TEMPERATURE_C = 15.0


class AtmosphereError(BaromapError):
    """A pressure or temperature no air can have: a caller passed a glitch on unchecked."""


def scale_height_m(temperature_c: float = STANDARD_TEMPERATURE_C) -> float:
    """``R_d T / g``: the height over which pressure falls by a factor e (about 8.4 km)."""
    kelvin = temperature_c + ZERO_CELSIUS_K
    if not kelvin > 0.0:
        raise AtmosphereError(f"temperature {temperature_c} C is below absolute zero")
    return R_DRY_AIR * kelvin / G0


def height_difference_m(
    p_from_pa: float, p_to_pa: float, temperature_c: float = STANDARD_TEMPERATURE_C
) -> float:
    """Height gained going from pressure ``p_from_pa`` to ``p_to_pa`` (positive going up)."""
    if p_from_pa <= 0.0 or p_to_pa <= 0.0:
        raise AtmosphereError(f"pressures must be positive, not {p_from_pa} and {p_to_pa}")
    return scale_height_m(temperature_c) * math.log(p_from_pa / p_to_pa)


def pressure_drop_pa(
    height_m: float, pressure_pa: float, temperature_c: float = STANDARD_TEMPERATURE_C
) -> float:
    """By how much pressure falls when climbing ``height_m`` from ``pressure_pa``."""
    return pressure_pa * -math.expm1(-height_m / scale_height_m(temperature_c))


def pa_per_m(pressure_pa: float, temperature_c: float = STANDARD_TEMPERATURE_C) -> float:
    """Local vertical pressure gradient magnitude (Pa per metre) for small displacements."""
    return pressure_pa / scale_height_m(temperature_c)
