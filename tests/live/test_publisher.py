"""The daemon's publisher when Zenoh misbehaves: offer() never waits, and says what it lost.

"Recording goes on at full rate" is the daemon's bar (its recorder is the daemon's); here
the publisher's half of it: whatever Zenoh does, a caller offering messages as fast as it can
is never held, every message is either published, dropped or unsent and counted as such, and
the publisher stops within its bound.
"""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from procs import Child, endpoint, free_port

from baromap.live.settings import LiveSettings, ZenohMode
from baromap.live.watch import EventReport, FloorWatch, RobotGone, RobotUp, StateReport
from baromap.messages import (
    NS_PER_S,
    FloorEvent,
    FloorEventKind,
    FloorPhase,
    FloorState,
    Odometry,
    PressureSample,
)
from baromapd.live import URGENT_QUEUE, LivePublisher

S = NS_PER_S


def event(i: int) -> FloorEvent:
    return FloorEvent(
        t_ns=(i + 1) * S,
        event_id=i + 1,
        kind=FloorEventKind.TRANSITION,
        replaces=None,
        t_start_ns=i * S,
        t_end_ns=i * S + S // 2,
        from_id=i % 2,
        to_id=(i + 1) % 2,
        from_name=str(i % 2),
        to_name=str((i + 1) % 2),
        height_m=3.3 * ((i + 1) % 2),
        delta_pa=-40.0,
        delta_m=3.3,
        level_pa=99_960.0,
    )


def state(t_ns: int, floor: int) -> FloorState:
    return FloorState(
        t_ns=t_ns,
        phase=FloorPhase.SETTLED,
        floor_id=floor,
        name=str(floor),
        height_m=3.3 * floor,
        level_m=3.3 * floor,
        level_pa=99_960.0,
        since_ns=t_ns,
        floors_known=2,
    )


def offer_everything(publisher: LivePublisher, count: int) -> None:
    """What a daemon's fan-out does in a busy second, ``count`` times over."""
    for i in range(count):
        publisher.offer(PressureSample(i * S // 50, 100_000.0))
        publisher.offer(Odometry(i * S // 50, 0.0, 0.0, 0.0))
        if i % 10 == 0:
            publisher.offer(event(i))
            publisher.offer(state(i * S // 50, i % 2))


def wait_open(*publishers: LivePublisher) -> None:
    deadline = time.monotonic() + 20
    while any(p.health()["state"] != "open" for p in publishers):
        assert time.monotonic() < deadline, "a publisher's session did not open"
        time.sleep(0.02)


def accounted(health: dict[str, int | str]) -> None:
    """Every offer is ignored, dropped, or went through the schedule."""
    assert isinstance(health["offered"], int)
    assert health["offered"] >= int(health["ignored"]) + int(health["dropped_bulk"]) + int(
        health["dropped_urgent"]
    )


@pytest.fixture
def zenoh_file(tmp_path: Path) -> Path:
    """Zenoh gives up a handshake after 1 s instead of 10, so a stalled test ends sooner."""
    path = tmp_path / "zenoh.json5"
    path.write_text("{ transport: { unicast: { open_timeout: 1000 } } }")
    return path


def test_offer_never_waits_for_a_router_that_is_not_there() -> None:
    nowhere = endpoint(free_port())
    settings = LiveSettings(mode=ZenohMode.CLIENT, listen=(), connect=(nowhere,), retry_max_s=0.2)
    publisher = LivePublisher(settings, "r1")
    publisher.start()
    try:
        offer_everything(publisher, 20_000)
        deadline = time.monotonic() + 10
        while publisher.health()["open_failures"] < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        health = dict(publisher.health())
    finally:
        publisher.stop()
    assert health["state"] == "connecting"
    assert int(health["open_failures"]) >= 2  # it keeps trying
    assert health["offered"] == 44_000
    assert health["ignored"] == 20_000  # odometry is not published
    assert health["published"] == 0
    assert int(health["unsent"]) + int(health["dropped_bulk"]) + int(health["queued"]) > 0
    accounted(health)
    assert publisher.health()["state"] == "stopped"


def test_offer_never_waits_for_a_peer_that_accepts_and_never_answers(zenoh_file: Path) -> None:
    with socket.socket() as mute:  # the kernel completes connections; nobody ever speaks
        mute.bind(("127.0.0.1", 0))
        mute.listen(64)
        port = mute.getsockname()[1]
        for mode in (ZenohMode.CLIENT, ZenohMode.PEER):
            settings = LiveSettings(
                mode=mode,
                listen=(endpoint(free_port()),) if mode is ZenohMode.PEER else (),
                connect=(endpoint(port),),
                config_file=zenoh_file,
                retry_max_s=0.2,
            )
            publisher = LivePublisher(settings, "r1")
            publisher.start()
            try:
                offer_everything(publisher, 20_000)
                health = dict(publisher.health())
            finally:
                publisher.stop()
            assert health["offered"] == 44_000
            accounted(health)
            assert publisher.health()["state"] == "stopped"


def test_offer_never_waits_for_a_subscriber_that_stopped_reading(
    tmp_path: Path, zenoh_file: Path
) -> None:
    robot_ep = endpoint(free_port())
    settings = LiveSettings(listen=(robot_ep,), config_file=zenoh_file)
    publisher = LivePublisher(settings, "r1")
    publisher.start()
    wait_open(publisher)
    listener = Child.node(
        "listener", ["listener", "--mode", "client", "--connect", robot_ep], tmp_path
    )
    try:
        listener.expect(lambda line: "ready" in line, 30, "listener ready")
        listener.proc.send_signal(19)  # SIGSTOP: its socket fills and stays full
        offered = 0
        # Events are sent reliably (Zenoh blocks on them): enough of them fill every buffer
        # between here and the stopped process, and then the worker is stuck in Zenoh.
        for i in range(200_000):
            publisher.offer(event(i))
            offered += 1
            if publisher.health()["dropped_urgent"]:
                break
        health = dict(publisher.health())
        assert offered < 200_000, "the stopped subscriber never held the publisher up"
        assert health["queued"] == URGENT_QUEUE  # the worker is stuck; this caller is not
        for i in range(1000):  # still never held: further offers are counted drops
            publisher.offer(PressureSample(i, 100_000.0))
        assert int(publisher.health()["dropped_urgent"]) >= 1
    finally:
        listener.proc.send_signal(18)  # SIGCONT
        listener.close()
        publisher.stop()
    assert publisher.health()["state"] == "stopped"


def test_a_late_watcher_gets_the_state_then_events_then_sees_the_robot_go(
    tmp_path: Path,
) -> None:
    robot_ep = endpoint(free_port())
    publisher = LivePublisher(LiveSettings(listen=(robot_ep,)), "r1")
    publisher.start()
    try:
        wait_open(publisher)
        publisher.offer(state(S, 1))
        deadline = time.monotonic() + 10
        while publisher.health()["published"] == 0:  # the worker has taken the state
            assert time.monotonic() < deadline
            time.sleep(0.02)
        with FloorWatch(LiveSettings.client((robot_ep,)), "r1") as watch:
            first = [watch.next(10.0) for _ in range(3)]
            assert RobotUp("r1", returned=False) in first
            assert StateReport("r1", state(S, 1), answered=True) in first
            publisher.offer(event(7))
            report = watch.next(10.0)
            while report is not None and not isinstance(report, EventReport):
                report = watch.next(10.0)
            assert report == EventReport("r1", event(7))
            publisher.stop()
            report = watch.next(10.0)
            while report is not None and not isinstance(report, RobotGone):
                report = watch.next(10.0)
            assert report == RobotGone("r1")
    finally:
        publisher.stop()


def test_a_robot_following_a_station_gets_its_pressure() -> None:
    station_ep = endpoint(free_port())
    station = LivePublisher(
        LiveSettings(listen=(station_ep,), pressure_period_s=0.0), "lobby", station=True
    )
    robot = LivePublisher(LiveSettings(listen=(), connect=(station_ep,)), "r1")
    received: list[PressureSample] = []
    robot.follow_reference("lobby", received.append)
    station.start()
    robot.start()
    try:
        wait_open(robot, station)
        deadline = time.monotonic() + 20
        i = 0
        while len(received) < 5 and time.monotonic() < deadline:
            station.offer(PressureSample(i * S, 100_000.0 + i, 18.0))
            station.offer(event(i))  # a station has no floors: not published
            i += 1
            time.sleep(0.05)
        health = robot.health()
    finally:
        robot.stop()
        station.stop()
    assert len(received) >= 5
    assert all(s.pressure_pa == 100_000.0 + s.t_ns // S for s in received)
    assert health["reference_samples"] == len(received)
    assert health["reference_bad"] == 0


def test_a_publisher_that_never_started_ignores_and_stops_quietly() -> None:
    publisher = LivePublisher(LiveSettings(enabled=False), "r1")
    publisher.start()
    publisher.offer(event(1))
    publisher.stop()
    health = publisher.health()
    assert health["state"] == "disabled"
    assert health["ignored"] == 1 and health["offered"] == 1


def test_an_event_offered_as_the_daemon_stops_still_reaches_a_watcher(tmp_path: Path) -> None:
    # the detector's last event is made as the readers stop (a ride that ended with the run),
    # and offered while the worker may be busy with the batch before it: stop() must not
    # leave it in the queue, nor close the session before it went out
    robot_ep = endpoint(free_port())
    publisher = LivePublisher(LiveSettings(listen=(robot_ep,)), "r1")
    publish = publisher._publish
    busy = threading.Event()

    def slow_publish(publishers: Any, out: Any) -> None:
        if any(getattr(item.message, "event_id", 0) == 2 for item in out):
            busy.set()
            time.sleep(0.3)  # the worker in the middle of a batch
        publish(publishers, out)

    publisher._publish = slow_publish  # type: ignore[method-assign]
    publisher.start()
    try:
        wait_open(publisher)
        with FloorWatch(LiveSettings.client((robot_ep,)), "r1") as watch:
            # the watcher hears the robot's events (its subscription takes a moment to reach
            # the robot: the event is offered again until it does)
            heard = None
            for _ in range(20):
                publisher.offer(event(0))
                heard = watch.next(0.5)
                while heard is not None and not isinstance(heard, EventReport):
                    heard = watch.next(0.5)
                if heard is not None:
                    break
            assert heard == EventReport("r1", event(0))
            while watch.next(0.5) is not None:  # the repeats, if any
                pass
            publisher.offer(event(1))
            assert busy.wait(10.0)
            publisher.offer(event(2))  # while the worker publishes the one before
            publisher.stop()
            # the robot's liveliness may overtake its last data on the way (Zenoh orders by
            # priority, and a declaration goes first): the watcher reports what comes
            reports = []
            report = watch.next(3.0)
            while report is not None:
                reports.append(report)
                report = watch.next(3.0)
            assert RobotGone("r1") in reports
            assert [r for r in reports if isinstance(r, EventReport)] == [
                EventReport("r1", event(1)),
                EventReport("r1", event(2)),
            ]
    finally:
        publisher.stop()
