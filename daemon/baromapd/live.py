"""The daemon's Zenoh publisher: one consumer of the daemon's fan-out, off the acquisition path.

``offer(message)`` is all a reader or the detector ever calls: it files the message in a
bounded queue under a lock held for an append, and returns. One worker thread owns the Zenoh
session and does the rest (:class:`~baromap.live.schedule.PublishSchedule` decides what goes
out and when). Whatever Zenoh does (a router that is down, a handshake that hangs, a
subscriber that stops reading and fills the socket) stalls at most that worker; the queue then
fills and further messages are dropped and counted, and acquisition and recording never wait.

Floor events and states have their own small queue ahead of the bulk of pressure and health,
so a backlog of pressure never costs an event. Pressure alone does not wake the worker (it has
no latency target and is published as block means): the worker takes it within
:data:`PRESSURE_HOLD_S`, which saves a thread wake-up per barometer sample. A session that
cannot be opened is retried with capped backoff; messages that arrive meanwhile still update
what the queryable will answer, and their publications are counted as unsent.

A client's session stays open while its router is gone (Zenoh reconnects by itself), and
its puts then go nowhere: the worker asks the session for its routers and peers every
:data:`LINK_CHECK_S`, and health says ``no router`` (down) while it has none, logged when
that changes.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Protocol

import structlog

from baromap.errors import ConfigError
from baromap.live.keys import Channel, NodeKeys
from baromap.live.payloads import MEDIA_TYPE, encode, schema_of
from baromap.live.reference import ReferenceListener
from baromap.live.schedule import Outgoing, PublishSchedule
from baromap.live.session import LiveError, close_session, open_session
from baromap.live.settings import LiveSettings, ReferenceSettings
from baromap.messages import (
    DeviceHealth,
    DeviceState,
    FloorEvent,
    FloorState,
    PressureSample,
    RideEvent,
)
from baromapd.osthread import name_os_thread

if TYPE_CHECKING:
    import zenoh

log = structlog.get_logger(__name__)

#: Events and states waiting for the worker (they come a few a minute; this is a long outage).
URGENT_QUEUE = 256
#: First wait before opening a session again after a failure, s (doubled up to retry_max_s).
RETRY_FIRST_S = 0.25
#: Longest a pressure sample waits in the queue: pressure does not wake the worker (at 50 Hz
#: that would be a wake-up per sample, each to add the sample to a block mean published every
#: 0.2 s by default); the worker looks at least this often instead.
PRESSURE_HOLD_S = 0.2
#: How often a client's worker asks whether a router (or peer) is connected.
LINK_CHECK_S = 0.5
#: A client's state while no router or peer is connected: its publications reach no one.
NO_ROUTER = "no router"
#: The publisher's state as a device state (anything else, like "connecting", is degraded).
_DEVICE_STATES = {
    "open": DeviceState.UP,
    "stopped": DeviceState.DOWN,
    "failed": DeviceState.DOWN,
    "disabled": DeviceState.DOWN,
    NO_ROUTER: DeviceState.DOWN,
}


@dataclass(slots=True)
class _Counters:
    """Counters shared by the offering threads and the worker (under the publisher's lock)."""

    offered: int = 0
    ignored: int = 0
    dropped_urgent: int = 0
    dropped_bulk: int = 0
    published: int = 0
    unsent: int = 0
    publish_errors: int = 0
    queries: int = 0
    opened: int = 0
    open_failures: int = 0


class LivePublisher:
    """Publishes a robot's (or a reference station's) live data over Zenoh.

    ``LivePublisher(settings, "robot1")`` for a robot; ``station=True`` for a reference
    station (pressure and health only, under ``baromap/reference/<id>/``). Call
    :meth:`follow_reference` before :meth:`start` for a robot that has a station.
    """

    #: What the daemon's fanout offers it: scans and odometry never reach :meth:`offer`.
    accepts = PublishSchedule.ACCEPTED

    def __init__(self, settings: LiveSettings, robot_id: str, *, station: bool = False) -> None:
        self.settings = settings
        self.keys = NodeKeys.reference(robot_id) if station else NodeKeys.robot(robot_id)
        self._schedule = PublishSchedule(settings, station=station)
        self._accepted = PublishSchedule.ACCEPTED
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._urgent: collections.deque[object] = collections.deque()
        self._bulk: collections.deque[object] = collections.deque()
        self._bulk_max = settings.queue_size
        self._counters = _Counters()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._state_payload: bytes | None = None
        self._status = "disabled" if not settings.enabled else "stopped"
        self._reference: ReferenceListener | None = None

    # -- the daemon's side ---------------------------------------------------------------

    def follow_reference(self, station: str, callback: Callable[[PressureSample], None]) -> None:
        """Hand ``station``'s pressure samples to ``callback`` (called on a Zenoh thread)."""
        if self._thread is not None:
            raise ConfigError("follow_reference must be called before start()")
        if self.keys.station:
            raise ConfigError("a reference station does not follow another station")
        self._reference = ReferenceListener(station, callback)

    def start(self) -> None:
        if not self.settings.enabled or self._thread is not None:
            return
        self._status = "connecting"
        self._thread = threading.Thread(
            target=self._run, name=f"zenoh-publisher-{self.keys.node}", daemon=True
        )
        self._thread.start()

    def offer(self, message: object) -> None:
        """Take a message for publishing; never blocks (a full queue drops it, counted)."""
        with self._lock:
            counters = self._counters
            counters.offered += 1
            if not isinstance(message, self._accepted) or self._thread is None:
                counters.ignored += 1
                return
            if isinstance(message, (FloorEvent, RideEvent, FloorState)):
                if len(self._urgent) >= URGENT_QUEUE:
                    counters.dropped_urgent += 1
                    return
                self._urgent.append(message)
            else:
                if len(self._bulk) >= self._bulk_max:
                    counters.dropped_bulk += 1
                    return
                self._bulk.append(message)
                if isinstance(message, PressureSample):
                    return  # no latency target: taken within PRESSURE_HOLD_S
            self._wake.notify()

    def stop(self) -> None:
        """Stop publishing and close the session (its liveliness token goes with it).

        Waits at most ``stop_timeout_s``: a session closing while a handshake hangs can take
        Zenoh's open timeout (10 s by default) to let go.
        """
        thread = self._thread
        if thread is None:
            return
        self._stop.set()
        with self._lock:
            self._wake.notify()
        thread.join(self.settings.stop_timeout_s)
        if thread.is_alive():
            log.warning(
                "zenoh publisher did not stop in time", seconds=self.settings.stop_timeout_s
            )
        else:
            self._thread = None

    def health(self) -> Mapping[str, int | str]:
        """Counters for the daemon's ``/diagnostics`` (cumulative since start)."""
        with self._lock:
            out: dict[str, int | str] = asdict(self._counters)
            out["queued"] = len(self._urgent) + len(self._bulk)
        out["state"] = self._status
        out["mode"] = self.settings.mode.value
        out["ignored_pressure"] = self._schedule.ignored_pressure
        if self._reference is not None:
            out.update(self._reference.counters())
        return out

    def close(self) -> None:
        """The daemon's name for :meth:`stop` (every fan-out consumer has ``close``)."""
        self.stop()

    def device_health(self, t_ns: int) -> DeviceHealth:
        """The publisher as one more device of the daemon's ``/diagnostics`` and ``STATUS=``."""
        health = self.health()
        status = str(health["state"])
        state = _DEVICE_STATES.get(status, DeviceState.DEGRADED)
        detail = "" if status == "open" else status
        dropped = int(health["dropped_urgent"]) + int(health["dropped_bulk"])
        if state is DeviceState.UP and dropped:
            detail = f"{dropped} messages dropped"
        endpoints = self.settings.connect if self.settings.connect else self.settings.listen
        return DeviceHealth(
            t_ns=t_ns,
            device="zenoh",
            state=state,
            port=",".join(endpoints),
            detail=detail,
            counters={k: v for k, v in health.items() if isinstance(v, int)},
        )

    # -- the worker ----------------------------------------------------------------------

    def _run(self) -> None:
        name_os_thread()
        session = None
        try:
            session = self._open()
            if session is None:
                return
            self._serve(session)
        except Exception:
            # the worker must not die silently: say why, and let health show it stopped
            log.exception("zenoh publisher failed")
            self._status = "failed"
        finally:
            if session is not None:
                close_session(session)
            if self._status != "failed":
                self._status = "stopped"

    def _open(self) -> zenoh.Session | None:
        """Open the session, retrying with capped backoff, while messages keep flowing."""
        wait = RETRY_FIRST_S
        while not self._stop.is_set():
            try:
                session = open_session(self.settings)
            except LiveError as exc:
                with self._lock:
                    self._counters.open_failures += 1
                    failures = self._counters.open_failures
                if failures == 1:
                    log.warning("zenoh session not open yet; retrying", error=str(exc))
                deadline = time.monotonic() + wait
                while not self._stop.is_set() and time.monotonic() < deadline:
                    self._pump(None, timeout=deadline - time.monotonic())
                wait = min(wait * 2.0, self.settings.retry_max_s)
                continue
            with self._lock:
                self._counters.opened += 1
            self._status = "open"
            log.info("zenoh session open", node=self.keys.prefix, mode=self.settings.mode.value)
            return session
        return None

    def _serve(self, session: zenoh.Session) -> None:
        import zenoh

        publishers = self._declare(session)
        if not self.keys.station:
            state_encoding = zenoh.Encoding(MEDIA_TYPE).with_schema(schema_of(Channel.STATE))
            session.declare_queryable(
                self.keys.key(Channel.STATE), lambda query: self._answer(query, state_encoding)
            )
        if self._reference is not None:
            self._reference.declare(session)
        # held while serving: a token that is dropped is undeclared, and the node looks dead
        token = session.liveliness().declare_token(self.keys.key(Channel.ALIVE))
        client = self.settings.mode.value == "client"
        check_ns = 0
        while not self._stop.is_set():
            self._pump(publishers, timeout=None)
            now = time.monotonic_ns()
            if client and now >= check_ns:
                check_ns = now + int(LINK_CHECK_S * 1e9)
                self._check_link(session)
        # what was offered while the last batch went out: the detector's last event is made
        # as the readers stop, just before the daemon stops this worker
        self._pump(publishers, timeout=0.0)
        token.undeclare()  # type: ignore[no-untyped-call]

    def _check_link(self, session: zenoh.Session) -> None:
        """A client is up while a router or peer is connected; a change is logged."""
        try:
            linked = bool(list(session.info.routers_zid()) or list(session.info.peers_zid()))
        except Exception as exc:  # zenoh.ZError; a session closing under it
            log.debug("zenoh link check failed", error=str(exc))
            linked = False
        status = "open" if linked else NO_ROUTER
        if status == self._status:
            return
        self._status = status
        where = ", ".join(self.settings.connect) or "multicast scouting"
        if linked:
            log.info("zenoh router reachable again", node=self.keys.prefix, connect=where)
        else:
            log.warning(
                "zenoh router lost: publishing to no one", node=self.keys.prefix, connect=where
            )

    def _declare(self, session: zenoh.Session) -> dict[Channel, zenoh.Publisher]:
        import zenoh

        block, drop = zenoh.CongestionControl.BLOCK, zenoh.CongestionControl.DROP
        qos = {
            Channel.EVENT: (block, zenoh.Priority.INTERACTIVE_HIGH, True),
            Channel.RIDE: (block, zenoh.Priority.INTERACTIVE_HIGH, True),
            Channel.STATE: (block, zenoh.Priority.DATA_HIGH, False),
            Channel.PRESSURE: (drop, zenoh.Priority.DATA, False),
            Channel.HEALTH: (drop, zenoh.Priority.DATA_LOW, False),
        }
        publishers = {}
        for channel, (congestion, priority, express) in qos.items():
            if self.keys.station and channel in (Channel.EVENT, Channel.RIDE, Channel.STATE):
                continue
            publishers[channel] = session.declare_publisher(
                self.keys.key(channel),
                encoding=zenoh.Encoding(MEDIA_TYPE).with_schema(schema_of(channel)),
                congestion_control=congestion,
                priority=priority,
                express=express,
            )
        return publishers

    def _pump(
        self, publishers: dict[Channel, zenoh.Publisher] | None, *, timeout: float | None
    ) -> None:
        """Wait for messages or a period to end, then publish (or count unsent)."""
        schedule = self._schedule
        with self._lock:
            if not (self._urgent or self._bulk or self._stop.is_set()):
                due = schedule.next_due_ns()
                wait = PRESSURE_HOLD_S if timeout is None else min(timeout, PRESSURE_HOLD_S)
                if due is not None:
                    wait = min(wait, max(0.0, (due - time.monotonic_ns()) / 1e9))
                self._wake.wait(wait)
            batch = list(self._urgent)
            batch.extend(self._bulk)
            self._urgent.clear()
            self._bulk.clear()
        now = time.monotonic_ns()
        out: list[Outgoing] = []
        for message in batch:
            out.extend(schedule.offer(message, now))
        out.extend(schedule.due(now))
        self._publish(publishers, out)

    def _publish(
        self, publishers: dict[Channel, zenoh.Publisher] | None, out: list[Outgoing]
    ) -> None:
        published = errors = 0
        for item in out:
            payload = encode(item.message)
            if item.channel is Channel.STATE:
                self._state_payload = payload  # what the queryable answers from now on
            if publishers is None:
                continue
            try:
                publishers[item.channel].put(payload)
                published += 1
            except Exception as exc:  # zenoh.ZError; a closed session
                errors += 1
                if errors == 1:
                    log.warning("zenoh publish failed", channel=item.channel.value, error=str(exc))
        with self._lock:
            counters = self._counters
            counters.published += published
            counters.publish_errors += errors
            if publishers is None:
                counters.unsent += len(out)

    def _answer(self, query: zenoh.Query, encoding: zenoh.Encoding) -> None:
        """The state queryable: the latest state, so a late subscriber knows the floor at once."""
        payload = self._state_payload
        with self._lock:
            self._counters.queries += 1
        if payload is not None:
            query.reply(self.keys.key(Channel.STATE), payload, encoding=encoding)


class LiveConfig(Protocol):
    """What the publisher reads of the daemon's configuration (``baromapd.config`` imports
    this module to check those tables, so the publisher names the fields, not the class)."""

    @property
    def robot(self) -> str: ...
    @property
    def role(self) -> str: ...
    @property
    def zenoh(self) -> Mapping[str, Any] | None: ...
    @property
    def reference(self) -> Mapping[str, Any] | None: ...


def create_publisher(
    config: LiveConfig, *, reference: Callable[[PressureSample], None] | None = None
) -> LivePublisher | None:
    """The daemon's publisher, started, from its configuration (None: ``enabled = false``).

    A robot's ``[reference]`` station's samples go to ``reference`` (the floor tracker's
    input: called on a Zenoh thread); a station (``role = "station"``) publishes its pressure
    under ``baromap/reference/<robot>/``.
    """
    settings = LiveSettings.from_table(config.zenoh or {})
    if not settings.enabled:
        return None
    station = config.role == "station"
    publisher = LivePublisher(settings, config.robot, station=station)
    if config.reference is not None:
        follow = ReferenceSettings.from_table(config.reference)
        if reference is None:
            raise ConfigError(
                "reference.station: this node runs no floor detector for the station to correct"
            )
        publisher.follow_reference(follow.station, reference)
    publisher.start()
    return publisher


def config_problems(
    zenoh: Mapping[str, Any] | None,
    reference: Mapping[str, Any] | None,
    *,
    robot: str,
    role: str,
) -> list[tuple[str, str]]:
    """(key, message) of each problem of the ``[zenoh]`` and ``[reference]`` tables, and of
    the robot id as a Zenoh key."""
    problems = []
    keys = NodeKeys.reference if role == "station" else NodeKeys.robot
    checks: list[Callable[[], object]] = [lambda: LiveSettings.from_table(zenoh or {})]
    if robot:  # a missing id is the configuration's own problem
        checks.append(lambda: keys(robot))
    if reference is not None:
        checks.append(lambda: ReferenceSettings.from_table(reference))
        if role == "station":
            problems.append(("reference", "a station is the reference; it follows none"))
    for check in checks:
        try:
            check()
        except ConfigError as exc:
            key, _, message = str(exc).partition(": ")
            problems.append(("robot" if key.endswith(" id") else key, message))
    return problems
