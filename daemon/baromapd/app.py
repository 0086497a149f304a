"""The daemon put together: sessions -> fanout -> recorder, floor tracker, live publisher and view.

The main loop does little on purpose: once a second (or at half the watchdog interval, if
that is shorter) it checks that every part is making progress (each thread updates a
heartbeat), publishes health (recorded on ``/diagnostics``), tells systemd the device states in
``STATUS=`` when they changed, and pings the watchdog only if every part made progress. A part
that hangs therefore gets the service restarted by systemd instead of recording nothing while
claiming to be fine. ``STATUS=`` is made from the health just published, not built a second
time: each tick is one wake-up and one pass over the parts.
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
from baromap.recording import topics
from baromap.recording.frames import LaserMount
from baromapd.barometer import BarometerSession
from baromapd.clock import HostClock
from baromapd.config import DaemonConfig
from baromapd.fanout import Consumer, Fanout
from baromapd.floors import FloorTracker
from baromapd.live import create_publisher
from baromapd.liveview import LiveView
from baromapd.lms200 import Lms200Session
from baromapd.notify import Notifier
from baromapd.pioneer import PioneerSession
from baromapd.recorder import Recorder
from baromapd.session import DeviceSession

log = structlog.get_logger(__name__)

#: The main loop's period: health is published once a second; the watchdog is pinged at
#: every tick, so a shorter watchdog interval shortens it to half of that.
TICK_S: Final = 1.0
#: A part whose heartbeat is older than this is stuck (reads time out every 50 ms in a
#: handshake and every 200 ms while streaming, the recorder wakes every 200 ms; a handshake
#: write may block for its 1 s timeout).
STUCK_NS: Final = 10 * NS_PER_S
#: ``baromapd``'s exit status when the recorder gave up or its thread died (``baromapd.main``):
#: not 0, so the unit's ``Restart=on-failure`` starts a new run.
EXIT_RECORDER: Final = 3


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
        view: bool = True,
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
            self.floors = FloorTracker(config.floors)
            self.fanout.attach(self.floors)
        self.live: Consumer | None = self._live_publisher() if live else None
        if self.live is not None:
            self.fanout.subscribe(self.live)
        # the live view's process: every message, never waited for (baromapd/liveview.py)
        self.view: LiveView | None = None
        if view and config.live_view.enabled:
            self.view = LiveView.for_daemon(config.live_view, config.robot, mount, config.log_level)
            self.fanout.subscribe(self.view)
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
        self._status = ""
        self.watchdog_pings = 0
        self.ready = threading.Event()
        self.exit_code = 0

    def _metadata(self) -> dict[str, str]:
        c = self.config
        data = {
            "role": c.role,
            topics.DAEMON_KEY: f"{topics.DAEMON_NAME} {__version__}",
            "configuration": c.source_text,
            # the Pioneer session's integrator joins every new track at the last pose
            topics.ODOMETRY_TRACKS_KEY: topics.ODOMETRY_TRACKS_JOINED,
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
        tick_s = TICK_S
        if self.notifier.watchdog_s is not None:
            tick_s = min(tick_s, self.notifier.watchdog_s / 2)
        try:
            while not self._stop.wait(tick_s):
                self.tick()
        finally:
            self.shutdown()
        return self.exit_code

    def start(self) -> None:
        # Everything imported and built so far lives as long as the daemon: out of the
        # collector's way, a full collection does not walk the ~55 000 objects of the
        # libraries (30-40 ms with the GIL held, every thread stopped) while a reader has
        # bytes waiting.
        gc.collect()
        gc.freeze()
        self.recorder.start()
        for session in self.sessions:
            session.start()
        self._status = status_line(self.health())
        self.notifier.ready(self._status)
        self.ready.set()
        log.info("baromapd running", run=self.name, devices=[s.name for s in self.sessions])

    def shutdown(self) -> None:
        self.notifier.stopping("stopping: closing devices and finishing the recording")
        for session in self.sessions:
            session.stop()
        self._publish_health()
        self.fanout.finish_stages()
        if self.live is not None:
            self.fanout.unsubscribe(self.live)
            self.live.close()
        if self.view is not None:
            self.fanout.unsubscribe(self.view)
            self.view.close()
        self.recorder.close()
        gc.unfreeze()  # a process that goes on (the tests) collects as before
        log.info("baromapd stopped", files=[str(p) for p in self.recorder.files])

    # ---- the main loop --------------------------------------------------------------------------
    def tick(self) -> None:
        now = time.monotonic_ns()
        health = self._publish_health()
        status = status_line(health)
        if status != self._status:  # systemd keeps the last STATUS= until a new one
            self._status = status
            self.notifier.status(status)
        recorder = self.recorder
        if recorder.fatal is not None or not recorder.alive:
            # Recording nothing while claiming to run helps nobody: a new run, by systemd.
            log.error(
                "the recorder cannot go on: stopping",
                reason=recorder.fatal or recorder.error,
                exit_code=EXIT_RECORDER,
            )
            self.exit_code = EXIT_RECORDER
            self._stop.set()
        stuck = self.stuck_parts(now)
        if stuck:
            log.error("parts are not making progress: no watchdog ping", parts=stuck)
        elif self.notifier.watchdog_s is not None and self.notifier.watchdog():
            self.watchdog_pings += 1

    def stuck_parts(self, now_ns: int) -> list[str]:
        stuck = [s.name for s in self.sessions if not s.alive or now_ns - s.heartbeat_ns > STUCK_NS]
        recorder = self.recorder
        if not recorder.alive or now_ns - recorder.heartbeat_ns > STUCK_NS:
            stuck.append(recorder.name)
        if self.floors is not None and self.floors.error is not None:
            stuck.append(self.floors.name)  # its detector failed: no floor events any more
        return stuck

    def health(self) -> list[DeviceHealth]:
        t = self.clock.now_unix_ns()
        out = [s.health(t) for s in self.sessions] + [self.recorder.health(t)]
        live_health = getattr(self.live, "device_health", None)
        if live_health is not None:  # the Zenoh publisher's state and counters
            out.append(live_health(t))
        if self.view is not None:
            out.append(self.view.health(t))
        return out

    def _publish_health(self) -> list[DeviceHealth]:
        health = self.health()
        for device in health:
            self.fanout.publish(device)
        return health

    def publish(self, message: Message) -> None:
        self.fanout.publish(message)


def status_line(health: list[DeviceHealth]) -> str:
    """Each part's state, and why for one that is down or degraded: systemd's ``STATUS=``."""
    parts = []
    for device in health:
        text = f"{device.device} {device.state.value}"
        if device.state in (DeviceState.DOWN, DeviceState.DEGRADED):
            text += f" ({device.detail[:60]})"
        parts.append(text)
    return "; ".join(parts)
