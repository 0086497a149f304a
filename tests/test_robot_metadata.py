"""The robot model travels with a recording, and re-integrating the counters honours it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from baromap.errors import ConfigError, InputFormatError
from baromap.messages import Odometry
from baromap.odometry.robot_metadata import (
    ROBOT_METADATA,
    model_from_metadata,
    reintegrate,
    robot_metadata,
)
from baromap.protocols.robot_models import P3AT, P3AT_SH
from baromap.recording import read_messages, read_metadata
from baromap.sim.record import record_run


def test_the_record_names_model_source_and_what_the_robot_reported() -> None:
    record = robot_metadata(P3AT_SH, ("Robin", "Pioneer", "p3at-sh"), "reported")
    assert record["model"] == "p3at-sh" and record["reported_subclass"] == "p3at-sh"
    assert float(record["dist_conv_factor"]) == 1.0
    assert model_from_metadata({ROBOT_METADATA: record}) == P3AT_SH
    with pytest.raises(ConfigError):
        robot_metadata(P3AT_SH, None, "guessed")


def test_recorded_factors_win_and_bad_records_are_input_errors() -> None:
    record = robot_metadata(P3AT, None, "override") | {"dist_conv_factor": "0.5"}
    assert model_from_metadata({ROBOT_METADATA: record}).dist_conv_factor == 0.5
    assert model_from_metadata({}) is None
    with pytest.raises(InputFormatError, match="p9"):
        model_from_metadata({ROBOT_METADATA: {"model": "p9"}})
    with pytest.raises(InputFormatError, match="dist_conv_factor"):
        model_from_metadata({ROBOT_METADATA: {"model": "p3at", "dist_conv_factor": "x"}})


@pytest.mark.slow
def test_a_recordings_counters_turn_into_its_own_metres_again(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    record_run(path, seed=1, floors=2, minutes=2.0, progress=False)
    odom = [r.message for r in read_messages(path, ["/odom"]) if isinstance(r.message, Odometry)]
    model = model_from_metadata(read_metadata(path))
    assert model == P3AT_SH  # the recorder's default base, today's ARCOS P3-AT
    again = reintegrate(odom, model)
    np.testing.assert_allclose([(o.x_m, o.y_m) for o in again], [(o.x_m, o.y_m) for o in odom])
    # The same counters read with the other generation's factor: every distance scaled.
    other = P3AT
    wrong = reintegrate(odom, other)
    ratio = other.dist_conv_factor / model.dist_conv_factor
    assert wrong[-1].x_m == pytest.approx(odom[-1].x_m * ratio, rel=1e-9, abs=1e-9)
    assert abs(odom[-1].x_m) + abs(odom[-1].y_m) > 0.1  # the robot did move
