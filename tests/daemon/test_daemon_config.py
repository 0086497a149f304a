"""``baromapd --check-config``: every problem named with its key and a hint, exit 2."""

from __future__ import annotations

from pathlib import Path
from typing import get_args

import pytest

from baromap.protocols import baro, lms200
from baromap.recording.writer import COMPRESSIONS
from baromapd import config as config_module
from baromapd.config import ConfigProblems, Retry, load_config, parse_config
from baromapd.main import main

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "systemd" / "baromapd.toml"


def test_the_example_configuration_is_valid(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The example as shipped, but recording where this machine lets the test write: its
    /var/lib/baromapd is the unit's StateDirectory, writable only by root or under systemd."""
    text = EXAMPLE.read_text(encoding="utf-8")
    shipped = 'directory = "/var/lib/baromapd"'
    assert shipped in text
    example = tmp_path / "baromapd.toml"
    example.write_text(text.replace(shipped, f'directory = "{tmp_path / "runs"}"'))
    assert main(["--check-config", str(example)]) == 0
    out = capsys.readouterr().out
    assert "laser" in out and "base" in out and "barometer" in out


def test_an_unknown_key_and_a_bad_baud_exit_2_naming_both(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(
        'robot = "r1"\n[laser]\nport = "/dev/ttyUSB0"\nbaud = 57600\n'
        '[barometer]\nport = "/dev/ttyACM0"\nrate_hz_typo = 50\n'
    )
    assert main(["--check-config", str(path)]) == 2
    err = capsys.readouterr().err
    assert "laser.baud" in err and "57600" in err
    assert "barometer.rate_hz_typo: unknown key" in err
    assert "known here:" in err  # a hint with each problem


def test_every_problem_is_reported_at_once() -> None:
    with pytest.raises(ConfigProblems) as caught:
        parse_config(
            'role = "boat"\nmystery = 1\n[recording]\nflush_interval_s = 5\n'
            '[laser]\nport = "COM3"\nresolution_deg = 0.25\n'
            '[base]\nport = "/dev/ttyUSB1"\nmodel = "p4at"\n'
            '[barometer]\nport = "/dev/ttyUSB1"\noversampling = 3\n'
            "[floors]\nmin_transition_m = -1\n"
            '[zenoh]\nmode = "radio"\n'
        )
    keys = {p.key for p in caught.value.problems}
    assert keys >= {
        "robot",
        "role",
        "mystery",
        "recording.flush_interval_s",
        "laser.port",
        "laser.resolution_deg",
        "base.model",
        "barometer.port",
        "barometer.oversampling",
        "floors.min_transition_m",
        "zenoh.mode",
    }


def test_values_reach_the_configuration() -> None:
    config = parse_config(
        'robot = "r1"\n[laser]\nport = "0403:6001:AB12"\nbaud = 500000\nunits = "cm"\n'
        "resolution_deg = 0.5\nmount = { x_m = 0.16, yaw_deg = 90 }\n"
        '[base]\nport = "/dev/baromap-base"\nmodel = "P3-AT-SH"\n'
        '[barometer]\nport = "/dev/baromap-baro"\n'
        '[zenoh]\nmode = "peer"\nlisten = ["tcp/127.0.0.1:7448"]\n[reference]\nstation = "roof"\n'
    )
    assert config.laser is not None and config.base is not None
    assert (config.laser.baud, config.laser.units, config.laser.resolution_cdeg) == (
        500000,
        "cm",
        50,
    )
    assert config.laser.mount.x_m == 0.16
    assert config.laser.mount.yaw_rad == pytest.approx(1.5707963)
    assert config.zenoh == {"mode": "peer", "listen": ["tcp/127.0.0.1:7448"]}  # for baromapd.live
    assert config.reference == {"station": "roof"}
    assert config.role == "robot"


def test_a_station_records_a_barometer_only() -> None:
    with pytest.raises(ConfigProblems, match="role"):
        parse_config('robot = "roof"\nrole = "station"\n[laser]\nport = "/dev/ttyUSB0"\n')
    config = parse_config('robot = "roof"\nrole = "station"\n[barometer]\nport = "/dev/ttyACM0"\n')
    assert config.role == "station"


BUILDING = """floors:
  - {index: 0, elevation_m: 0.0, name: basement}
  - {index: 1, elevation_m: 3.6, name: lobby}
  - {index: 2, elevation_m: 7.2, name: lab}
"""


def test_start_floor_and_a_building_model_reach_the_detector(tmp_path: Path) -> None:
    (tmp_path / "site").mkdir()
    (tmp_path / "site" / "building.yaml").write_text(BUILDING)
    path = tmp_path / "baromapd.toml"
    path.write_text(
        'robot = "r1"\n[barometer]\nport = "/dev/ttyACM0"\n'
        '[floors]\nstart_floor = "lobby"\nbuilding = "site/building.yaml"\n'
    )
    floors = load_config(path).floors  # the relative path is the configuration file's
    assert floors.start_floor == "lobby"
    assert floors.building is not None
    assert [f.name for f in floors.building.floors] == ["basement", "lobby", "lab"]
    assert floors.building.elevation_of("lab") == pytest.approx(7.2)
    plain = parse_config('robot = "r1"\n[barometer]\nport = "/dev/ttyACM0"\n').floors
    assert (plain.start_floor, plain.building) == ("0", None)


def test_check_config_names_a_bad_start_floor_or_building_with_a_hint(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "building.yaml").write_text(BUILDING)
    head = 'robot = "r1"\n[barometer]\nport = "/dev/ttyACM0"\n[floors]\n'
    cases = {
        'start_floor = "roof"\nbuilding = "building.yaml"': ("floors.start_floor", "roof"),
        'building = "missing.yaml"': ("floors.building", "missing.yaml"),
        "start_floor = 3": ("floors.start_floor", "Expected `str`, got `int`"),
        'start_floor = " "': ("floors.start_floor", "must not be empty"),
    }
    for body, (key, what) in cases.items():
        path = tmp_path / "bad.toml"
        path.write_text(head + body + "\n")
        assert main(["--check-config", str(path)]) == 2, body
        err = capsys.readouterr().err
        line = next((x for x in err.splitlines() if key in x), "")
        assert what in line, (body, err)
        assert 'e.g. start_floor = "0"' in line or "baromap build-maps" in line, line  # hint


def test_the_choices_the_file_offers_are_the_protocols_and_the_writers() -> None:
    assert set(get_args(config_module.LmsBaud)) == set(lms200.BAUD_MODES)
    assert get_args(config_module.Oversampling) == baro.OVERSAMPLING_VALUES
    assert get_args(config_module.IirFilter) == baro.IIR_FILTER_VALUES
    assert get_args(config_module.Compression) == tuple(COMPRESSIONS)
    assert set(get_args(lms200.Units)) == {"mm", "cm"}


def test_a_retry_key_sits_in_the_device_table_and_keeps_that_devices_defaults() -> None:
    config = parse_config(
        'robot = "r1"\n[laser]\nport = "/dev/l"\nretry_initial_s = 2\n'
        '[base]\nport = "/dev/b"\nmodel = " P3-AT-SH "\n'
    )
    assert config.laser is not None and config.base is not None
    assert config.laser.retry == Retry(initial_s=2.0, max_s=30.0, silence_s=1.0, garbage_s=2.0)
    assert config.base.retry == Retry()
    assert config.base.model == "p3-at-sh"
    with pytest.raises(ConfigProblems) as caught:
        parse_config(
            'robot = "r1"\n[barometer]\nport = "/dev/b"\nretry_initial_s = 5\nretry_max_s = 1\n'
            'silence_s = inf\n[recording]\ndirectory = 3\n[laser]\nport = "/dev/l"\n'
            "mount = { x_m = 1, z_m = 2 }\n"
        )
    problems = {p.key: p.message for p in caught.value.problems}
    assert problems == {
        "barometer.retry_max_s": "1.0 is below retry_initial_s 5.0",
        "barometer.silence_s": "must be finite, not inf",
        "recording.directory": "Expected `str` (a path), got `int`",
        "laser.mount.z_m": "unknown key",
    }


def _with_directory(tmp_path: Path, directory: Path) -> Path:
    path = tmp_path / "baromapd.toml"
    path.write_text(
        f'robot = "r1"\n[recording]\ndirectory = "{directory}"\n[barometer]\nport = "loop://"\n'
    )
    return path


@pytest.mark.parametrize("where", ["under_a_file", "under_proc"])
def test_an_unusable_recording_directory_exits_2_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], where: str
) -> None:
    (tmp_path / "a_file").write_text("")
    directory = {
        "under_a_file": tmp_path / "a_file" / "runs",
        "under_proc": Path("/proc/baromapd-runs"),
    }[where]
    config = _with_directory(tmp_path, directory)
    for args in (["--check-config", str(config)], ["--config", str(config)]):
        assert main(args) == 2
        problems = [line for line in capsys.readouterr().err.splitlines() if line.startswith("  ")]
        assert len(problems) == 1 and problems[0].startswith("  recording.directory: "), problems
    assert not directory.exists()


def test_a_read_only_recording_directory_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import os
    import subprocess

    if os.geteuid() != 0:
        pytest.skip("mounting a read-only file system needs root (root also ignores chmod)")
    mount = tmp_path / "ro"
    mount.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(mount)], check=True)
    try:
        assert main(["--check-config", str(_with_directory(tmp_path, mount))]) == 2
        assert "recording.directory: " in capsys.readouterr().err
        assert main(["--check-config", str(_with_directory(tmp_path, mount / "runs"))]) == 2
        assert "cannot be created: Read-only file system" in capsys.readouterr().err
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def test_a_missing_but_creatable_directory_is_fine_and_left_as_it_was(tmp_path: Path) -> None:
    directory = tmp_path / "not" / "yet"
    assert load_config(_with_directory(tmp_path, directory)).recording.directory == directory
    assert not (tmp_path / "not").exists()
    assert config_module.directory_problem(tmp_path) is None
    assert list(tmp_path.iterdir()) == [tmp_path / "baromapd.toml"]
