"""The ``baromap`` command as a person meets it: help and errors (the demo: tests/e2e)."""

from __future__ import annotations

from pathlib import Path

import pytest

from baromap.cli.main import COMMAND_MODULES, main

EXPECTED_COMMANDS = (
    "demo",
    "sim",
    "detect",
    "eval-floors",
    "build-maps",
    "info",
    "import",
)


def test_every_command_module_exists_and_registers(capsys: pytest.CaptureFixture[str]) -> None:
    for name in COMMAND_MODULES:
        __import__(name)
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    for command in EXPECTED_COMMANDS:
        assert f"    {command} " in out


def test_no_command_prints_help_and_fails(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([]) == 2
    assert "usage: baromap" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["info", "{missing}"], "cannot open recording"),
        (["info", "{text}"], "is not an MCAP file"),
        (["detect", "{text}"], "is not in pascals"),
        (["detect", "{empty}"], "no time_s,pressure_pa rows"),
        (["build-maps", "{text}", "-o", "{out}"], "is not an MCAP file"),
        (["import", "carmen", "{text}", "-o", "{out}/x.mcap"], "no FLASER or ROBOTLASER1"),
        (["sim", "record", "-o", "{out}/x.mcap", "--floors", "0"], "floors must be"),
        (["demo", "--out", "{out}", "--speed", "20"], "speed must be"),
    ],
)
def test_bad_input_is_one_clear_line_and_exit_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    text = tmp_path / "not-data.csv"
    text.write_text("hello,world\n1,2\n")
    empty = tmp_path / "empty.csv"
    empty.write_text("time_s,pressure_pa\n")
    paths = {"missing": tmp_path / "missing.mcap", "text": text, "empty": empty}
    paths["out"] = tmp_path / "out"
    assert main([arg.format(**paths) for arg in argv]) == 1
    err_lines = capsys.readouterr().err.strip().splitlines()
    assert err_lines[-1].startswith("baromap: error: ")
    assert message in err_lines[-1]
    assert not any("Traceback" in line for line in err_lines)


def test_demo_states_its_options(capsys: pytest.CaptureFixture[str]) -> None:
    """The demo itself runs end to end in tests/e2e (once per session: it takes minutes)."""
    with pytest.raises(SystemExit) as exit_info:
        main(["demo", "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert "--out" in out and "--speed" in out
