"""The live view as the daemon sees it: one consumer of the fan-out, and a process of its own.

Viewers (Foxglove, Lichtblick, any client of the Foxglove WebSocket protocol) see the robot
while it drives: every channel the daemon records, and a live map of the current floor. All of
that runs in a child process (:mod:`baromapd.liveview_child`): the SDK's server, the front that
takes the viewers, and the live map's scan matching, which would otherwise take the GIL from
the device readers. The recorder never waits on any of it.

The daemon's side is :meth:`LiveView.offer`, on the reader threads: a message is pickled and
sent down a ``SOCK_SEQPACKET`` socket pair without waiting (``MSG_DONTWAIT``). The pair's
kernel buffer is the bounded queue: when the child falls behind (or has not started yet) the
send fails at once and the message is counted as dropped; a packet goes whole or not at all.
Once a second (:meth:`LiveView.health`, from the main loop) the child's latest report is read
off the pair and becomes the ``live_view`` entry of ``/diagnostics``: where it serves, how many
viewers and what each lost, the map's floor, CPU and memory.

A live view that cannot bind its address says so in one log line and the daemon records on
without it; one that ends otherwise is logged once and not restarted.
"""

from __future__ import annotations

import json
import pickle
import socket
import subprocess
import sys
import threading
from dataclasses import asdict, dataclass
from typing import Any, Final

import structlog

from baromap.messages import DeviceHealth, DeviceState, Message
from baromap.recording.frames import LaserMount
from baromapd.config import LiveViewConfig

log = structlog.get_logger(__name__)

#: The pair's send buffer: about a second of the laser, the base and the barometer.
SEND_BUFFER: Final = 1 << 18
#: Largest report the child sends.
MAX_REPORT: Final = 1 << 20


@dataclass(frozen=True, slots=True)
class ChildSettings:
    """What the daemon tells its live view (JSON on the command line)."""

    robot: str
    host: str = "127.0.0.1"
    port: int = 8765
    resolution_m: float = 0.1
    laser_mount: tuple[float, float, float] | None = None
    log_level: str = "info"

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> ChildSettings:
        data = json.loads(text)
        mount = data.get("laser_mount")
        data["laser_mount"] = tuple(mount) if mount is not None else None
        return cls(**data)


class LiveView:
    """Starts the live view's process and feeds it; ``health`` for ``/diagnostics``."""

    name = "live_view"

    def __init__(self, settings: ChildSettings) -> None:
        self.settings = settings
        self.url = f"ws://{settings.host}:{settings.port}"
        self._pair, child_end = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self._pair.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER)
        self._lock = threading.Lock()
        self.sent = 0
        self.dropped = 0
        self._report: dict[str, Any] = {}
        self._state = DeviceState.STARTING
        self._detail = f"starting on {self.url}"
        self._broken = False  # a send found the child gone
        try:
            self._proc: subprocess.Popen[bytes] | None = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "baromapd.liveview_child",
                    "--fd",
                    str(child_end.fileno()),
                    "--settings",
                    settings.to_json(),
                ],
                pass_fds=(child_end.fileno(),),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
            )
        except OSError as exc:
            self._proc = None
            self._end(f"cannot start the live view's process: {exc}")
        finally:
            child_end.close()

    @classmethod
    def for_daemon(
        cls, config: LiveViewConfig, robot: str, mount: LaserMount | None, log_level: str
    ) -> LiveView:
        return cls(
            ChildSettings(
                robot=robot,
                host=config.address,
                port=config.port,
                resolution_m=config.resolution_m,
                laser_mount=None if mount is None else (mount.x_m, mount.y_m, mount.yaw_rad),
                log_level=log_level,
            )
        )

    def offer(self, message: Message) -> None:
        """Hand the message on, or count it as dropped; never waits."""
        if self._broken or self._state is DeviceState.DOWN:
            return
        try:
            self._pair.send(pickle.dumps(message, pickle.HIGHEST_PROTOCOL), socket.MSG_DONTWAIT)
        except BlockingIOError:
            with self._lock:
                self.dropped += 1
            return
        except OSError:
            self._broken = True  # the child is gone: health() says so
            return
        self.sent += 1  # a reader thread each per type; a lost increment is a count off by one

    def health(self, t_ns: int) -> DeviceHealth:
        self._read_reports()
        report = self._report
        clients: list[dict[str, Any]] = report.get("clients", [])
        counters = {
            "clients": len(clients),
            "served": int(report.get("served", 0)),
            "sent": self.sent,
            "dropped": self.dropped,
            "client_drops": int(report.get("client_drops", 0)),
            "refused": int(report.get("refused", 0)),
            "map_dropped": int(report.get("map_dropped", 0)),
            "map_keyframes": int(report.get("map_keyframes", 0)),
            "map_cpu_ms": int(report.get("map_cpu_ms", 0)),
            "map_bytes": int(report.get("map_bytes", 0)),
        }
        for client in clients:
            counters[f"client_{client['number']}_dropped"] = int(client["dropped"])
        detail = self._detail
        if self._state is DeviceState.UP:
            names = ", ".join(f"{c['number']} {c['address']}" for c in clients) or "none"
            detail = f"serving {self.url}; viewers: {names}"
            floor = (report.get("map") or {}).get("floor_name")
            if floor is not None:
                detail += f"; live map of floor {floor}"
            if report.get("map_error"):
                detail += f"; live map failed: {report['map_error']}"
        return DeviceHealth(
            t_ns=t_ns,
            device=self.name,
            state=self._state,
            port=self.url,
            detail=detail,
            counters=counters,
        )

    def _read_reports(self) -> None:
        while self._state is not DeviceState.DOWN:
            try:
                packet = self._pair.recv(MAX_REPORT, socket.MSG_DONTWAIT)
            except BlockingIOError:
                break
            except ConnectionResetError:
                # the child closed with messages unread; what it sent before is still queued
                # (the error is reported once, then the queue reads)
                continue
            except OSError:
                packet = b""
            if not packet:
                self._gone()
                break
            report = pickle.loads(packet)
            if "bind_error" in report:
                log.error(
                    "live view not served; the daemon records on without it",
                    reason=report["bind_error"],
                )
                self._end(report["bind_error"])
                break
            if self._state is DeviceState.STARTING:
                log.info("live view serving", url=report.get("serving"))
                self._state, self._detail = DeviceState.UP, ""
            self._report = report
        if self._state is not DeviceState.DOWN and (
            self._broken or (self._proc is not None and self._proc.poll() is not None)
        ):
            self._gone()

    def _gone(self) -> None:
        if self._state is DeviceState.DOWN:
            return
        code = None if self._proc is None else self._proc.poll()
        log.error("live view ended; the daemon records on without it", exit_code=code)
        self._end(f"the live view's process ended (exit {code})")

    def _end(self, why: str) -> None:
        self._state = DeviceState.DOWN
        self._detail = why
        self._report = {}

    def close(self, timeout_s: float = 5.0) -> None:
        """Close the pair (the child's cue to stop) and wait for the child."""
        self._broken = True
        self._pair.close()
        if self._proc is None:
            return
        try:
            self._proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
