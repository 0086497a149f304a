import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from baromap.messages import BeamFlag, LaserScan, PressureSample, wrap_angle


def make_scan(ranges: list[float], flags: list[int]) -> LaserScan:
    return LaserScan(
        t_ns=1,
        angle_min_rad=-math.pi / 2,
        angle_increment_rad=math.radians(1),
        range_max_m=8.19,
        ranges_m=np.array(ranges),
        flags=np.array(flags),
    )


def test_scan_arrays_are_read_only_copies() -> None:
    source = np.array([1.0, 2.0])
    scan = make_scan(source.tolist(), [0, 0])
    source[0] = 5.0
    assert scan.ranges_m[0] == 1.0
    with pytest.raises(ValueError):
        scan.ranges_m[0] = 3.0
    assert scan.ranges_m.dtype == np.float32
    assert scan.flags.dtype == np.uint16


def test_scan_equality_treats_nan_as_equal_and_validity_uses_flags() -> None:
    a = make_scan([1.0, float("nan"), 3.0], [0, int(BeamFlag.DAZZLE), int(BeamFlag.RAW_BIT13)])
    b = make_scan([1.0, float("nan"), 3.0], [0, int(BeamFlag.DAZZLE), int(BeamFlag.RAW_BIT13)])
    assert a == b
    assert a.valid().tolist() == [True, False, True]
    assert a.angle_max_rad == pytest.approx(-math.pi / 2 + 2 * math.radians(1))


def test_scan_rejects_mismatched_arrays() -> None:
    with pytest.raises(ValueError):
        make_scan([1.0, 2.0], [0])


def test_messages_are_frozen() -> None:
    sample = PressureSample(t_ns=1, pressure_pa=101325.0)
    with pytest.raises(AttributeError):
        sample.pressure_pa = 1.0  # type: ignore[misc]


@given(st.floats(min_value=-1e6, max_value=1e6))
def test_wrap_angle_range(theta: float) -> None:
    wrapped = wrap_angle(theta)
    assert -math.pi < wrapped <= math.pi
    assert math.isclose(math.cos(wrapped), math.cos(theta), abs_tol=1e-6)
