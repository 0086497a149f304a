"""Watching robots' floors over Zenoh: what ``baromap watch`` shows, as typed reports.

Order of work, so nothing falls between the cracks: subscribe to events and liveliness
first, then ask the state queryables. An event decided while the question is on its way is
then seen as an event, and the answer tells the state after it (or before it: both carry
their own stamps). Liveliness with history says at once which robots are up; a robot whose
token disappears (its process died, its machine or its link went away) is reported gone, and
when its token comes back its state is asked again (as it is of a robot that comes up after
the first question was answered).

Zenoh delivers on its own threads; they only put reports on a queue, and the caller takes
them with :meth:`FloorWatch.next` on its own thread.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from baromap.errors import InputFormatError
from baromap.live.keys import Channel, robot_of, robot_selector
from baromap.live.payloads import decode
from baromap.live.session import close_session, open_session
from baromap.live.settings import LiveSettings
from baromap.messages import DeviceHealth, FloorEvent, FloorState, PressureSample, RideEvent

if TYPE_CHECKING:
    import zenoh

#: Reports waiting for the caller; a caller that stops taking them loses the newest.
MAX_PENDING = 10_000


@dataclass(frozen=True, slots=True)
class RobotUp:
    """A robot's liveliness token is there: at start (``returned`` False) or again."""

    robot: str
    returned: bool


@dataclass(frozen=True, slots=True)
class RobotGone:
    """A robot's liveliness token went away: its daemon, machine or link is down."""

    robot: str


@dataclass(frozen=True, slots=True)
class StateReport:
    """A robot's floor state: ``answered`` by its queryable, or published (change, period)."""

    robot: str
    state: FloorState
    answered: bool


@dataclass(frozen=True, slots=True)
class EventReport:
    robot: str
    event: FloorEvent


@dataclass(frozen=True, slots=True)
class RideReport:
    robot: str
    ride: RideEvent


@dataclass(frozen=True, slots=True)
class PressureReport:
    robot: str
    sample: PressureSample


@dataclass(frozen=True, slots=True)
class HealthReport:
    robot: str
    health: DeviceHealth


@dataclass(frozen=True, slots=True)
class QueryDone:
    """The state question has been answered by every robot that will (``robots``)."""

    robots: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class Unreadable:
    """A sample on a baromap key that is not what the key should carry."""

    key: str
    reason: str


WatchReport = (
    RobotUp
    | RobotGone
    | StateReport
    | EventReport
    | RideReport
    | PressureReport
    | HealthReport
    | QueryDone
    | Unreadable
)


def _published_state(robot: str, state: FloorState) -> StateReport:
    return StateReport(robot, state, answered=False)


#: The report of each published channel, from (robot, message).
_PUBLISHED: dict[Channel, Callable[[str, Any], WatchReport]] = {
    Channel.EVENT: EventReport,
    Channel.RIDE: RideReport,
    Channel.STATE: _published_state,
    Channel.PRESSURE: PressureReport,
    Channel.HEALTH: HealthReport,
}


class FloorWatch:
    """Live floor reports of one robot (``robot``) or of all of them.

    ``channels`` are the published channels to follow besides liveliness and the state
    question at start: events by default; add ``Channel.RIDE`` for rides as they start and
    end, ``Channel.STATE`` for every state publication, ``Channel.PRESSURE`` and
    ``Channel.HEALTH`` for those.
    """

    def __init__(
        self,
        settings: LiveSettings,
        robot: str | None = None,
        *,
        channels: tuple[Channel, ...] = (Channel.EVENT,),
        query_timeout_s: float = 2.0,
    ) -> None:
        for channel in channels:
            if channel not in _PUBLISHED:
                raise ValueError(f"{channel.value!r} is not a published channel")
        self.settings = settings
        self.robot = robot
        robot_selector(Channel.EVENT, robot)  # an invalid robot id fails here, not later
        self.channels = channels
        self.query_timeout_s = query_timeout_s
        self._reports: queue.Queue[WatchReport] = queue.Queue(MAX_PENDING)
        self._lock = threading.Lock()
        self._alive: set[str] = set()
        self._seen: set[str] = set()
        self._session: zenoh.Session | None = None
        self._first_answered = False
        self._first_robots: set[str] = set()  # robots that answered the first question
        self.lost = 0

    # -- lifetime ------------------------------------------------------------------------

    def open(self) -> FloorWatch:
        session = open_session(self.settings)
        self._session = session
        for channel in self.channels:
            session.declare_subscriber(
                robot_selector(channel, self.robot), self._published_handler(channel)
            )
        session.liveliness().declare_subscriber(
            robot_selector(Channel.ALIVE, self.robot), self._on_alive, history=True
        )
        self._ask_state(self.robot, first=True)
        return self

    def close(self) -> None:
        session, self._session = self._session, None
        if session is not None:
            close_session(session)

    def __enter__(self) -> FloorWatch:
        return self.open()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def next(self, timeout: float | None = None) -> WatchReport | None:
        """The next report, or None if none came within ``timeout`` seconds."""
        try:
            return self._reports.get(timeout=timeout)
        except queue.Empty:
            return None

    # -- from Zenoh's threads ------------------------------------------------------------

    def _put(self, report: WatchReport) -> None:
        try:
            self._reports.put_nowait(report)
        except queue.Full:
            self.lost += 1

    def _decode(self, channel: Channel, sample: zenoh.Sample) -> tuple[str, Any] | None:
        key = str(sample.key_expr)
        robot = robot_of(key)
        if robot is None:
            self._put(Unreadable(key, "not a robot's key"))
            return None
        try:
            return robot, decode(channel, sample.payload.to_bytes())
        except InputFormatError as exc:
            self._put(Unreadable(key, str(exc)))
            return None

    def _published_handler(self, channel: Channel) -> Callable[[zenoh.Sample], None]:
        report = _PUBLISHED[channel]

        def on_sample(sample: zenoh.Sample) -> None:
            decoded = self._decode(channel, sample)
            if decoded is not None:
                self._put(report(*decoded))

        return on_sample

    def _on_alive(self, sample: zenoh.Sample) -> None:
        import zenoh

        robot = robot_of(str(sample.key_expr))
        if robot is None:
            return
        ask = False
        with self._lock:
            if sample.kind == zenoh.SampleKind.DELETE:
                if robot not in self._alive:
                    return
                self._alive.discard(robot)
                report: WatchReport = RobotGone(robot)
            else:
                if robot in self._alive:
                    return
                self._alive.add(robot)
                returned = robot in self._seen
                self._seen.add(robot)
                report = RobotUp(robot, returned=returned)
                # one that came back, or came up after the first question was answered
                # without having answered it
                ask = returned or (self._first_answered and robot not in self._first_robots)
        self._put(report)
        if ask:
            self._ask_state(robot, first=False)

    def _ask_state(self, robot: str | None, *, first: bool) -> None:
        import zenoh

        session = self._session
        if session is None:
            return
        answered: list[str] = []

        def on_reply(reply: zenoh.Reply) -> None:
            sample = reply.ok
            if sample is None:
                return
            decoded = self._decode(Channel.STATE, sample)
            if decoded is not None:
                answered.append(decoded[0])
                self._put(StateReport(decoded[0], decoded[1], answered=True))

        def on_done() -> None:
            if first:
                with self._lock:
                    self._first_answered = True
                    self._first_robots.update(answered)
                self._put(QueryDone(tuple(sorted(set(answered)))))

        session.get(
            robot_selector(Channel.STATE, robot),
            zenoh.handlers.Callback(on_reply, on_done),
            timeout=self.query_timeout_s,
        )
