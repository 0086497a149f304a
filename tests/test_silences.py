"""Silences cut into a copy of a recording: one pass equals one copy per silence."""

from __future__ import annotations

from pathlib import Path

import pytest

from baromap.evaluation.silences import Silence, silenced, without
from baromap.recording import read_messages
from baromap.sim.record import record_run


def test_silences_in_one_pass_are_the_copies_one_after_another(tmp_path: Path) -> None:
    """The odometry power-cycled (joined, then zeroed) and the laser silent: one pass writes
    the file that three copies made one from the other write, to the byte."""
    run = tmp_path / "run.mcap"
    record_run(run, seed=1, floors=2, minutes=1.0, progress=False)
    cuts = [
        Silence("/odom", 10, 15, counters="joined"),
        Silence("/scan", 12, 20),
        Silence("/odom", 30, 31, counters="zeroed"),
    ]
    step = run
    one_by_one = []
    for k, cut in enumerate(cuts):
        copy = tmp_path / f"copy{k}.mcap"
        one_by_one.append(
            without(step, copy, cut.topic, cut.start_s, cut.end_s, counters=cut.counters)
        )
        step = copy
    assert silenced(run, tmp_path / "once.mcap", cuts) == one_by_one
    assert min(one_by_one) > 0
    assert (tmp_path / "once.mcap").read_bytes() == step.read_bytes()
    # the base counts from zero after the zeroed cut
    records = list(read_messages(step, ["/odom"]))
    first = records[0].log_time_ns
    (after,) = [r.message for r in records if r.log_time_ns - first >= 31e9][:1]
    assert (after.x_m, after.y_m, after.theta_rad) == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)


def test_a_silence_with_counters_is_odometry_only() -> None:
    with pytest.raises(ValueError, match="only /odom has counters"):
        Silence("/scan", 1, 2, counters="zeroed")
    with pytest.raises(ValueError, match="counters must be one of"):
        Silence("/odom", 1, 2, counters="reset")
