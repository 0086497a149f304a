"""Floors: hypsometric heights, Holt smoothing, configuration."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from baromap.errors import ConfigError
from baromap.floors.config import FloorDetectorConfig
from baromap.floors.height import (
    AtmosphereError,
    height_difference_m,
    pa_per_m,
    pressure_drop_pa,
    scale_height_m,
)
from baromap.floors.smoothing import DoubleExponentialSmoother, double_exponential_smoothing


def test_scale_height_and_gradient_match_textbook_values() -> None:
    assert scale_height_m(15.0) == pytest.approx(8434.5, abs=1.0)
    # About 12 Pa per metre at sea level, 11.6 at the IPIN museum's 977 hPa.
    assert pa_per_m(101325.0, 15.0) == pytest.approx(12.01, abs=0.02)
    assert pa_per_m(97700.0, 15.0) == pytest.approx(11.58, abs=0.02)


def test_warmer_air_makes_the_same_step_taller() -> None:
    cold = height_difference_m(97700.0, 97660.0, 0.0)
    warm = height_difference_m(97700.0, 97660.0, 30.0)
    assert warm / cold == pytest.approx(303.15 / 273.15, rel=1e-9)
    assert height_difference_m(97660.0, 97700.0, 20.0) < 0  # more pressure = lower


@given(
    st.floats(50_000.0, 110_000.0),
    st.floats(-50.0, 300.0),
    st.floats(-30.0, 45.0),
)
def test_pressure_drop_inverts_height_difference(p: float, h: float, temp: float) -> None:
    drop = pressure_drop_pa(h, p, temp)
    assert height_difference_m(p, p - drop, temp) == pytest.approx(h, abs=1e-6)


def test_height_rejects_impossible_inputs() -> None:
    with pytest.raises(AtmosphereError):
        height_difference_m(0.0, 1000.0)
    with pytest.raises(AtmosphereError):
        scale_height_m(-300.0)


@settings(deadline=None)  # the first call imports scipy.signal
@given(
    st.lists(st.floats(-1e4, 1e4, allow_nan=False), min_size=1, max_size=200),
    st.floats(0.01, 1.0),
    st.floats(0.01, 1.0),
)
def test_streaming_smoother_equals_batch(values: list[float], alpha: float, gamma: float) -> None:
    level, trend = double_exponential_smoothing(values, alpha, gamma)
    smoother = DoubleExponentialSmoother(alpha, gamma)
    streamed = np.array([smoother.update(v) for v in values])
    np.testing.assert_allclose(streamed[:, 0], level, rtol=1e-9, atol=1e-6)
    # The batch trend knows b_1 = y_2 - y_1 from the start; a stream learns it one sample on.
    np.testing.assert_allclose(streamed[1:, 1], trend[1:], rtol=1e-9, atol=1e-6)


def test_smoother_follows_a_ramp_without_lag() -> None:
    y = 100.0 + 0.5 * np.arange(400)
    level, trend = double_exponential_smoothing(y, 0.1, 0.1)
    assert level[-1] == pytest.approx(y[-1], abs=1e-6)
    assert trend[-1] == pytest.approx(0.5, abs=1e-9)


@pytest.mark.parametrize(
    "changes",
    [
        {"min_transition_m": 0.0},
        {"min_transition_m": math.nan},
        {"settle_s": -1.0},
        {"start_m": 2.0},
        {"settle_rate_m_s": 0.5},
        {"paper_alpha": 1.5},
        {"default_temperature_c": 500.0},
        {"landing_s": -3.0},
    ],
)
def test_config_rejects_nonsense(changes: dict[str, float]) -> None:
    with pytest.raises(ConfigError):
        FloorDetectorConfig(**changes)


@pytest.mark.parametrize(("alpha", "gamma"), [(0.0, 0.5), (0.5, 1.5), (math.nan, 0.5)])
def test_smoother_rejects_constants_outside_0_1(alpha: float, gamma: float) -> None:
    with pytest.raises(ConfigError):
        DoubleExponentialSmoother(alpha, gamma)


def test_floor_heights_from_steps_leave_out_floors_no_step_reaches() -> None:
    from baromap.floors.elevation import Step, solve_levels

    # 0 -> 1 measured twice (3.1 and 3.3 m), 2 <-> 3 measured but never joined to 0 or 1.
    steps = [Step(0, 1, -36.0, 3.1), Step(1, 0, 38.0, -3.3), Step(2, 3, -40.0, 3.5)]
    heights = solve_levels(steps, 4, "height_m")
    assert heights[1] - heights[0] == pytest.approx(3.2)
    assert np.isnan(heights[2]) and np.isnan(heights[3])
