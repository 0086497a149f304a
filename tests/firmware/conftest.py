"""Fixtures of the firmware tests: builds (guarded by a lock), simulated and real boards.

The build needs the AVR toolchain (gcc-avr, avr-libc, arduino-core-avr) and the harness needs
libsimavr-dev; without them the tests skip and say what is missing. CI runs as root with all
of them installed.
"""

from __future__ import annotations

import fcntl
import shutil
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from firmware_board import (
    BUILD_DIR,
    ELF,
    FIRMWARE_DIR,
    HARNESS,
    HOOKS_ELF,
    HOST_TESTS,
    BoardLink,
    SimulatedBoard,
    open_real_board,
)

ARDUINO_CORE = Path("/usr/share/arduino/hardware/arduino/avr/cores/arduino")
SIM_ONLY = (
    "simavr only: needs what only the simulator gives (injected pressure, a removable sensor,"
    " a cold start or a test build)"
)


def _make(target: str) -> subprocess.CompletedProcess[str]:
    """Run one firmware make target; a file lock keeps parallel workers from racing."""
    BUILD_DIR.mkdir(exist_ok=True)
    with (BUILD_DIR / ".build.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        result = subprocess.run(
            ["make", "--no-print-directory", "-C", str(FIRMWARE_DIR), target],
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
    if result.returncode != 0:
        pytest.fail(f"make {target} failed:\n{result.stdout}\n{result.stderr}", pytrace=False)
    return result


def _require(*tools: str) -> None:
    missing = [tool for tool in tools if shutil.which(tool) is None]
    if missing:
        pytest.skip(
            f"toolchain missing: {', '.join(missing)}"
            " (install gcc-avr avr-libc arduino-core-avr g++ make)"
        )


@pytest.fixture(scope="session")
def host_tests_binary() -> Path:
    _require("make", "g++")
    _make("host-tests")
    return HOST_TESTS


@pytest.fixture(scope="session")
def firmware_size_report() -> str:
    """Output of the firmware build: the size lines it prints."""
    _require("make", "avr-gcc", "avr-g++", "avr-size", "avr-objcopy")
    if not ARDUINO_CORE.is_dir():
        pytest.skip(f"arduino-core-avr missing ({ARDUINO_CORE})")
    _make("firmware")
    return _make("size").stdout


@pytest.fixture(scope="session")
def firmware_elf(firmware_size_report: str) -> Path:
    assert ELF.is_file()
    return ELF


@pytest.fixture(scope="session")
def harness(firmware_elf: Path) -> Path:
    _require("gcc", "pkg-config")
    probe = subprocess.run(
        ["pkg-config", "--exists", "simavr", "simavrparts"], capture_output=True, check=False
    )
    if probe.returncode != 0 or not Path("/usr/include/libelf.h").exists():
        pytest.skip("simavr missing: install simavr libsimavr-dev libelf-dev")
    _make("sim")
    return HARNESS


@pytest.fixture(scope="session")
def hooks_elf(firmware_elf: Path) -> Path:
    """The firmware built with test-only commands (make hooks)."""
    _make("hooks")
    assert HOOKS_ELF.is_file()
    return HOOKS_ELF


@pytest.fixture
def sim_board(
    request: pytest.FixtureRequest, tmp_path: Path
) -> Iterator[Callable[..., SimulatedBoard]]:
    """Factory of simulated boards (closed at teardown); skips when a real board is given."""
    if request.config.getoption("--baro-port"):
        pytest.skip(SIM_ONLY)
    request.getfixturevalue("harness")
    boards: list[SimulatedBoard] = []

    def start(**kwargs: object) -> SimulatedBoard:
        board = SimulatedBoard(tmp_path, name=f"board{len(boards)}", **kwargs)  # type: ignore[arg-type]
        boards.append(board)
        return board

    yield start
    for board in boards:
        board.close()


@pytest.fixture
def board(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[BoardLink]:
    """The board under test: the simulated one, or the real one given by --baro-port."""
    port = request.config.getoption("--baro-port")
    if port:
        link = open_real_board(str(port))
        try:
            yield link
        finally:
            link.port.close()
        return
    request.getfixturevalue("harness")
    with SimulatedBoard(tmp_path) as simulated:
        assert simulated.link is not None
        yield simulated.link
