"""The unit file: ``systemd-analyze verify`` silent, security exposure at most 2.0."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
UNIT = REPO / "systemd" / "baromapd.service"
INSTALLED = "/opt/baromap/bin/baromapd"

pytestmark = pytest.mark.skipif(
    shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed"
)


def test_verify_prints_nothing(tmp_path: Path) -> None:
    # The unit runs the install location of README.md; here that is this checkout's venv.
    unit = tmp_path / "baromapd.service"
    here = str(Path(sys.executable).parent / "baromapd")
    unit.write_text(UNIT.read_text().replace(INSTALLED, here))
    result = subprocess.run(
        ["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, check=False
    )
    assert (result.stdout + result.stderr).strip() == ""
    assert result.returncode == 0


def test_security_exposure_is_at_most_2() -> None:
    result = subprocess.run(
        ["systemd-analyze", "security", "--offline=yes", "--no-pager", str(UNIT)],
        capture_output=True,
        text=True,
        check=False,
    )
    match = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", result.stdout)
    assert match, result.stdout[-500:] + result.stderr
    assert float(match.group(1)) <= 2.0


def test_the_unit_has_what_the_daemon_relies_on() -> None:
    text = UNIT.read_text()
    for line in (
        "Type=notify",
        "WatchdogSec=",
        "Restart=on-failure",
        "RestartPreventExitStatus=2",
        "StateDirectory=baromapd",
        "ConfigurationDirectory=baromapd",
        "SupplementaryGroups=dialout",
        "DevicePolicy=closed",
        "DeviceAllow=char-ttyUSB rw",
        "ProtectSystem=strict",
    ):
        assert line in text
