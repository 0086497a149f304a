"""The live view's public socket: a thin front to the Foxglove SDK's WebSocket server.

The SDK (foxglove-sdk 0.30) speaks the Foxglove WebSocket protocol but accepts only the
subprotocol ``foxglove.sdk.v1``; Lichtblick and Foxglove releases from before that name, and
``@foxglove/ws-protocol``'s documented client set-up, offer only ``foxglove.websocket.v1``,
and the SDK answers them HTTP 400. The two names stand for the same protocol. Its per-client
queue drops the oldest message when full, and counts nothing a daemon could report. So the SDK
listens on a private loopback port, and this front takes the viewers:

- it accepts either subprotocol, and relays each viewer over a connection of its own to the
  SDK (``foxglove.sdk.v1``), frame for frame, without decoding the messages;
- each viewer has its own bounded queue: the front always reads the SDK at once, and a viewer
  that reads slowly or not at all loses its oldest data messages, counted per viewer, while
  the others and the daemon go on (control messages, advertisements and server info, are never
  dropped: a viewer that lets ``MAX_CONTROL`` of them pile up is disconnected);
- read-only: of what a viewer sends, only ``subscribe`` and ``unsubscribe`` reach the SDK;
  publishing, parameters, services and anything else are refused and counted (the SDK also
  advertises no such capability);
- a viewer that answers no ping for ``ping_timeout_s`` is disconnected.

It runs an asyncio loop in a thread of its own (:class:`FrontThread`).
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import itertools
import json
import os
import socket
import threading
import time
from dataclasses import dataclass

import structlog
from websockets.asyncio.client import ClientConnection, connect
from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed
from websockets.typing import Subprotocol

from baromapd.osthread import name_os_thread

log = structlog.get_logger(__name__)

#: What the SDK's server accepts, and the protocol's older name (same messages).
SDK_SUBPROTOCOL = Subprotocol("foxglove.sdk.v1")
WEBSOCKET_SUBPROTOCOL = Subprotocol("foxglove.websocket.v1")
#: Offered to viewers, preferred first.
SUBPROTOCOLS = (SDK_SUBPROTOCOL, WEBSOCKET_SUBPROTOCOL)
#: The server's binary opcode of a data message (the only frames ever dropped).
MESSAGE_DATA = 0x01
#: The operations a viewer may send on.
FORWARDED_OPS = frozenset({"subscribe", "unsubscribe"})
#: Control frames a viewer may leave unread before it is disconnected.
MAX_CONTROL = 1024
#: Largest frame a viewer may send (subscriptions are a few hundred bytes).
MAX_CLIENT_FRAME = 1 << 16


@dataclass(frozen=True, slots=True)
class FrontSettings:
    host: str = "127.0.0.1"
    port: int = 8765
    #: data messages queued for one viewer, at most (75 scans a second: about 3 s)
    max_queued: int = 256
    #: bytes queued for one viewer, at most (a few live grids)
    max_queued_bytes: int = 8 << 20
    ping_interval_s: float = 20.0
    ping_timeout_s: float = 60.0
    #: the kernel's send buffer towards one viewer (bytes): what the kernel holds for a viewer
    #: that does not read is bounded too, and the rest waits in the counted queue
    socket_buffer: int = 1 << 18


@dataclass(slots=True)
class ClientStats:
    """One viewer, as diagnostics report it; counters since it connected."""

    number: int
    address: str
    subprotocol: str
    sent: int = 0
    dropped: int = 0
    refused: int = 0


class _Viewer:
    """One connected viewer's queue and counters (touched only on the loop's thread)."""

    def __init__(self, stats: ClientStats, settings: FrontSettings) -> None:
        self.stats = stats
        self.settings = settings
        self.control: collections.deque[str | bytes] = collections.deque()
        self.data: collections.deque[bytes] = collections.deque()
        self.data_bytes = 0
        self.ready = asyncio.Event()

    def put(self, frame: str | bytes) -> None:
        if isinstance(frame, bytes) and frame[:1] == bytes((MESSAGE_DATA,)):
            self.data.append(frame)
            self.data_bytes += len(frame)
            s = self.settings
            while len(self.data) > 1 and (
                len(self.data) > s.max_queued or self.data_bytes > s.max_queued_bytes
            ):
                self.data_bytes -= len(self.data.popleft())
                self.stats.dropped += 1
        else:
            if len(self.control) >= MAX_CONTROL:
                raise _TooSlow
            self.control.append(frame)
        self.ready.set()

    def take(self) -> str | bytes | None:
        if self.control:
            return self.control.popleft()
        if self.data:
            frame = self.data.popleft()
            self.data_bytes -= len(frame)
            return frame
        self.ready.clear()
        return None


class _TooSlow(Exception):
    """A viewer let MAX_CONTROL control messages pile up."""


class Front:
    """Viewers in, one SDK connection each out; ``clients()`` and the totals for diagnostics."""

    def __init__(self, upstream_url: str, settings: FrontSettings) -> None:
        self.upstream_url = upstream_url
        self.settings = settings
        self._viewers: dict[int, _Viewer] = {}
        self._numbers = itertools.count(1)
        self._server: Server | None = None
        self._lock = threading.Lock()
        #: counters of viewers that have gone, so totals never go down
        self._gone_dropped = 0
        self._gone_refused = 0
        self.served = 0

    async def start(self) -> None:
        """Listen (raises OSError when the address cannot be bound)."""
        s = self.settings
        self._server = await serve(
            self._viewer,
            s.host,
            s.port,
            subprotocols=list(SUBPROTOCOLS),
            compression=None,
            max_size=MAX_CLIENT_FRAME,
            ping_interval=s.ping_interval_s,
            ping_timeout=s.ping_timeout_s,
            server_header=None,
        )

    @property
    def port(self) -> int:
        assert self._server is not None
        port: int = next(iter(self._server.sockets)).getsockname()[1]
        return port

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()

    def clients(self) -> list[ClientStats]:
        """The connected viewers' counters (a copy; any thread)."""
        with self._lock:
            viewers = list(self._viewers.values())
        return [
            ClientStats(
                v.stats.number,
                v.stats.address,
                v.stats.subprotocol,
                v.stats.sent,
                v.stats.dropped,
                v.stats.refused,
            )
            for v in viewers
        ]

    def totals(self) -> tuple[int, int]:
        """Data messages dropped and frames refused, over every viewer so far."""
        current = self.clients()
        return (
            self._gone_dropped + sum(c.dropped for c in current),
            self._gone_refused + sum(c.refused for c in current),
        )

    async def _viewer(self, ws: ServerConnection) -> None:
        peer = ws.remote_address
        address = f"{peer[0]}:{peer[1]}" if peer else "?"
        stats = ClientStats(next(self._numbers), address, str(ws.subprotocol or ""))
        viewer = _Viewer(stats, self.settings)
        sock = ws.transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self.settings.socket_buffer)
        try:
            upstream = await connect(
                self.upstream_url,
                subprotocols=[SDK_SUBPROTOCOL],
                compression=None,
                max_size=None,
                ping_interval=None,
                # the front reads the SDK at once; its own queue is the bound
                max_queue=None,
            )
        except (TimeoutError, OSError) as exc:
            log.error("live view: the SDK's server refused a viewer", error=str(exc))
            return
        with self._lock:
            self._viewers[stats.number] = viewer
            self.served += 1
        log.info("live view viewer connected", viewer=stats.number, address=address)
        tasks = [
            asyncio.create_task(self._from_sdk(upstream, viewer)),
            asyncio.create_task(self._from_viewer(ws, upstream, viewer)),
            asyncio.create_task(self._to_viewer(ws, viewer)),
        ]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await upstream.close()
            with self._lock:
                del self._viewers[stats.number]
                self._gone_dropped += stats.dropped
                self._gone_refused += stats.refused
            log.info(
                "live view viewer gone",
                viewer=stats.number,
                sent=stats.sent,
                dropped=stats.dropped,
                refused=stats.refused,
            )

    async def _from_sdk(self, upstream: ClientConnection, viewer: _Viewer) -> None:
        with contextlib.suppress(ConnectionClosed, _TooSlow):
            async for frame in upstream:
                viewer.put(frame)

    async def _from_viewer(
        self, ws: ServerConnection, upstream: ClientConnection, viewer: _Viewer
    ) -> None:
        with contextlib.suppress(ConnectionClosed):
            async for frame in ws:
                if isinstance(frame, str) and _operation(frame) in FORWARDED_OPS:
                    await upstream.send(frame)
                else:
                    viewer.stats.refused += 1

    async def _to_viewer(self, ws: ServerConnection, viewer: _Viewer) -> None:
        with contextlib.suppress(ConnectionClosed):
            while True:
                frame = viewer.take()
                if frame is None:
                    await viewer.ready.wait()
                    continue
                # waits while the viewer's socket is full: this viewer's queue fills, no other
                await ws.send(frame)
                viewer.stats.sent += 1


def _operation(text: str) -> str | None:
    try:
        data = json.loads(text)
    except ValueError:
        return None
    op = data.get("op") if isinstance(data, dict) else None
    return op if isinstance(op, str) else None


class FrontThread:
    """The front's event loop in a thread of its own."""

    def __init__(self, upstream_url: str, settings: FrontSettings) -> None:
        self.front = Front(upstream_url, settings)
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._run, name="baromapd-view-front", daemon=True)
        self._started = threading.Event()
        self._error: str | None = None
        self._stop: asyncio.Event | None = None

    def start(self, timeout_s: float = 30.0) -> str | None:
        """Bind and serve; returns why binding failed, or None once it is listening."""
        self._thread.start()
        if not self._started.wait(timeout_s):
            return f"the front did not start within {timeout_s:g} s"
        return self._error

    @property
    def port(self) -> int:
        return self.front.port

    def _run(self) -> None:
        name_os_thread()
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._main())
        finally:
            self._loop.close()

    async def _main(self) -> None:
        self._stop = asyncio.Event()
        try:
            await self.front.start()
        except OSError as exc:
            where = f"{self.front.settings.host}:{self.front.settings.port}"
            reason = os.strerror(exc.errno) if exc.errno else str(exc)
            self._error = f"cannot listen on {where}: {reason}"
            self._started.set()
            return
        self._started.set()
        await self._stop.wait()
        await self.front.stop()

    def stop(self, timeout_s: float = 5.0) -> None:
        if self._stop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
        deadline = time.monotonic() + timeout_s
        self._thread.join(max(0.0, deadline - time.monotonic()))
