"""A fleet on loopback, every part its own process: a Zenoh router, two robots publishing
their floors, two ``baromap watch`` subscribers that see them only through the router.

Until the daemon drives the publisher, a robot is ``nodes.py robot``: a simulated run through
the online detector into :class:`daemon.live.LivePublisher`, offered as the daemon offers.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from procs import Child, endpoint, free_port

ROBOTS = {"r1": 1, "r2": 2}  # robot id -> simulation seed


@pytest.fixture
def children(tmp_path: Path) -> Iterator[list[Child]]:
    started: list[Child] = []
    yield started
    for child in reversed(started):
        child.close(interrupt=child.name.startswith("watch"))


def reports(child: Child, kind: str, robot: str | None = None) -> list[dict[str, Any]]:
    return [
        line
        for line in child.lines
        if line.get("report") == kind and (robot is None or line.get("robot") == robot)
    ]


def test_every_watcher_gets_every_event_of_every_robot_through_a_router(
    tmp_path: Path, children: list[Child]
) -> None:
    router_ep = endpoint(free_port())
    router = Child.node("router", ["router", "--listen", router_ep], tmp_path)
    children.append(router)
    router.expect(lambda line: "ready" in line, 20, "router ready")

    robots = {}
    for robot, seed in ROBOTS.items():
        args = ["robot", robot, "--seed", str(seed), "--listen", endpoint(free_port())]
        robots[robot] = Child.node(robot, [*args, "--connect", router_ep], tmp_path)
        children.append(robots[robot])
    for robot, child in robots.items():
        child.expect(lambda line, r=robot: line.get("ready") == r, 60, "robot ready")

    watchers = [
        Child.watch(name, ["--connect", router_ep, "--states"], tmp_path)
        for name in ("watch-a", "watch-b")
    ]
    children.extend(watchers)
    for watcher in watchers:
        # both robots answered the state question through the router: subscribed everywhere
        answered = watcher.expect(lambda line: line.get("report") == "answered", 30, "answers")
        assert answered["robots"] == sorted(ROBOTS)
        for robot in ROBOTS:
            assert reports(watcher, "online", robot), f"{robot} not seen online"
            (state,) = reports(watcher, "state", robot)
            assert state["state"]["floor_id"] is None  # one sample in: no floor yet

    for child in robots.values():
        child.send("go")
    published = {
        robot: child.expect(lambda line, r=robot: line.get("done") == r, 120, "run done")
        for robot, child in robots.items()
    }
    for robot, done in published.items():
        assert len(done["events"]) >= 2, f"{robot}'s run decided too few transitions to test"
        assert done["health"]["dropped_urgent"] == 0

    for watcher in watchers:
        for robot, done in published.items():
            last = done["events"][-1]
            watcher.expect(
                lambda line, r=robot, e=last: (
                    line.get("report") == "event" and line["robot"] == r and line["event"] == e
                ),
                30,
                f"{robot}'s last event",
            )
            got = [line["event"] for line in reports(watcher, "event", robot)]
            assert got == done["events"], f"{watcher.name} saw {robot}'s events differently"

    # A late joiner, through the router, is told each robot's floor at once.
    late = Child.watch("watch-late", ["--connect", router_ep, "--seconds", "60"], tmp_path)
    children.append(late)
    late.expect(lambda line: line.get("report") == "answered", 30, "late answers")
    for robot, done in published.items():
        (state,) = reports(late, "state", robot)
        assert state["state"]["floor_id"] == done["state"]["floor_id"] is not None
        assert state["state"]["floor_id"] == done["events"][-1]["to_id"]

    # A robot that dies is reported gone by liveliness; one that stops cleanly too.
    robots["r1"].kill()
    for watcher in [*watchers, late]:
        watcher.expect(
            lambda line: line.get("report") == "gone" and line["robot"] == "r1", 30, "r1 gone"
        )
    assert robots["r2"].close() == 0
    stopped = robots["r2"].expect(lambda line: "stopped" in line, 5, "r2 stopped")
    assert stopped["health"]["state"] == "stopped"
    for watcher in watchers:
        watcher.expect(
            lambda line: line.get("report") == "gone" and line["robot"] == "r2", 30, "r2 gone"
        )
        assert watcher.close(interrupt=True) == 130  # Ctrl-C: the watch ends cleanly
        assert not reports(watcher, "unreadable")
