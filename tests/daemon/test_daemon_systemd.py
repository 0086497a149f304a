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
SECURITY = ("systemd-analyze", "security", "--offline=yes", "--no-pager")

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


def unit_settings(text: str) -> dict[tuple[str, str], list[str]]:
    """(section, key) -> values, as systemd reads a unit: comments skipped, an empty
    assignment resets the list. ``systemd-analyze verify`` (above) says every key is known
    in its section, so what is found here is in force."""
    settings: dict[tuple[str, str], list[str]] = {}
    section = ""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1]
            continue
        key, _, value = line.partition("=")
        values = settings.setdefault((section, key.strip()), [])
        if value.strip():
            values.append(value.strip())
        else:
            values.clear()
    return settings


def _verify(tmp_path: Path, text: str, dropins: dict[str, str] | None = None) -> str:
    """What ``systemd-analyze verify`` says about a unit (with drop-ins beside it)."""
    unit = tmp_path / "baromapd.service"
    here = str(Path(sys.executable).parent / "baromapd")
    unit.write_text(text.replace(INSTALLED, here))
    for name, body in (dropins or {}).items():
        (tmp_path / "baromapd.service.d").mkdir(exist_ok=True)
        (tmp_path / "baromapd.service.d" / name).write_text(body)
    result = subprocess.run(
        ["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, check=False
    )
    return (result.stdout + result.stderr).strip() + ("" if result.returncode == 0 else " (rc)")


def test_the_unit_has_what_the_daemon_relies_on(tmp_path: Path) -> None:
    settings = unit_settings(UNIT.read_text())
    service = {key: values for (section, key), values in settings.items() if section == "Service"}
    assert service["Type"] == ["notify"]
    assert service["NotifyAccess"] == ["main"]
    assert service["Restart"] == ["on-failure"]
    # 2 (configuration) is not restarted; the recorder's 3 and a stop's 4 are
    assert service["RestartPreventExitStatus"] == ["2"]
    assert service["StateDirectory"] == ["baromapd"]
    assert service["ConfigurationDirectory"] == ["baromapd"]
    assert service["SupplementaryGroups"] == ["dialout"]
    assert service["DevicePolicy"] == ["closed"]
    assert "char-ttyUSB rw" in service["DeviceAllow"]
    assert service["ProtectSystem"] == ["strict"]
    # the daemon leaves a hung part behind after 10 s (baromapd.main): inside the stop timeout
    assert int(service["TimeoutStopSec"][0].removesuffix("s")) > 10
    assert int(service["WatchdogSec"][0].removesuffix("s")) >= 2
    assert _verify(tmp_path, UNIT.read_text()) == ""


def test_verify_finds_a_setting_out_of_place(tmp_path: Path) -> None:
    """What the test above relies on: a key in the wrong section, or misspelt, is reported."""
    text = UNIT.read_text()
    moved = text.replace("RestartPreventExitStatus=2\n", "").replace(
        "[Unit]\n", "[Unit]\nRestartPreventExitStatus=2\n"
    )
    assert "Unknown key 'RestartPreventExitStatus' in section [Unit]" in _verify(tmp_path, moved)
    assert "RestartPreventExitStatus" not in {
        key for (section, key) in unit_settings(moved) if section == "Service"
    }
    assert "Unknown key" in _verify(tmp_path, text.replace("Type=notify", "Typ=notify"))


def test_documentation_names_what_the_install_puts_there() -> None:
    (links,) = unit_settings(UNIT.read_text())[("Unit", "Documentation")]
    install = (REPO / "docs" / "install.md").read_text()
    for link in links.split():
        assert link.startswith("file:///usr/share/doc/baromap/"), link
        name = link.rsplit("/", 1)[1]
        assert (REPO / "docs" / name).is_file(), name
        assert "-t /usr/share/doc/baromap" in install and f"docs/{name}" in install


def test_the_fleet_drop_in_lets_the_daemon_reach_routers_beyond_localhost(
    tmp_path: Path,
) -> None:
    fleet = (REPO / "systemd" / "baromapd.service.d" / "fleet.conf").read_text()
    assert _verify(tmp_path, UNIT.read_text(), {"fleet.conf": fleet}) == ""

    def ip_allow_list(directory: Path) -> str:
        result = subprocess.run(
            [*SECURITY, str(directory / "baromapd.service")],
            capture_output=True,
            text=True,
            check=False,
        )
        (line,) = [line for line in result.stdout.splitlines() if "IPAddressDeny=" in line]
        return line

    # as systemd reads the unit: localhost only without the drop-in, more with it
    assert "with non-localhost entries" in ip_allow_list(tmp_path)
    bare = tmp_path / "bare"
    bare.mkdir()
    assert _verify(bare, UNIT.read_text()) == ""
    assert "with only localhost entries" in ip_allow_list(bare)
