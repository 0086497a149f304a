"""What a BMP280 makes of the air around it.

Bosch's "indoor navigation" setting is modelled: pressure oversampling x16, the chip's IIR
filter with coefficient 16 (which is why a step takes about 22 samples to reach 75 %), output
noise about 0.2 Pa RMS (1.6 cm), 20-bit resolution (0.16 Pa), an absolute offset of the order
of the datasheet's +-1 hPa that differs per chip, and the 1.5 Pa/K temperature coefficient of
the offset. The die temperature follows the air slowly and sits above it (the board warms
it); it is reported in 0.01 degC steps.

The model is stateful and takes samples in chunks of any length, so one recording is
processed in one call and a real-time twin calls it once per sample with the same result.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray

PRESSURE_LSB_PA = 0.16
TEMPERATURE_LSB_C = 0.01
IIR_COEFFICIENT = 16
#: Raw noise before the IIR filter; after it the output is about 0.19 Pa RMS.
RAW_NOISE_PA = 1.05
TEMPERATURE_COEFF_PA_PER_K = 1.5
#: Where the offset's temperature dependence is zero (the datasheet's reference point).
REFERENCE_TEMPERATURE_C = 25.0


@dataclass(slots=True)
class Bmp280:
    """One sensor: its own offset, self-heating and noise stream."""

    rng: np.random.Generator
    rate_hz: float
    offset_pa: float
    self_heating_c: float
    thermal_tau_s: float = 90.0
    raw_noise_pa: float = RAW_NOISE_PA
    _iir: float | None = field(default=None, init=False)
    _die_c: float | None = field(default=None, init=False)

    @classmethod
    def random(cls, rng: np.random.Generator, rate_hz: float, heated: bool = True) -> Bmp280:
        return cls(
            rng=rng,
            rate_hz=rate_hz,
            offset_pa=float(np.clip(rng.normal(0.0, 50.0), -100.0, 100.0)),
            self_heating_c=float(rng.uniform(0.8, 2.0)) if heated else 0.3,
        )

    def measure(
        self, pressure_pa: npt.ArrayLike, air_c: npt.ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Readings (Pa, degC) for consecutive samples of the true pressure and air temperature."""
        # scipy.signal here, not at the top: it pulls in scipy.stats, a second of CPU that every
        # process importing the twins (the daemon's tests, `baromap sim`) would pay at start.
        from scipy.signal import lfilter

        p = np.atleast_1d(np.asarray(pressure_pa, dtype=np.float64))
        air = np.broadcast_to(np.asarray(air_c, dtype=np.float64), p.shape)
        # The die temperature: first-order lag towards air + self-heating.
        target = air + self.self_heating_c
        alpha = 1.0 - np.exp(-1.0 / (self.rate_hz * self.thermal_tau_s))
        if self._die_c is None:
            self._die_c = float(target[0])
        die, zf = lfilter([alpha], [1.0, alpha - 1.0], target, zi=[(1.0 - alpha) * self._die_c])
        self._die_c = float(die[-1])
        # The ADC sees the pressure plus offset, temperature error and noise.
        adc = (
            p
            + self.offset_pa
            + TEMPERATURE_COEFF_PA_PER_K * (die - REFERENCE_TEMPERATURE_C)
            + self.rng.normal(0.0, self.raw_noise_pa, p.shape)
        )
        # The chip's IIR filter: x = (x_prev * (c - 1) + adc) / c, seeded by the first value.
        c = IIR_COEFFICIENT
        if self._iir is None:
            self._iir = float(adc[0])
        filtered, _ = lfilter([1.0 / c], [1.0, -(c - 1) / c], adc, zi=[(c - 1) / c * self._iir])
        self._iir = float(filtered[-1])
        del zf
        pressure = np.round(filtered / PRESSURE_LSB_PA) * PRESSURE_LSB_PA
        temperature = np.round(die / TEMPERATURE_LSB_C) * TEMPERATURE_LSB_C
        return pressure, temperature
