"""``baromap detect``: odometry fusion, floor names, and inputs that are not what they say."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from baromap.cli.main import main
from baromap.evaluation.floor_traces import Stay, Trace, trace
from baromap.messages import Odometry, PressureSample
from baromap.recording import RecordingWriter
from baromap.recording import topics as t

STOREY_M = 3.4


def write_recording(path: Path, tr: Trace, *, odometry: bool = True) -> None:
    messages: list[tuple[int, str, PressureSample | Odometry]] = [
        (int(ti), t.BARO, PressureSample(int(ti), float(pi), 20.0))
        for ti, pi in zip(tr.t_ns, tr.pressure_pa, strict=True)
    ]
    if odometry:
        odo_t, x, y = tr.odometry
        messages += [
            (int(ti), t.ODOM, Odometry(int(ti), float(xi), float(yi), 0.0))
            for ti, xi, yi in zip(odo_t, x, y, strict=True)
        ]
    messages.sort(key=lambda m: m[0])
    with RecordingWriter(path, robot="test") as writer:
        for _, topic, message in messages:
            writer.write(message, topic=topic)


def stop_in_the_car() -> Trace:
    """Up one storey, 30 s there without leaving the car, then on up another storey."""
    return trace(
        [Stay(0.0, 60), Stay(STOREY_M, 30.0), Stay(2 * STOREY_M, 60, drive_m=3.0)],
        temperature_c=20.0,
    )


def detect_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, object]:
    capsys.readouterr()  # the recording's own log lines
    assert main(["detect", *argv, "--json"]) == 0
    document: dict[str, object] = json.loads(capsys.readouterr().out)
    return document


def hops(document: dict[str, object]) -> list[tuple[int, int]]:
    return [(x["from"], x["to"]) for x in document["transitions"]]  # type: ignore[attr-defined, index]


def test_a_recordings_own_odometry_keeps_a_stop_in_the_car_part_of_the_ride(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run.mcap"
    write_recording(run, stop_in_the_car())
    assert hops(detect_json(capsys, str(run))) == [(0, 1)]
    # Without odometry, 30 s at a storey is a visit.
    assert hops(detect_json(capsys, str(run), "--no-odom")) == [(0, 1), (1, 2)]


def test_odometry_from_another_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tr = stop_in_the_car()
    pressure, odometry = tmp_path / "baro.mcap", tmp_path / "odom.mcap"
    write_recording(pressure, tr, odometry=False)
    write_recording(odometry, tr)
    assert hops(detect_json(capsys, str(pressure))) == [(0, 1), (1, 2)]
    assert hops(detect_json(capsys, str(pressure), "--odom", str(odometry))) == [(0, 1)]
    capsys.readouterr()
    assert main(["detect", str(pressure), "--odom", str(pressure)]) == 1
    assert "no /odom messages" in capsys.readouterr().err


def test_start_floor_and_building_model_name_the_floors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "run.mcap"
    write_recording(run, stop_in_the_car())
    document = detect_json(capsys, str(run), "--no-odom", "--start-floor", "5")
    names = {f["index"]: f["name"] for f in document["floors"]}  # type: ignore[attr-defined]
    assert names == {0: "5", 1: "6", 2: "7"}
    building = tmp_path / "building.yaml"
    building.write_text(
        "floors:\n  - {index: 0, elevation_m: 0.0, name: lobby}\n"
        "  - {index: 1, elevation_m: 3.5, name: first}\n"
        "  - {index: 2, elevation_m: 6.9, name: second}\n"
    )
    capsys.readouterr()
    assert main(["detect", str(run), "--building", str(building), "--start-floor", "lobby"]) == 0
    out = capsys.readouterr().out
    assert "floor lobby -> second" in out and "with odometry" in out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--building", "{building}"], "start_floor '0' is not a floor of the building model"),
        (["--building", "{missing}", "--start-floor", "G"], "cannot read"),
        (["--odom", "{run}", "--no-odom"], "contradict"),
    ],
)
def test_bad_naming_arguments_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    run = tmp_path / "run.mcap"
    write_recording(run, stop_in_the_car())
    building = tmp_path / "building.yaml"
    building.write_text("floors:\n  - {index: 0, elevation_m: 0.0, name: G}\n")
    paths = {"building": building, "missing": tmp_path / "missing.yaml", "run": run}
    capsys.readouterr()
    assert main(["detect", str(run), *[a.format(**paths) for a in argv]]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_a_file_named_mcap_that_is_not_mcap_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fake = tmp_path / "run.mcap"
    fake.write_text("time_s,pressure_pa\n0,97000\n")
    assert main(["detect", str(fake)]) == 1
    err = capsys.readouterr().err.strip()
    assert "is named .mcap but is not an MCAP recording" in err
