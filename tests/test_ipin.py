"""IPIN (GetSensorData) log reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from baromap.errors import InputFormatError
from baromap.recording.ipin import looks_like_ipin, parse_ipin, read_ipin

SAMPLE = """% LogFile created by the 'GetSensorData' App for Android.
% Model:                   	SM-G930F
ACCE;0.01;100.0;0.1;0.2;9.8;3
PRES;0.10;100.00;976.8699;3
PRES;0.20;100.10;976.8628;3
PRES;garbage
PRES;0.30;100.20;5.0;3
POSI;0.25;1;49.46;11.11;0;100
PRES;0.40;100.30;976.8557;3
POSI;0.35;2;49.46;11.11;-1;100
"""


def test_parse_pressure_waypoints_and_phone() -> None:
    log = parse_ipin(SAMPLE.splitlines())
    assert log.phone == "SM-G930F"
    assert log.pressure_pa.tolist() == pytest.approx([97686.99, 97686.28, 97685.57])
    # Sensor-clock spacing on the app clock (median offset 0.1 - 100.0).
    assert (log.t_ns / 1e9).tolist() == pytest.approx([0.1, 0.2, 0.4])
    assert [(w.index, w.floor) for w in log.waypoints] == [(1, 0), (2, -1)]
    assert log.skipped["bad PRES"] == 2


def test_garbage_numbers_are_skipped_not_raised() -> None:
    lines = [
        *SAMPLE.splitlines(),
        "POSI;0.5;3;49.46;11.11;inf;100",  # int(inf) overflows
        "POSI;nan;4;49.46;11.11;0;100",
        "POSI;1e300;5;49.46;11.11;0;100",  # beyond int64 nanoseconds
        "PRES;1e300;100.4;976.8;3",
        "PRES;0.5;inf;976.8;3",
    ]
    log = parse_ipin(lines)
    assert [w.index for w in log.waypoints] == [1, 2]
    assert log.skipped["bad POSI"] == 3
    assert log.skipped["bad PRES"] == 4
    assert log.pressure_pa.size == 3


def test_missing_file_is_an_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputFormatError, match="cannot read"):
        read_ipin(tmp_path / "missing.txt")


def test_not_ipin() -> None:
    assert not looks_like_ipin("time_s,pressure_pa\n0,97000\n")
    with pytest.raises(InputFormatError, match="no PRES lines"):
        parse_ipin(["% nothing\n", "ACCE;1;2;3;4;5;6\n"])


def test_a_log_whose_every_pressure_is_unusable_says_so() -> None:
    """PRES lines all reading 0 hPa (a sensor that never started): the error names them
    instead of calling the file something else than an IPIN log."""
    with pytest.raises(InputFormatError, match="no usable PRES line: 2 unreadable or outside"):
        parse_ipin(["PRES;0.1;1.0;0.0;3\n", "PRES;0.2;1.1;0.0;3\n"])


def test_real_logs(shared_data: Path) -> None:
    """Invariants of what the reader makes of the real logs, not their exact counts."""
    paths = sorted((shared_data / "baro").glob("*.txt"))
    assert paths, "no IPIN logs in the shared data: the loop below would check nothing"
    for path in paths:
        log = read_ipin(path)
        seconds = np.diff(log.t_ns) / 1e9
        assert np.all(seconds > 0)  # strictly increasing times
        assert 0.05 < np.median(seconds) < 0.25  # a phone barometer: a few to 20 Hz
        assert 97_000 < log.pressure_pa.min() <= log.pressure_pa.max() < 98_500  # in Pa, not hPa
        # a walk through the museum's three floors: floors 0, -1, -2 and nothing else
        assert {w.floor for w in log.waypoints} <= {0, -1, -2}
        assert [w.index for w in log.waypoints] == sorted(w.index for w in log.waypoints)
