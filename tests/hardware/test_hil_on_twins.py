"""The hardware tests against the twins, as a bench would run them, on every commit.

``baromap sim --link-dir DIR`` runs as a process of its own (stable links ``DIR/lms200``,
``DIR/p3at``, ``DIR/baro``); for each device alone, ``pytest -m hardware --allow-motion
--<device>-port DIR/<link>`` runs in a subprocess, so the real-port path (the options plugin,
a port path outside the checkout, the daemon's sessions on a serial line) is the one tested.
Each device must run at least three tests, skip none and pass all. A device whose only
failures are timing (its rate, a pause) runs once more, alone: on a loaded machine the twins'
threads starve as a real device would not.

Beside the twins, the firmware's test build runs in simavr at real time (when the toolchain
is there) through the barometer's watchdog test, in a fourth process at the same time.

Then the same against twins with faults scheduled throughout the run (a killed link, a stall,
garbage on the line): the test that should catch each fault must fail, saying why.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
#: device -> (the option naming its port, the twin's link, its test module)
DEVICES = {
    "laser": ("--lms-port", "lms200", "test_hil_lms200"),
    "base": ("--p2os-port", "p3at", "test_hil_p2os"),
    "barometer": ("--baro-port", "baro", "test_hil_baro"),
}
#: Short windows: the twins are paced like real lines, two seconds show the rate. The laser at
#: RS-232's 38400 baud (10 scans a second, not 75): three test processes and the twins share
#: two cores with the rest of the suite.
ARGS = ["-m", "hardware", "--allow-motion", "--hil-seconds", "2"]
SUBPROCESS_TIMEOUT_S = 240


@dataclass(frozen=True)
class Outcome:
    name: str
    module: str
    result: str  # passed, failed, error, skipped
    message: str


def _environment() -> dict[str, str]:
    """This environment without what configures the outer pytest (xdist workers, addopts)."""
    return {k: v for k, v in os.environ.items() if not k.startswith(("PYTEST_", "COV_"))}


class Twins:
    """``baromap sim --link-dir DIR`` as a separate process (stopped with SIGTERM)."""

    def __init__(self, link_dir: Path, log: Path, twins_toml: Path | None = None) -> None:
        self.link_dir = link_dir
        command = [sys.executable, "-m", "baromap.cli", "sim", "--link-dir", str(link_dir)]
        command += ["--minutes", "20", "--seed", "5"]
        if twins_toml is not None:
            command += ["--twins", str(twins_toml)]
        self._log = log.open("wb")
        self.process = subprocess.Popen(
            command, stdout=self._log, stderr=subprocess.STDOUT, env=_environment()
        )

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        links = [self.link_dir / link for _, link, _ in DEVICES.values()]
        while not all(link.exists() for link in links):
            assert self.process.poll() is None, "baromap sim exited"
            assert time.monotonic() < deadline, "baromap sim made no links"
            time.sleep(0.1)

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._log.close()


def _ports(link_dir: Path) -> dict[str, tuple[str, str]]:
    """Each device's option and its twin's link."""
    return {device: (option, str(link_dir / link)) for device, (option, link, _) in DEVICES.items()}


def _run_devices(
    ports: dict[str, tuple[str, str]], out: Path, runs: dict[str, list[str]]
) -> dict[str, tuple[list[Outcome], str]]:
    """``pytest`` for each run at once, each in its own process with its device's port
    (``ports``: name -> option and path; ``runs``: name -> the tests, all of
    ``tests/hardware`` when empty): outcomes and output."""
    processes = {}
    for name, tests in runs.items():
        option, path = ports[name]
        xml = out / f"{name}.xml"
        # the space form for the laser, the = form for the others: both must work
        port = [option, path] if name == "laser" else [f"{option}={path}"]
        command = [sys.executable, "-m", "pytest", *ARGS, *port, "-p", "no:cacheprovider",
                   f"--junitxml={xml}", "-q", *(tests or ["tests/hardware"])]  # fmt: skip
        processes[name] = (
            xml,
            subprocess.Popen(
                command,
                cwd=REPO,
                env=_environment(),
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
            ),
        )
    results = {}
    for name, (xml, process) in processes.items():
        output, _ = process.communicate(timeout=SUBPROCESS_TIMEOUT_S)
        print(f"== {name}\n{output}")
        results[name] = (_outcomes(xml) if xml.exists() else [], output)
    return results


def _outcomes(xml: Path) -> list[Outcome]:
    out = []
    for case in ET.parse(xml).getroot().iter("testcase"):
        result, message = "passed", ""
        for child in case:
            if child.tag in ("failure", "error", "skipped"):
                result = "failed" if child.tag == "failure" else child.tag
                message = (child.get("message") or "") + "\n" + (child.text or "")
        module = case.get("classname", "").rsplit(".", 1)[-1]
        out.append(Outcome(case.get("name", ""), module, result, message))
    return out


#: What a streaming test says when only timing failed: on a loaded machine (the twins, the
#: daemon's readers and two other test processes share two cores) that device runs again,
#: alone, once.
TIMING = ("rate off", "stream paused")


def _timing_only(outcomes: list[Outcome]) -> bool:
    failed = [o for o in outcomes if o.result in ("failed", "error")]
    return bool(failed) and all(any(t in o.message for t in TIMING) for o in failed)


@pytest.fixture(scope="module")
def clean_runs(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[dict[str, tuple[list[Outcome], str]]]:
    base = tmp_path_factory.mktemp("hil")
    ports = _ports(base / "links")
    runs: dict[str, list[str]] = {device: [] for device in DEVICES}
    with contextlib.ExitStack() as stack:
        twins = Twins(base / "links", base / "sim.log")
        stack.callback(twins.close)
        board = _firmware_board(base / "simavr.log")  # alongside, when it can be built
        if board is not None:
            stack.callback(board.close)
            ports["firmware"] = ("--baro-port", board.pty)
            runs["firmware"] = [WATCHDOG_TEST]
        twins.wait_ready()
        results = _run_devices(ports, base, runs)
        for name, (outcomes, output) in list(results.items()):
            if _timing_only(outcomes):
                again, rerun = _run_devices(ports, base, {name: runs[name]})[name]
                results[name] = (again, f"{output}\n== again, alone (timing failed):\n{rerun}")
        yield results


@pytest.mark.parametrize("device", list(DEVICES))
def test_each_device_alone_runs_its_tests_and_all_pass(
    clean_runs: dict[str, tuple[list[Outcome], str]], device: str
) -> None:
    everything, output = clean_runs[device]
    module = DEVICES[device][2]
    outcomes = [o for o in everything if o.module == module]
    others = [o for o in everything if o.module != module]
    assert len(outcomes) >= 3, f"{device}: {len(outcomes)} tests ran\n{output}"
    assert all(o.result == "skipped" and "no real device" in o.message for o in others), (
        "another device's tests ran"
    )
    bad = [o for o in outcomes if o.result != "passed"]
    assert not bad, f"{device}: " + "; ".join(f"{o.name} {o.result}: {o.message}" for o in bad)
    assert "baromap hardware report" in output


def _faults(device: str, kind: str, every_s: float, **fields: float) -> list[str]:
    """One fault every ``every_s`` for two minutes, as [[twins.faults]] tables."""
    extra = "".join(f"\n{key} = {value}" for key, value in fields.items())
    return [
        f'[[twins.faults]]\ndevice = "{device}"\nat_s = {i * every_s:.2f}\nkind = "{kind}"{extra}'
        for i in range(int(120 / every_s))
    ]


#: Faults all through the run, so that whatever moment a test streams, it meets them.
FAULTS = "\n".join(
    _faults("baro", "garbage", 0.5, size=48)
    + _faults("lms200", "stall", 1.0, duration_s=0.5)
    + _faults("p3at", "unplug", 3.0, duration_s=1.0)
)
#: What a streaming test says when its stream stopped: paused, reconnected, or never up.
STREAM_BROKEN = ("stream paused", "rate off", "it reconnected", "not streaming", "is not up")
#: device -> (its test that should catch the fault, what its failure must say)
CATCHES = {
    "barometer": ("test_board_identifies_configures_and_streams_at_its_rate", ("framing errors",)),
    # a stall that cuts a scan short also shows as a framing error
    "laser": (
        "test_each_mode_streams_its_beams_at_its_rate[180deg-1deg-mm]",
        (*STREAM_BROKEN, "framing errors"),
    ),
    "base": ("test_handshake_config_and_sips_at_the_robots_cycle", STREAM_BROKEN),
}


def test_a_twin_fault_fails_the_test_that_should_catch_it(tmp_path: Path) -> None:
    """Garbage on the barometer's line, the laser stalling, the base's link killed: each
    device's streaming test fails on it."""
    toml = tmp_path / "faults.toml"
    toml.write_text(FAULTS + "\n")
    twins = Twins(tmp_path / "links", tmp_path / "sim.log", toml)
    try:
        twins.wait_ready()
        runs = {
            device: [f"tests/hardware/{DEVICES[device][2]}.py::{name}"]
            for device, (name, _) in CATCHES.items()
        }
        results = _run_devices(_ports(tmp_path / "links"), tmp_path, runs)
    finally:
        twins.close()
    for device, (name, says) in CATCHES.items():
        outcomes, output = results[device]
        caught = [o for o in outcomes if o.name == name]
        assert caught, f"{device}: {name} did not run\n{output}"
        assert caught[0].result == "failed", (
            f"{device}: {name} {caught[0].result} despite the fault"
        )
        assert any(phrase in caught[0].message for phrase in says), caught[0].message


WATCHDOG_TEST = (
    "tests/hardware/test_hil_baro.py::"
    "test_firmware_reports_status_every_second_and_its_watchdog_works"
)


class FirmwareBoard:
    """The firmware's test build (its hang command) in the simavr harness at real time."""

    def __init__(self, harness: Path, elf: Path, log: Path) -> None:
        self._log = log.open("w")
        self.process = subprocess.Popen([str(harness), str(elf), "--speed", "1"],
                                        stdout=subprocess.PIPE, stderr=self._log, text=True,
                                        start_new_session=True)  # fmt: skip
        assert self.process.stdout is not None
        lines = (line for line in self.process.stdout if line.startswith("baro_board: pty"))
        self.pty = next(lines, " none").split()[-1]

    def close(self) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.process.pid, signal.SIGTERM)
        self.process.wait(10)
        if self.process.stdout is not None:
            self.process.stdout.close()
        self._log.close()


def _firmware_board(log: Path) -> FirmwareBoard | None:
    """The firmware's test build in simavr, built if need be; None without the toolchain."""
    firmware = REPO / "firmware"
    tools = ("make", "avr-gcc", "pkg-config", "gcc")
    if any(shutil.which(tool) is None for tool in tools):
        return None
    if subprocess.run(["pkg-config", "--exists", "simavr"], check=False).returncode != 0:
        return None
    build = firmware / "build"
    build.mkdir(exist_ok=True)
    with (build / ".build.lock").open("w") as lock:  # the firmware tests' lock: one build at a time
        fcntl.flock(lock, fcntl.LOCK_EX)
        made = subprocess.run(["make", "--no-print-directory", "-C", str(firmware), "hooks", "sim"],
                              capture_output=True, text=True, timeout=300, check=False)  # fmt: skip
    assert made.returncode == 0, made.stdout + made.stderr
    return FirmwareBoard(build / "baro_board", build / "hooks" / "baromap_baro.elf", log)


def test_the_real_firmware_in_simavr_passes_the_barometer_watchdog_test(
    clean_runs: dict[str, tuple[list[Outcome], str]],
) -> None:
    """The firmware's test build running in simavr at real time, on a pty like a board's
    port: the hardware watchdog test sees its hung loop reset by the watchdog (the twin, like
    the shipped firmware, refuses the hang command instead)."""
    if "firmware" not in clean_runs:
        pytest.skip("firmware toolchain or simavr missing (scripts/system-deps.sh installs them)")
    outcomes, output = clean_runs["firmware"]
    assert [o.result for o in outcomes] == ["passed"], output
    assert "test build: hung loop reset by the watchdog" in output
