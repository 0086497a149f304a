"""The daemon's test rig: the three devices (pty twins, or real ones when given), helpers.

``pytest --lms-port PATH --p2os-port PATH --baro-port PATH`` runs the same integration tests
against real hardware; tests that need to pull a plug or inject bytes use the ``twins``
fixture and are skipped then.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from baromap.messages import DeviceHealth, DeviceState
from baromap.recording import read_messages
from baromap.recording.reader import Record
from baromap.sim.twins import SimDevices
from baromapd import tap
from baromapd.app import Daemon
from baromapd.config import DaemonConfig, parse_config


@dataclass
class Rig:
    """Where the devices are; ``sim`` is None on real hardware."""

    ports: dict[str, str]
    sim: SimDevices | None = None
    directory: Path = field(default_factory=Path)


def _hardware(config: pytest.Config) -> dict[str, str] | None:
    options = {"laser": "--lms-port", "base": "--p2os-port", "barometer": "--baro-port"}
    given = {name: config.getoption(opt) for name, opt in options.items()}
    if not any(given.values()):
        return None
    missing = [options[n] for n, v in given.items() if not v]
    if missing:
        pytest.skip(f"the daemon's hardware tests need all three ports; missing {missing}")
    return {k: str(v) for k, v in given.items()}


@pytest.fixture
def rig(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Rig]:
    """The three devices: real ones if their ports were given, else twins on ptys."""
    ports = _hardware(request.config)
    if ports is not None:
        yield Rig(ports, None, tmp_path)
        return
    with SimDevices(link_dir=tmp_path / "links", minutes=30, seed=3) as sim:
        paths = sim.paths()
        yield Rig(
            {"laser": paths["lms200"], "base": paths["p3at"], "barometer": paths["baro"]},
            sim,
            tmp_path,
        )


@pytest.fixture(params=["python", "c"])
def tap_program(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Each implementation of the laser's tap (``daemon/baromapd/tap.py``, ``daemon/tap.c``), as the
    program a ``Tap`` runs when none is given; the C one is skipped where it is not built."""
    if request.param == "python":
        program = list(tap.python_program())
    else:
        native = tap.native_program()
        if not os.access(native, os.X_OK):
            pytest.skip(f"the C tap is not built ({native}: `make setup` builds it with cc)")
        program = [str(native)]
    monkeypatch.setattr(tap, "default_program", lambda: tuple(program))
    return program


@pytest.fixture
def twins(rig: Rig) -> SimDevices:
    """The simulated devices themselves, for tests that unplug, stall or garble them."""
    if rig.sim is None:
        pytest.skip("fault injection needs the simulated devices")
    return rig.sim


def config_text(
    rig: Rig, devices: tuple[str, ...] = ("laser", "base", "barometer"), **extra: str
) -> str:
    """A configuration for the rig with quick retries; ``extra`` appends lines to a table."""
    tables = {
        "recording": [f'directory = "{rig.directory / "rec"}"', "min_free_mb = 0"],
        "laser": ["baud = 500000", "retry_initial_s = 0.2", "retry_max_s = 1.0", "silence_s = 1.0"],
        "base": ["retry_initial_s = 0.2", "retry_max_s = 1.0", "silence_s = 1.0"],
        "barometer": [
            "rate_hz = 50",
            "retry_initial_s = 0.2",
            "retry_max_s = 1.0",
            "silence_s = 1.0",
        ],
    }
    # Live publishing and the live view off: parallel test workers would all listen on the
    # default ports.
    lines = ['robot = "test"', "[zenoh]", "enabled = false", "[live_view]", "enabled = false"]
    for name, body in tables.items():
        if name != "recording" and name not in devices:
            continue
        lines.append(f"[{name}]")
        if name in rig.ports:
            lines.append(f'port = "{rig.ports[name]}"')
        lines += body
        if name in extra:
            lines.append(extra[name])
    return "\n".join(lines) + "\n"


def make_config(
    rig: Rig, devices: tuple[str, ...] = ("laser", "base", "barometer"), **extra: str
) -> DaemonConfig:
    return parse_config(config_text(rig, devices, **extra))


class RunningDaemon:
    """The daemon on a thread of the test process, as ``baromapd`` runs it."""

    def __init__(self, config: DaemonConfig, **kwargs: Any) -> None:
        kwargs.setdefault("live", False)
        self.daemon = Daemon(config, **kwargs)
        self._thread = threading.Thread(target=self.daemon.run, name="test-baromapd")
        self.history: list[DeviceHealth] = []

    @classmethod
    def live(cls, config: DaemonConfig, **kwargs: Any) -> RunningDaemon:
        """With its Zenoh publisher (as configured in ``[zenoh]``)."""
        return cls(config, live=True, **kwargs)

    def __enter__(self) -> RunningDaemon:
        self._thread.start()
        assert self.daemon.ready.wait(10), "daemon did not start"
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def stop(self) -> None:
        if self._thread.is_alive():
            self.daemon.request_stop()
            self._thread.join(30)
            assert not self._thread.is_alive(), "daemon did not stop"

    def states(self) -> dict[str, DeviceState]:
        return {h.device: h.state for h in self.daemon.health()}

    def wait_until(self, what: Callable[[], bool], timeout: float, message: str) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if what():
                return
            time.sleep(0.05)
        pytest.fail(
            f"timed out after {timeout} s waiting until {message}; health: {self.daemon.health()}"
        )

    def wait_up(
        self, devices: tuple[str, ...] = ("laser", "base", "barometer"), timeout: float = 15
    ) -> None:
        self.wait_until(
            lambda: all(self.states().get(d) is DeviceState.UP for d in devices),
            timeout,
            f"{devices} are up",
        )


def read_all(files: list[Path], topics: list[str] | None = None) -> list[Record]:
    records: list[Record] = []
    for path in files:
        records += list(read_messages(path, topics))
    return records
