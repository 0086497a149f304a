"""The live view's own process: the SDK's WebSocket server, its front, and the live map.

Started by :class:`baromapd.liveview.LiveView` with one end of a socket pair. The daemon sends
every message it records down the pair, one pickled message per packet, without ever waiting
(:mod:`baromapd.liveview` says why and how); here they are logged to the view's channels
(:class:`~baromap.liveview.channels.ViewChannels`) in the order they came, and the map's share
(odometry, scans, floor states) is handed to the live map's thread through a bounded queue
that forgets the oldest when the map falls behind. Once a second this process sends its
report back up the pair: where it serves, its viewers with their counters, the map's state,
CPU and memory; the daemon turns it into the ``live_view`` entry of ``/diagnostics``.

The process ends when the daemon closes its end (or dies: the pair then reads as closed), and
when it cannot bind its address: it says so in its one report and exits, and the daemon
records on without a view.

    python -m baromapd.liveview_child --fd N --settings JSON
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import logging
import pickle
import signal
import socket
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import asdict
from typing import Any, Final

import foxglove
import structlog

from baromap import logs
from baromap.liveview.channels import ViewChannels
from baromap.liveview.floor_map import LiveFloorMap, LiveMapSettings
from baromap.messages import FloorState, LaserScan, Message, Odometry
from baromap.recording.frames import LaserMount
from baromapd.liveview import ChildSettings
from baromapd.liveview_front import FrontSettings, FrontThread
from baromapd.osthread import name_os_thread

log = structlog.get_logger(__name__)

#: Largest packet the daemon sends (a pickled scan is about 3 kB; a DeviceHealth less).
MAX_PACKET: Final = 1 << 20
#: The live map's queue: about three seconds of the laser, the base and floor states.
MAP_QUEUE: Final = 300
#: The live map is published this often (s): the issue's floor is 0.5 Hz.
MAP_EVERY_S: Final = 1.0
#: A report to the daemon this often (s).
REPORT_EVERY_S: Final = 1.0


class MapWorker:
    """The live map's thread: takes odometry, scans and floor states in order, publishes the
    map every ``MAP_EVERY_S``; when it falls behind, the oldest waiting messages are forgotten
    (counted): the map only ever needs the newest."""

    def __init__(self, channels: ViewChannels, floor_map: LiveFloorMap) -> None:
        self.channels = channels
        self.map = floor_map
        self._queue: collections.deque[Message] = collections.deque()
        self._lock = threading.Condition()
        self._stop = False
        self.dropped = 0
        self.keyframes = 0
        self.published = 0
        self.cpu_s = 0.0
        self.error: str | None = None
        self._thread = threading.Thread(target=self._run, name="baromapd-view-map", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def offer(self, message: Message) -> None:
        with self._lock:
            if len(self._queue) >= MAP_QUEUE:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(message)
            self._lock.notify()

    def stop(self) -> None:
        with self._lock:
            self._stop = True
            self._lock.notify()
        self._thread.join(5.0)

    def _run(self) -> None:
        name_os_thread()
        next_publish = time.monotonic() + MAP_EVERY_S
        try:
            while True:
                with self._lock:
                    while not self._queue and not self._stop:
                        if not self._lock.wait(max(0.0, next_publish - time.monotonic())):
                            break
                    if self._stop:
                        return
                    batch = list(self._queue)
                    self._queue.clear()
                for message in batch:
                    if isinstance(message, LaserScan):
                        if self.map.scan(message):
                            self.keyframes += 1
                    elif isinstance(message, Odometry):
                        self.map.odometry(message)
                    elif isinstance(message, FloorState):
                        self.map.floor_state(message)
                if time.monotonic() >= next_publish:
                    next_publish = time.monotonic() + MAP_EVERY_S
                    if self.map.t_ns:  # nothing to show before the first message
                        self.channels.log_map(self.map.snapshot())
                        self.published += 1
                self.cpu_s = time.thread_time()
        except Exception as exc:
            self.error = f"{type(exc).__name__}: {exc}"
            log.exception("live map failed; the view goes on without it")


def _report(pair: socket.socket, report: dict[str, Any]) -> None:
    # the daemon not reading (or gone) loses this one: the next report says the same, newer
    with contextlib.suppress(OSError):
        pair.send(pickle.dumps(report), socket.MSG_DONTWAIT)


def serve(pair: socket.socket, settings: ChildSettings) -> int:
    """Run until the daemon closes the pair; 0, or 1 when the address could not be bound."""
    context = foxglove.Context()
    mount = LaserMount(*settings.laser_mount) if settings.laser_mount is not None else None
    channels = ViewChannels(context, mount)
    sdk = foxglove.start_server(
        name=f"baromapd {settings.robot}",
        host="127.0.0.1",
        port=0,
        capabilities=[],
        context=context,
    )
    front = FrontThread(
        f"ws://127.0.0.1:{sdk.port}", FrontSettings(host=settings.host, port=settings.port)
    )
    error = front.start()
    if error is not None:
        _report(pair, {"bind_error": error})
        sdk.stop()
        return 1
    url = f"ws://{settings.host}:{front.port}"
    offset = None if mount is None else (mount.x_m, mount.y_m, mount.yaw_rad)
    floor_map = LiveFloorMap(LiveMapSettings(resolution_m=settings.resolution_m), offset)
    worker = MapWorker(channels, floor_map)
    worker.start()
    received = 0
    next_report = 0.0
    pair.settimeout(REPORT_EVERY_S)
    try:
        while True:
            now = time.monotonic()
            if now >= next_report:
                next_report = now + REPORT_EVERY_S
                dropped, refused = front.front.totals()
                _report(
                    pair,
                    {
                        "serving": url,
                        "clients": [asdict(c) for c in front.front.clients()],
                        "served": front.front.served,
                        "client_drops": dropped,
                        "refused": refused,
                        "received": received,
                        "map": asdict(floor_map.snapshot().info) if worker.published else None,
                        "map_error": worker.error,
                        "map_dropped": worker.dropped,
                        "map_keyframes": worker.keyframes,
                        "map_cpu_ms": round(worker.cpu_s * 1000),
                        "map_bytes": floor_map.nbytes(),
                    },
                )
            try:
                packet = pair.recv(MAX_PACKET)
            except TimeoutError:
                continue
            except ConnectionResetError:
                packet = b""  # the daemon closed its end with reports of ours unread
            if not packet:
                return 0  # the daemon closed its end
            message = pickle.loads(packet)
            received += 1
            channels.log(message)
            if isinstance(message, (LaserScan, Odometry, FloorState)):
                worker.offer(message)
    finally:
        worker.stop()
        front.stop()
        sdk.stop()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="baromapd-live-view")
    parser.add_argument("--fd", type=int, required=True, help="the daemon's socket pair end")
    parser.add_argument("--settings", required=True, help="ChildSettings as JSON")
    args = parser.parse_args(argv)
    settings = ChildSettings.from_json(args.settings)
    # as the daemon's "auto": text on a terminal, JSON lines under systemd and into pipes
    logs.configure("console" if sys.stderr.isatty() else "json", settings.log_level)
    # the SDK's and websockets' own lines (a viewer's failed handshake, each connection) stay
    # below the daemon's: the front logs viewers coming and going itself
    foxglove.set_log_level("ERROR")
    logging.getLogger("websockets").setLevel(logging.WARNING)
    # the daemon ends this process by closing the pair; Ctrl-C on a terminal reaches the
    # daemon, which finishes its recording first
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    pair = socket.socket(fileno=args.fd)
    try:
        return serve(pair, settings)
    finally:
        pair.close()


if __name__ == "__main__":
    raise SystemExit(main())
