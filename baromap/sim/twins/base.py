"""What every twin shares: the simulated clock, a thread, a pty, power, faults and truth.

Faults come two ways: called by a test at any moment (:meth:`Twin.inject_garbage`,
:meth:`Twin.power_cycle`, ...) or scheduled in the scenario's :class:`TwinSettings` at a
simulated time, which the twin's thread carries out when the clock gets there.
"""

from __future__ import annotations

import bisect
import math
import select
import threading
import time
from pathlib import Path
from types import TracebackType
from typing import Self

import structlog

from baromap.errors import ConfigError
from baromap.sim.scenario import STREAM_FAULTS, Fault, Scenario, TwinSettings
from baromap.sim.twins.pty_port import PtyPort
from baromap.sim.twins.truth import TruthLog, TruthSink

log = structlog.get_logger(__name__)

#: A message's end put on the line later than this is counted late in the twin's stop line.
LATE_S = 0.02

TICK_S = 0.002


class SimClock:
    """Simulated time for all twins: wall time times ``speed``, and the robot's route time.

    The robot's route time stops while the base's watchdog holds the robot (no host packets
    for 2 s), so the laser, the barometer and the odometry all see it standing still; the
    weather keeps its own course.
    """

    def __init__(self, scenario: Scenario, speed: float = 1.0, start_s: float = 0.0) -> None:
        """``start_s``: simulated seconds already gone when the clock starts (join mid-route)."""
        if not 0 < speed < math.inf:
            raise ConfigError(f"speed must be positive and finite, got {speed}")
        if not 0 <= start_s <= scenario.duration_s:
            raise ConfigError(f"start must be within the run's {scenario.duration_s:g} s")
        self.scenario = scenario
        self.speed = speed
        self._t0 = time.monotonic() - start_s / speed
        self._lock = threading.Lock()
        self._halted_at: float | None = None
        self._halted_total = 0.0

    def now(self) -> float:
        """Simulated seconds since the start."""
        return (time.monotonic() - self._t0) * self.speed

    def robot_time(self) -> float:
        with self._lock:
            t = self._halted_at if self._halted_at is not None else self.now()
            return max(0.0, min(t - self._halted_total, self.scenario.duration_s))

    def halt(self) -> None:
        with self._lock:
            if self._halted_at is None:
                self._halted_at = self.now()

    def resume(self) -> None:
        with self._lock:
            if self._halted_at is not None:
                self._halted_total += self.now() - self._halted_at
                self._halted_at = None

    @property
    def halted(self) -> bool:
        return self._halted_at is not None

    def real_delay(self, sim_seconds: float) -> float:
        return sim_seconds / self.speed

    def t_ns(self, sim_seconds: float) -> int:
        return int(self.scenario.start_ns + round(sim_seconds * 1e9))


class Started:
    """Something that runs between ``start()`` and ``stop()``, or for a ``with`` block."""

    def start(self) -> Self:
        raise NotImplementedError

    def stop(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()


class Twin(Started):
    """A device on a pty, served by its own thread; use as a context manager or start/stop."""

    name = "device"
    initial_baud = 9600

    def __init__(
        self,
        clock: SimClock,
        link: str | Path | None = None,
        *,
        truth_sink: TruthSink | None = None,
    ) -> None:
        self.clock = clock
        self.settings: TwinSettings = clock.scenario.twins
        self.port = PtyPort(self.initial_baud, link)
        self.truth = TruthLog(self.name, sink=truth_sink)
        #: Power-ups so far minus one: 0 during the first, 1 after one power cycle, ...
        self.boot = -1
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._replug_pending = False
        self._replug_at: float | None = None
        self._power_on_at: float | None = None
        self._faults = list(self.settings.faults_of(self.name))
        self.setup()

    # ---- lifetime -------------------------------------------------------------------------------
    @property
    def path(self) -> str:
        return self.port.path

    def start(self) -> Twin:
        self._power_up()
        self._thread = threading.Thread(target=self._loop, name=f"sim-{self.name}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        self.port.close()
        self._log_lateness()

    def _log_lateness(self) -> None:
        """How late this twin put its messages' ends on the line: a host's stamps can be no
        better than that (a twin's thread held up on a loaded machine delivers late, which no
        real device does), so a host's timestamp error is told apart from the twin's own."""
        late = sorted(self.port.lateness)
        if not late:
            return
        log.info(
            "twin stopped",
            twin=self.name,
            messages=len(late),
            late_p99_ms=round(late[(99 * len(late) + 99) // 100 - 1] * 1e3, 1),  # nearest rank
            late_max_ms=round(late[-1] * 1e3, 1),
            late_over_20ms=len(late) - bisect.bisect_right(late, LATE_S),
        )

    # ---- faults ---------------------------------------------------------------------------------
    def inject_garbage(self, data: bytes) -> None:
        self.port.inject_garbage(data)

    def drop_bytes(self, count: int) -> None:
        self.port.drop_next(count)

    def stall(self, seconds: float) -> None:
        self.port.stall(seconds)

    def unplug(self) -> None:
        self.port.unplug()

    def replug(self) -> None:
        """Power the device up again on a fresh pty behind the same link."""
        self.port.replug()
        self._replug_pending = True

    def power_cycle(self, off_s: float = 0.5) -> None:
        """Cut the power for ``off_s`` simulated seconds; the device then boots afresh."""
        self.port.clear()
        self._power_on_at = time.monotonic() + self.clock.real_delay(off_s)

    @property
    def powered(self) -> bool:
        return self._power_on_at is None

    def _apply(self, fault: Fault) -> None:
        log.info("scheduled fault", twin=self.name, kind=fault.kind, at_s=fault.at_s)
        if fault.kind == "power_cycle":
            self.power_cycle(fault.duration_s)
        elif fault.kind == "stall":
            self.stall(self.clock.real_delay(fault.duration_s))
        elif fault.kind == "garbage":
            noise = self.clock.scenario.rng(STREAM_FAULTS).integers(0, 256, fault.size)
            self.inject_garbage(bytes(noise.astype("u1")))
        elif fault.kind == "drop":
            self.drop_bytes(fault.size)
        elif fault.kind == "unplug":
            self.unplug()
            self._replug_at = time.monotonic() + self.clock.real_delay(fault.duration_s)

    def _due_faults(self) -> None:
        now_s = self.clock.now()
        while self._faults and self._faults[0].at_s <= now_s:
            self._apply(self._faults.pop(0))
        if self._replug_at is not None and time.monotonic() >= self._replug_at:
            self._replug_at = None
            self.replug()

    # ---- the device -----------------------------------------------------------------------------
    def setup(self) -> None:
        """What the device keeps across power cycles (models, counters): once, at creation."""

    def _power_up(self) -> None:
        self.boot += 1
        self.power_on()

    def power_on(self) -> None:
        """Reset the device's state (at start, after a replug and after a power cycle)."""

    def on_bytes(self, data: bytes) -> None:
        """Bytes the host wrote."""

    def tick(self) -> None:
        """Called every few milliseconds: produce output that is due."""

    def _loop(self) -> None:
        while not self._stop.is_set():
            self._due_faults()
            if self._replug_pending:
                self._replug_pending = False
                self._power_up()
            if self._power_on_at is not None and time.monotonic() >= self._power_on_at:
                self._power_on_at = None
                self._power_up()
            fd = self.port.fileno()
            if fd is None:
                self._stop.wait(0.01)
                continue
            # Wake at the next tick, or when a message's last byte is due (the line's end).
            due = self.port.next_due()
            timeout = TICK_S if due is None else min(TICK_S, max(0.0, due - time.monotonic()))
            try:
                ready, _, _ = select.select([fd], [], [], timeout)
            except (OSError, ValueError):  # unplugged or replugged meanwhile
                continue
            try:
                data = self.port.read() if ready else b""
                if not self.powered:
                    continue  # no power: what the host sends is lost, nothing is sent
                if data:
                    self.on_bytes(data)
                self.tick()
                self.port.pump()
            except Exception:  # a twin must never die silently mid-test
                log.exception("twin failed", twin=self.name)
                raise
