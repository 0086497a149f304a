"""The mapping gate's log variants: what each writes, read back by the importer's parser."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from baromap.errors import ConfigError
from baromap.evaluation.log_variants import (
    ODOMETRY,
    OdometryErrors,
    Variant,
    degrade,
    make_variant,
    read_source,
)
from baromap.mapping import se2
from baromap.recording.carmen import parse_lines


def _source(tmp_path: Path, n: int = 60, stamp: str | None = None) -> Path:
    """A log of ``n`` scans a metre apart along a gentle curve, two seconds apart."""
    lines = []
    pose = np.zeros(3)
    for k in range(n):
        t = stamp or f"{1000 + 2 * k:.6f}"
        p = " ".join(f"{v:.6f}" for v in pose)
        lines.append(f"FLASER 3 1.0 2.0 3.0 {p} {p} {t} host {t}")
        pose = se2.compose(pose, np.array([1.0, 0.0, 0.05]))
    path = tmp_path / "src.log"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_degrade_makes_the_models_errors() -> None:
    """No error at all gives the reference back; the default reads 5 % long and creeps."""
    ref = np.array([[k * 1.0, 0.0, 0.0] for k in range(200)])
    exact = OdometryErrors(scale=0.0, creep_deg_per_m=0.0, noise=0.0)
    assert np.allclose(degrade(ref, 0, exact), ref)
    odom = degrade(ref, 0, ODOMETRY["default"])
    steps = se2.between(odom[:-1], odom[1:])
    assert np.hypot(steps[:, 0], steps[:, 1]).sum() == pytest.approx(199 * 1.05, rel=0.01)
    assert math.degrees(steps[:, 2].sum()) / 199 == pytest.approx(2.0, abs=0.2)
    assert np.array_equal(odom, degrade(ref, 0, ODOMETRY["default"]))
    assert not np.array_equal(odom, degrade(ref, 1, ODOMETRY["default"]))
    slips = degrade(ref, 0, ODOMETRY["slip"])
    jumps = np.hypot(*np.diff(slips[:, :2], axis=0).T) - 1.05
    assert (jumps > 0.09).sum() >= 3  # five slips a hundred metres: some in 200 m


def test_odometry_at_the_scan_times_with_pauses(tmp_path: Path) -> None:
    source = read_source(_source(tmp_path))
    made = make_variant(source, Variant(timing="pauses"), 3)
    log = parse_lines(made.lines)
    assert log.stamps is None  # nothing for the importer to repair
    t = log.scan_times_ns()
    assert np.array_equal(t, made.scan_ns)
    assert [o.t_ns for o in log.odometry] == t.tolist()
    gaps = np.diff(t) / 1e9
    assert ((gaps > 3.9) & (gaps < 42.1)).sum() == 10
    assert np.allclose(log.reference_poses(), [(o.x_m, o.y_m, o.theta_rad) for o in log.odometry])


def test_ten_hertz_odometry_a_reset_and_a_robot_standing(tmp_path: Path) -> None:
    source = read_source(_source(tmp_path))
    ten = parse_lines(make_variant(source, Variant(timing="10hz"), 0).lines)
    assert len(ten.odometry) == pytest.approx(59 * 2 * 10, abs=5)
    reset = make_variant(source, Variant(timing="reset"), 0)
    log = parse_lines(reset.lines)
    at = len(reset.reference) // 2
    (restart,) = [o for o in log.odometry if o.t_ns == log.scans[at].t_ns]
    assert (restart.x_m, restart.y_m, restart.theta_rad) == (0.0, 0.0, 0.0)
    assert np.diff(log.scan_times_ns())[at - 1] == pytest.approx(22e9, abs=1e6)
    quiet = make_variant(source, Variant(timing="quiet"), 0)
    log = parse_lines(quiet.lines)
    assert len(log.scans) == 60 + quiet.extra_scans and quiet.extra_scans > 4 * 2 * 18
    odom_t = np.array([o.t_ns for o in log.odometry])
    # no odometry while the robot stands with the laser on
    assert np.diff(odom_t).max() > 20e9


@pytest.mark.parametrize("stamps", ["constant", "zero", "wrap"])
def test_broken_stamps_are_what_the_importer_repairs(tmp_path: Path, stamps: str) -> None:
    made = make_variant(read_source(_source(tmp_path)), Variant(stamps=stamps), 0)
    assert made.scan_ns is None
    log = parse_lines(made.lines)
    assert log.stamps is not None and log.stamps.from_order
    assert len(log.scans) == 60


def test_a_log_broken_as_published_keeps_its_stamps_and_only_that(tmp_path: Path) -> None:
    source = read_source(_source(tmp_path, stamp="1.01893e+09"))
    assert source.times_ns is None
    made = make_variant(source, Variant(stride=2), 0)
    assert all(line.endswith("1.01893e+09 gate 1.01893e+09") for line in made.lines)
    assert len(made.reference) == 30
    with pytest.raises(ConfigError, match="broken"):
        make_variant(source, Variant(timing="pauses"), 0)
