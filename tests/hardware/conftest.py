"""Fixtures of the hardware tests: the ports given on the command line, and the report.

Each device's tests run when its port is given (``--lms-port``, ``--p2os-port``,
``--baro-port``, any subset) and skip saying which option they need otherwise; the tests that
can move the base also need ``--allow-motion``. What each test measured is printed at the end
of the run as "baromap hardware report", one block per device.
"""

from __future__ import annotations

from collections.abc import Callable

import pytest

from baromap.discovery import resolve_port
from baromap.errors import BaromapError
from baromapd.clock import HostClock

REPORT = pytest.StashKey[list[tuple[str, str, str]]]()


def _port(config: pytest.Config, option: str) -> str:
    """The port given for ``option`` (a USB identity ``vid:pid[:serial]`` looked up now), or
    skip: hardware tests are opt-in."""
    port = config.getoption(option)
    if not port:
        pytest.skip(f"no real device: pass {option} PATH to run against hardware")
    try:
        return resolve_port(str(port))
    except BaromapError as exc:
        pytest.fail(f"{option} {port}: {exc}", pytrace=False)


@pytest.fixture
def lms_port(request: pytest.FixtureRequest) -> str:
    return _port(request.config, "--lms-port")


@pytest.fixture
def p2os_port(request: pytest.FixtureRequest) -> str:
    return _port(request.config, "--p2os-port")


@pytest.fixture
def baro_port(request: pytest.FixtureRequest) -> str:
    return _port(request.config, "--baro-port")


@pytest.fixture
def allow_motion(request: pytest.FixtureRequest) -> None:
    """Skip unless ``--allow-motion``: the test can move the base."""
    if not request.config.getoption("--allow-motion"):
        pytest.skip("moves the base: pass --allow-motion (clear 20 cm around the robot)")


@pytest.fixture
def hil_seconds(request: pytest.FixtureRequest) -> float:
    return float(request.config.getoption("--hil-seconds"))


@pytest.fixture
def host_clock() -> HostClock:
    return HostClock()


@pytest.fixture
def report(request: pytest.FixtureRequest) -> Callable[[str, str], None]:
    """``report(device, line)``: a line of the device's block in the end-of-run report."""
    lines = request.config.stash.setdefault(REPORT, [])

    def add(device: str, line: str) -> None:
        lines.append((device, request.node.name, line))

    return add


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    lines = terminalreporter.config.stash.get(REPORT, [])
    if not lines:
        return
    terminalreporter.section("baromap hardware report")
    for device in sorted({d for d, _, _ in lines}):
        terminalreporter.write_line(device)
        for _, test, line in (entry for entry in lines if entry[0] == device):
            terminalreporter.write_line(f"  {test}: {line}")
