"""A serial link to the barometer board, simulated (simavr harness) or real, for the tests.

Everything the tests assert about timing is read from the board's own clock (``time_us`` of
its frames), never from the host's: the simulator may run many times faster than real time,
and a real board's timing must not depend on how busy the test machine is.

What the host causes (a command's ACK, the reset after a hang) has no board-time bound: the
host cannot know the board time at which its bytes arrived. While it was busy (a loaded
machine) the board ran on, and seconds of frames may stand in the pty and the harness's buffer
before the answer. Those waits walk the stream to the answer under a generous wall deadline.
"""

from __future__ import annotations

import itertools
import math
import os
import signal
import subprocess
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, TypeVar

import serial

from baromap.protocols import baro
from baromap.protocols.framing import BadFrame

FIRMWARE_DIR = Path(__file__).resolve().parents[2] / "firmware"
BUILD_DIR = FIRMWARE_DIR / "build"
ELF = BUILD_DIR / "baromap_baro.elf"
HOOKS_ELF = BUILD_DIR / "hooks" / "baromap_baro.elf"
HARNESS = BUILD_DIR / "baro_board"
HOST_TESTS = BUILD_DIR / "host_tests"
BAUD = 115200
#: Wall seconds the host waits for an answer to what it sent (an ACK, a reset), and for the
#: first frame of a board: long enough for a harness starved of CPU on a loaded machine.
ANSWER_WALL_S = 60.0

F = TypeVar("F", bound=baro.Frame)


@dataclass(frozen=True)
class TrajectoryRow:
    """One row of the simulated world: time since start, pressure, temperature, sensor present."""

    t_s: float
    pressure_pa: float
    temperature_c: float = 22.0
    present: bool = True


def write_trajectory(path: Path, rows: Iterable[TrajectoryRow]) -> Path:
    lines = ["time_s,pressure_pa,temperature_c,present"]
    lines += [
        f"{r.t_s:.6f},{r.pressure_pa:.6f},{r.temperature_c:.4f},{int(r.present)}" for r in rows
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def interpolate(rows: Sequence[TrajectoryRow], t_s: float) -> tuple[float, float]:
    """Pressure and temperature the trajectory gives at ``t_s`` (as the harness interpolates)."""
    if t_s <= rows[0].t_s:
        return rows[0].pressure_pa, rows[0].temperature_c
    for a, b in itertools.pairwise(rows):
        if a.t_s <= t_s < b.t_s:
            w = (t_s - a.t_s) / (b.t_s - a.t_s) if b.t_s > a.t_s else 0.0
            return (
                a.pressure_pa + w * (b.pressure_pa - a.pressure_pa),
                a.temperature_c + w * (b.temperature_c - a.temperature_c),
            )
    return rows[-1].pressure_pa, rows[-1].temperature_c


class BoardLink:
    """Frames in, commands out, over one open serial port; keeps every frame it has seen."""

    def __init__(self, port: serial.Serial, simulated: bool, speed: float) -> None:
        self.port = port
        self.simulated = simulated
        #: simulated seconds per wall second (an estimate for wall-clock safety timeouts)
        self.speed = speed
        self.decoder = baro.Decoder()
        self.frames: list[baro.Frame] = []
        self.bad: list[BadFrame] = []
        self._seq = 0
        self._cursor = 0
        #: unwrapped board time (s) of each frame in ``frames``
        self.times: list[float] = []
        self._time_base = 0
        self._last_time: int | None = None

    def pump(self, wait_s: float = 0.05) -> list[baro.Frame]:
        """Read what has arrived (waiting up to ``wait_s`` for the first byte) and decode it."""
        self.port.timeout = wait_s
        data = self.port.read(max(1, self.port.in_waiting))
        if self.port.in_waiting:
            data += self.port.read(self.port.in_waiting)
        new: list[baro.Frame] = []
        for item in self.decoder.feed(data):
            if isinstance(item, BadFrame):
                self.bad.append(item)
            else:
                new.append(item)
                self.times.append(self._unwrap(item.time_us))
        self.frames += new
        return new

    def _unwrap(self, time_us: int) -> float:
        if self._last_time is not None and time_us < self._last_time - (1 << 31):
            self._time_base += 1 << 32
        self._last_time = time_us
        return (self._time_base + time_us) / 1e6

    def _reference_time(self) -> float:
        """Board time where the next wait or run starts: the last frame consumed."""
        deadline = time.monotonic() + ANSWER_WALL_S
        while not self.frames and time.monotonic() < deadline:
            self.pump()
        if not self.frames:
            raise AssertionError("the board sends nothing")
        return self.times[max(self._cursor - 1, 0)]

    def wait_for(
        self, predicate: Callable[[baro.Frame], bool], device_s: float | None, what: str
    ) -> baro.Frame:
        """The next unconsumed frame satisfying ``predicate``, within ``device_s`` of board time
        (None: an answer to the host, whenever it comes; see the module's docstring).

        Frames before it are consumed too: waits and runs walk the stream in order.
        """
        if device_s is None:
            end = math.inf
            deadline = time.monotonic() + ANSWER_WALL_S
        else:
            end = self._reference_time() + device_s
            deadline = time.monotonic() + self._wall_budget(device_s)
        while time.monotonic() < deadline:
            while self._cursor < len(self.frames):
                if self.times[self._cursor] > end:
                    raise AssertionError(f"no {what} within {device_s} s of board time")
                frame = self.frames[self._cursor]
                self._cursor += 1
                if predicate(frame):
                    return frame
            self.pump()
        raise AssertionError(f"no {what} within {deadline_text(device_s)}")

    def wait_type(self, cls: type[F], device_s: float | None = 3.0) -> F:
        frame = self.wait_for(lambda f: isinstance(f, cls), device_s, cls.__name__)
        assert isinstance(frame, cls)
        return frame

    def run_for(self, device_s: float) -> list[baro.Frame]:
        """Every frame of the next ``device_s`` seconds of board time (unconsumed ones first)."""
        end = self._reference_time() + device_s
        deadline = time.monotonic() + self._wall_budget(device_s)
        out: list[baro.Frame] = []
        while True:
            while self._cursor < len(self.frames) and self.times[self._cursor] <= end:
                out.append(self.frames[self._cursor])
                self._cursor += 1
            if self._cursor < len(self.frames):
                return out  # the next frame is already past the end
            if time.monotonic() > deadline:
                raise AssertionError(f"board time advanced less than {device_s} s")
            self.pump()

    def _wall_budget(self, device_s: float) -> float:
        return 10.0 + device_s / min(self.speed, 1.0) * 3.0

    def send(self, data: bytes) -> None:
        self.port.write(data)
        self.port.flush()

    def next_seq(self) -> int:
        self._seq = (self._seq + 1) % baro.SEQ_MODULO
        return self._seq

    def command(self, frame: baro.CommandFrame) -> baro.AckFrame:
        """Send a command (with a flushing 0x00 before it) and wait for its ACK."""
        self.send(b"\x00" + baro.encode(frame))
        return self.wait_ack(frame.TYPE, frame.seq)

    def wait_ack(self, command: int, seq: int) -> baro.AckFrame:
        frame = self.wait_for(
            lambda f: (
                isinstance(f, baro.AckFrame) and f.command == command and f.command_seq == seq
            ),
            None,
            f"ACK of command 0x{command:02x} seq {seq}",
        )
        assert isinstance(frame, baro.AckFrame)
        return frame

    def identify(self) -> baro.HelloFrame:
        ack = self.command(baro.IdentifyCommand(self.next_seq(), 0))
        assert ack.result == baro.AckResult.OK
        return self.wait_type(baro.HelloFrame)

    def set_rate(self, rate_hz: int) -> baro.AckFrame:
        return self.command(baro.SetRateCommand(self.next_seq(), 0, rate_hz))


def deadline_text(device_s: float | None) -> str:
    if device_s is None:
        return f"{ANSWER_WALL_S:g} s (wall)"
    return f"{device_s} s of board time (wall timeout)"


def frames_of(frames: Iterable[baro.Frame], cls: type[F]) -> list[F]:
    return [f for f in frames if isinstance(f, cls)]


class SimulatedBoard:
    """The firmware ELF running in the simavr harness, its UART on a pty opened with pyserial."""

    def __init__(
        self,
        workdir: Path,
        *,
        trajectory: Sequence[TrajectoryRow] | None = None,
        speed: float = 0.0,
        address: int = 0x76,
        name: str = "board",
        elf: Path = ELF,
        sensor: str = "bmp280",
    ) -> None:
        self.workdir = workdir
        self.trajectory = list(trajectory) if trajectory else None
        self.truth_path = workdir / f"{name}-truth.csv"
        self.log_path = workdir / f"{name}-harness.log"
        args = [str(HARNESS), str(elf), "--wait-host", "--speed", repr(speed)]
        args += ["--address", hex(address), "--sensor", sensor, "--truth", str(self.truth_path)]
        if self.trajectory:
            path = write_trajectory(workdir / f"{name}-trajectory.csv", self.trajectory)
            args += ["--trajectory", str(path)]
        self._log: IO[Any] = self.log_path.open("w")
        try:
            self.process = subprocess.Popen(
                args, stdout=subprocess.PIPE, stderr=self._log, text=True, start_new_session=True
            )
        except BaseException:
            self._log.close()
            raise
        self.link: BoardLink | None = None
        try:
            pty_path = self._read_pty_path()
            port = serial.serial_for_url(pty_path, baudrate=BAUD, timeout=0.05)
            # Unthrottled the harness runs 10-30x real time on one core; assume less.
            self.link = BoardLink(port, simulated=True, speed=speed if speed > 0 else 2.0)
        except BaseException:
            self.close()
            raise

    def _read_pty_path(self) -> str:
        assert self.process.stdout is not None
        try:
            for line in self.process.stdout:
                if line.startswith("baro_board: pty "):
                    return line.split()[-1]
        finally:
            self.process.stdout.close()
        raise RuntimeError(f"harness did not start: {self.log_text()}")

    def log_text(self) -> str:
        self._log.flush()
        return self.log_path.read_text()

    def truth(self) -> list[dict[str, float]]:
        """Data-register reads the virtual BMP280 served (read time, measurement time, values)."""
        text = self.truth_path.read_text()
        lines = text[: text.rfind("\n") + 1].splitlines()  # complete lines only
        keys = lines[0].split(",")
        return [dict(zip(keys, map(float, line.split(",")), strict=True)) for line in lines[1:]]

    def close(self) -> None:
        if self.link is not None:
            self.link.port.close()
            self.link = None
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGTERM)
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()
        if self.process.stdout is not None:
            self.process.stdout.close()
        self._log.close()

    def __enter__(self) -> SimulatedBoard:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_real_board(port_url: str) -> BoardLink:
    """A real board, back at its defaults.

    Opening the port resets an Uno/Nano (DTR), so wait for it to come up; adapters without that
    reset keep the previous test's settings, so set the defaults explicitly.
    """
    port = serial.serial_for_url(port_url, baudrate=BAUD, timeout=0.05)
    link = BoardLink(port, simulated=False, speed=1.0)
    deadline = time.monotonic() + 4.0
    while time.monotonic() < deadline and not link.frames:
        link.pump()
    for command in (
        baro.SetRateCommand(link.next_seq(), 0, 25),
        baro.SetOversamplingCommand(link.next_seq(), 0, 16, 2, 16),
    ):
        if link.command(command).result != baro.AckResult.OK:
            raise AssertionError(f"the board refused {command}")
    link.run_for(0.5)
    return link
