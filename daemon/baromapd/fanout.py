"""The one place every message goes through: readers publish, consumers are offered it.

A consumer (the recorder, the live Zenoh publisher) implements ``offer(message)``, which must
never block: each keeps its own bounded queue and counts what it had to drop, so a slow disk
or a slow network can never stall a device's reader thread. A consumer that measures latency
from the wire may also implement ``offer_received(message, received_ns)`` (host monotonic ns
at which the frame's last byte was read); the fanout then calls that instead. A consumer that
wants only some message types says so in ``accepts`` (a tuple of types): the fanout then never
calls it with others (75 scans a second go to the recorder only, not through two more calls
that would ignore them).

A *stage* (the floor tracker) turns messages into others: ``process(message)`` returns what
it made of one (floor events and states), ``finish()`` what it makes of the end of the input.
The fanout hands a stage's output to the consumers, never to a stage, so the flow is one-way:
readers -> fanout -> consumers, and readers -> fanout -> stage -> consumers. The floor
tracker does its work in ``process``, on the reader's thread (``daemon/baromapd/floors.py``
says why): a few microseconds of arithmetic per sample, where a queue and a thread of its
own cost a wake-up per sample.

This is the reader threads' hot path, so it is lean: routes per message type are worked out
once, and the queues are :class:`queue.SimpleQueue` (a put is one C call that never waits;
``queue.Queue`` takes two Python-level conditions and a lock per put and per get).
"""

from __future__ import annotations

import queue
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

import structlog

from baromap.messages import Message
from baromapd.osthread import name_os_thread

log = structlog.get_logger(__name__)


class Consumer(Protocol):
    def offer(self, message: Message) -> None:
        """Take the message or count it as dropped; never block."""

    def close(self) -> None:
        """Finish: process what was offered, release resources."""


class Stage(Protocol):
    #: The message types it takes (the fanout never calls it with others).
    accepts: tuple[type, ...]

    def process(self, message: Message) -> list[Message]:
        """What the message makes: handed to the consumers, never back to a stage."""

    def finish(self) -> list[Message]:
        """What the end of the input makes (a decision in progress)."""


@runtime_checkable
class TimedConsumer(Protocol):
    def offer_received(self, message: Message, received_ns: int) -> None: ...


_Offer = Callable[[Message], None]
_Route = tuple[tuple[_Offer, Callable[[Message, int], None] | None], ...]


class Fanout:
    """Hands every published message to every subscribed consumer that accepts its type, in
    subscription order, then to every attached stage that accepts it, whose output goes to
    the consumers."""

    def __init__(self) -> None:
        self._targets: tuple[Consumer, ...] = ()
        self._stages: tuple[Stage, ...] = ()
        self._routes: dict[type, tuple[_Route, tuple[Callable[[Message], list[Message]], ...]]]
        self._routes = {}
        self._lock = threading.Lock()

    def subscribe(self, consumer: Consumer) -> None:
        with self._lock:
            self._targets = (*self._targets, consumer)
            self._routes = {}

    def unsubscribe(self, consumer: Consumer) -> None:
        with self._lock:
            self._targets = tuple(t for t in self._targets if t is not consumer)
            self._routes = {}

    def attach(self, stage: Stage) -> None:
        with self._lock:
            self._stages = (*self._stages, stage)
            self._routes = {}

    def _route(self, cls: type) -> tuple[_Route, tuple[Callable[[Message], list[Message]], ...]]:
        consumers = tuple(
            (c.offer, c.offer_received if isinstance(c, TimedConsumer) else None)
            for c in self._targets
            if _accepts(c, cls)
        )
        stages = tuple(s.process for s in self._stages if _accepts(s, cls))
        self._routes[cls] = (consumers, stages)
        return consumers, stages

    def publish(self, message: Message, received_ns: int | None = None) -> None:
        route = self._routes.get(type(message))
        if route is None:
            route = self._route(type(message))
        consumers, stages = route
        for offer, timed in consumers:
            if timed is not None and received_ns is not None:
                timed(message, received_ns)
            else:
                offer(message)
        for process in stages:
            for made in process(message):
                self._to_consumers(made)

    def finish_stages(self) -> None:
        """The input has ended (the readers stopped): what the stages make of that goes to
        the consumers."""
        for stage in self._stages:
            for made in stage.finish():
                self._to_consumers(made)

    def _to_consumers(self, message: Message) -> None:
        route = self._routes.get(type(message))
        if route is None:
            route = self._route(type(message))
        for offer, _ in route[0]:
            offer(message)


def _accepts(consumer: object, cls: type) -> bool:
    accepts: tuple[type, ...] | None = getattr(consumer, "accepts", None)
    return accepts is None or issubclass(cls, accepts)


_STOP = object()


class QueueWorker:
    """A bounded queue served by one thread: the building block of the daemon's consumers.

    ``offer`` never blocks; a full queue drops the message and counts it by type. The worker
    calls :meth:`handle` per item and :meth:`idle` at least every ``idle_s``.
    """

    def __init__(self, name: str, maxsize: int, idle_s: float = 0.2) -> None:
        self.name = name
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._maxsize = maxsize
        self._idle_s = idle_s
        self._thread: threading.Thread | None = None
        self.dropped: Counter[str] = Counter()
        self.heartbeat_ns = time.monotonic_ns()
        self.error: str | None = None

    def offer(self, message: Message) -> None:
        self._put((message, None))

    def offer_received(self, message: Message, received_ns: int) -> None:
        self._put((message, received_ns))

    def _put(self, item: tuple[Message, int | None] | tuple[Message, int | None, str]) -> None:
        # Readers of several devices may pass the size check at once: the bound can be
        # overshot by a message per reader, which is all it needs to be (bounded, never wait).
        if self._queue.qsize() >= self._maxsize:
            self.dropped[type(item[0]).__name__] += 1
        else:
            self._queue.put(item)

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=f"baromapd-{self.name}")
        self._thread.start()

    def close(self, timeout: float = 10.0) -> None:
        """Process everything offered so far, then stop the thread."""
        if self._thread is None:
            return
        self._queue.put(_STOP)
        self._thread.join(timeout)
        self._thread = None

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def backlog(self) -> int:
        return self._queue.qsize()

    def _run(self) -> None:
        name_os_thread()
        try:
            self.started()
            while True:
                try:
                    item = self._queue.get(timeout=self._idle_s)
                except queue.Empty:
                    item = None
                self.heartbeat_ns = time.monotonic_ns()
                if item is _STOP:
                    break
                if item is not None:
                    self.handle(*item)
                self.idle()
        except Exception as exc:
            self.error = f"{type(exc).__name__}: {exc}"
            log.exception("consumer failed", consumer=self.name)
            raise
        finally:
            self.finished()

    def started(self) -> None:
        """In the worker thread, before the first item."""

    def handle(self, message: Message, received_ns: int | None) -> None:
        raise NotImplementedError

    def idle(self) -> None:
        """After each item and at least every ``idle_s``."""

    def finished(self) -> None:
        """In the worker thread, after the last item."""
