"""CSV pressure logs and ``baromap import csv``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from baromap.cli.main import main
from baromap.errors import InputFormatError
from baromap.recording.csv_pressure import parse_csv_pressure


def test_header_comments_and_bad_rows() -> None:
    series = parse_csv_pressure(
        [
            "time_s,pressure_pa,temperature_c\n",
            "# bench log\n",
            "0.0,97000.5,21.5\n",
            "0.1,97001.0\n",
            "oops\n",
            "0.2;97001.5;21.7\n",
            "0.1,97009.0,21.0\n",
        ]
    )
    assert series.t_ns.tolist() == [0, 100_000_000, 200_000_000]
    assert series.pressure_pa.tolist() == [97000.5, 97001.0, 97001.5]
    assert np.isnan(series.temperature_c[1]) and series.temperature_c[2] == 21.7


@pytest.mark.parametrize(
    "rows",
    [
        ["0,970.0\n"],  # hPa
        ["t,p\n"],
        [],
        ["0,97000,293.1\n"],  # kelvin
        ["0,97000,-500\n"],  # below absolute zero
        ["1e12,97000\n"],  # not seconds (and beyond int64 nanoseconds)
    ],
)
def test_wrong_units_or_empty_are_refused(rows: list[str]) -> None:
    with pytest.raises(InputFormatError):
        parse_csv_pressure(rows)


@pytest.mark.parametrize("argv", [["import", "csv", "{missing}"], ["detect", "{missing}"]])
def test_missing_file_is_one_line_not_a_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str]
) -> None:
    missing = tmp_path / "missing.csv"
    args = [a.format(missing=missing) for a in argv] + (
        ["-o", str(tmp_path / "x.mcap")] if argv[0] == "import" else []
    )
    assert main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"baromap: error: cannot read {missing}: [Errno 2] No such file or directory: '{missing}'"
    ]


def test_import_then_detect(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rate = 10
    z = np.concatenate([np.zeros(600), np.linspace(0, 3.5, 40), np.full(600, 3.5)])
    t = np.arange(z.size) / rate + 1_700_000_000.0
    p = 97_700.0 * np.exp(-z / 8434.5) + np.random.default_rng(1).normal(0, 0.2, z.size)
    csv = tmp_path / "run.csv"
    csv.write_text(
        "time_s,pressure_pa,temperature_c\n"
        + "".join(f"{a:.2f},{b:.2f},20.0\n" for a, b in zip(t, p, strict=True))
    )
    mcap = tmp_path / "run.mcap"
    assert main(["import", "csv", str(csv), "-o", str(mcap)]) == 0
    assert "1240 pressure samples" in capsys.readouterr().out
    assert main(["detect", str(mcap), "--json"]) == 0
    import json

    document = json.loads(capsys.readouterr().out)
    assert [(x["from"], x["to"]) for x in document["transitions"]] == [(0, 1)]
    assert document["floors"][1]["elevation_m"] == pytest.approx(3.5, abs=0.15)
    assert main(["detect", str(csv)]) == 0
    assert "floor 0 -> 1" in capsys.readouterr().out
