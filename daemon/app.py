"""The daemon put together: sessions -> fanout -> recorder, floor tracker, live publisher.

The main loop does little on purpose: twice a second it checks that every part is making
progress (each thread updates a heartbeat), publishes health once a second (recorded on
``/diagnostics``), tells systemd the device states in ``STATUS=``, and pings the watchdog only
if every part made progress. A part that hangs therefore gets the service restarted by
systemd instead of recording nothing while claiming to be fine.
"""

from __future__ import annotations

import datetime as dt
import gc
import json
import threading
import time
from collections.abc import Callable
from typing import Any, Final

import structlog

from baromap import __version__
from baromap.discovery import resolve_port
from baromap.messages import NS_PER_S, DeviceHealth, DeviceState, Message, PressureSample
from baromap.recording.frames import LaserMount
from daemon.barometer import BarometerSession
from daemon.clock import HostClock
from daemon.config import DaemonConfig
from daemon.fanout import Consumer, Fanout
from daemon.floors import FloorTracker
from daemon.live import create_publisher
from daemon.lms200 import Lms200Session
from daemon.notify import Notifier
from daemon.pioneer import PioneerSession
from daemon.recorder import Recorder
from daemon.session import DeviceSession

log = structlog.get_logger(__name__)

TICK_S: Final = 0.5
HEALTH_EVERY_NS: Final = NS_PER_S
#: A part whose heartbeat is older than this is stuck (reads time out every 50 ms in a
#: handshake and every 200 ms while streaming, the recorder wakes every 200 ms; a handshake
#: write may block for its 1 s timeout).
STUCK_NS: Final = 10 * NS_PER_S


def run_name(robot: str, wall_ns: int) -> str:
    stamp = dt.datetime.fromtimestamp(wall_ns / NS_PER_S, tz=dt.UTC)
    return f"{robot}_{stamp:%Y%m%dT%H%M%SZ}"


class Daemon:
    """One run of baromapd: build with a configuration, :meth:`run` until :meth:`request_stop`."""

    def __init__(
        self,
        config: DaemonConfig,
        *,
        clock: HostClock | None = None,
        notifier: Notifier | None = None,
        resolve: Callable[[str], str] = resolve_port,
        live: bool = True,
    ) -> None:
        self.config = config
        self.clock = clock or HostClock()
        self.notifier = notifier or Notifier(environ={})
        self.fanout = Fanout()
        self._stop = threading.Event()
        self.name = run_name(config.robot, self.clock.now_unix_ns())
        mount = None
        if config.laser is not None:
            m = config.laser.mount
            mount = LaserMount(m.x_m, m.y_m, m.yaw_rad)
        self.recorder = Recorder(
            config.recording,
            robot=config.robot,
            metadata=self._metadata(),
            run_name=self.name,
            laser_mount=mount,
        )
        self.fanout.subscribe(self.recorder)
        self.floors: FloorTracker | None = None
        if config.barometer is not None:
            self.floors = FloorTracker(config.floors, self.fanout.publish)
            self.fanout.subscribe(self.floors)
        self.live: Consumer | None = self._live_publisher() if live else None
        if self.live is not None:
            self.fanout.subscribe(self.live)
        common: dict[str, Any] = {
            "clock": self.clock,
            "publish": self.fanout.publish,
            "identify": self.recorder.set_metadata,
            "resolve": resolve,
        }
        self.sessions: list[DeviceSession] = []
        if config.laser is not None:
            self.sessions.append(Lms200Session(config.laser, **common))
        if config.base is not None:
            self.sessions.append(PioneerSession(config.base, **common))
        if config.barometer is not None:
            self.sessions.append(BarometerSession(config.barometer, **common))
        self._last_health_ns = 0
        self.watchdog_pings = 0
        self.ready = threading.Event()

    def _metadata(self) -> dict[str, str]:
        c = self.config
        data = {
            "role": c.role,
            "daemon": f"baromapd {__version__}",
            "configuration": c.source_text,
            "devices": json.dumps(
                {
                    name: device.port
                    for name, device in (
                        ("laser", c.laser),
                        ("base", c.base),
                        ("barometer", c.barometer),
                    )
                    if device is not None
                }
            ),
        }
        data.update(self.clock.metadata())
        return data

    def _live_publisher(self) -> Consumer | None:
        """The Zenoh publisher, started (None when ``[zenoh] enabled = false``)."""
        reference = self._reference if self.floors is not None else None
        return create_publisher(self.config, reference=reference)

    def _reference(self, sample: PressureSample) -> None:
        """A reference station's sample (on a Zenoh thread): to the detector, and recorded."""
        self.recorder.offer_reference(sample)
        if self.floors is not None:
            self.floors.offer_reference(sample)

    # ---- lifetime -------------------------------------------------------------------------------
    def request_stop(self) -> None:
        """Ask the main loop to finish (safe from a signal handler)."""
        self._stop.set()

    def run(self) -> int:
        self.start()
        try:
            while not self._stop.wait(TICK_S):
                self.tick()
        finally:
            self.shutdown()
        return 0

    def start(self) -> None:
        # Everything imported and built so far lives as long as the daemon: out of the
        # collector's way, a full collection no longer walks the ~55 000 objects of the
        # libraries (30-40 ms with the GIL held, every thread stopped, measured) while a
        # reader has bytes waiting.
        gc.collect()
        gc.freeze()
        self.recorder.start()
        if self.floors is not None:
            self.floors.start()
        for session in self.sessions:
            session.start()
        self.notifier.ready(self.status_line())
        self.ready.set()
        log.info("baromapd running", run=self.name, devices=[s.name for s in self.sessions])

    def shutdown(self) -> None:
        self.notifier.stopping("stopping: closing devices and finishing the recording")
        for session in self.sessions:
            session.stop()
        self._publish_health()
        if self.floors is not None:
            self.floors.close()
        if self.live is not None:
            self.fanout.unsubscribe(self.live)
            self.live.close()
        self.recorder.close()
        gc.unfreeze()  # a process that goes on (the tests) collects as before
        log.info("baromapd stopped", files=[str(p) for p in self.recorder.files])

    # ---- the main loop --------------------------------------------------------------------------
    def tick(self) -> None:
        now = time.monotonic_ns()
        if now - self._last_health_ns >= HEALTH_EVERY_NS:
            self._last_health_ns = now
            self._publish_health()
        self.notifier.status(self.status_line())
        stuck = self.stuck_parts(now)
        if stuck:
            log.error("parts are not making progress: no watchdog ping", parts=stuck)
        elif self.notifier.watchdog_s is not None and self.notifier.watchdog():
            self.watchdog_pings += 1

    def stuck_parts(self, now_ns: int) -> list[str]:
        stuck = [s.name for s in self.sessions if not s.alive or now_ns - s.heartbeat_ns > STUCK_NS]
        workers = [self.recorder] + ([self.floors] if self.floors is not None else [])
        stuck += [w.name for w in workers if not w.alive or now_ns - w.heartbeat_ns > STUCK_NS]
        return stuck

    def health(self) -> list[DeviceHealth]:
        t = self.clock.now_unix_ns()
        out = [s.health(t) for s in self.sessions] + [self.recorder.health(t)]
        live_health = getattr(self.live, "device_health", None)
        if live_health is not None:  # the Zenoh publisher's state and counters
            out.append(live_health(t))
        return out

    def _publish_health(self) -> None:
        for health in self.health():
            self.fanout.publish(health)

    def status_line(self) -> str:
        parts = []
        for health in self.health():
            text = f"{health.device} {health.state.value}"
            if health.state in (DeviceState.DOWN, DeviceState.DEGRADED):
                text += f" ({health.detail[:60]})"
            parts.append(text)
        return "; ".join(parts)

    def publish(self, message: Message) -> None:
        self.fanout.publish(message)
