"""The bar of the live floor issue, with the real daemon: a Zenoh router, two robots (each
``baromapd`` on its own simulated barometer board), two ``baromap watch`` subscribers that
know only the router; every part its own process, on loopback.

Every subscriber gets every floor event of every robot (what each daemon recorded on
``/floor/event``), a late subscriber is told each robot's floor by its queryable through the
router, and a killed robot is reported gone. The twins run 20 times faster than real time so
elevator rides come within seconds.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from procs import Child, endpoint, free_port

from baromap import jsonmsg
from baromap.recording import read_messages, topics

ROBOTS = {"r1": 11, "r2": 12}  # robot id -> simulation seed
SIM_SPEED = ("--speed", "20", "--json")


@pytest.fixture
def children() -> Iterator[list[Child]]:
    started: list[Child] = []
    yield started
    for child in reversed(started):
        child.close(interrupt=child.name.startswith("watch"), terminate=True)


def daemon_config(robot: str, baro: str, directory: Path, router: str) -> str:
    return (
        f'robot = "{robot}"\n'
        f'[recording]\ndirectory = "{directory}"\nmin_free_mb = 0\n'
        f'[barometer]\nport = "{baro}"\nrate_hz = 25\n'
        "retry_initial_s = 0.2\nretry_max_s = 1.0\nsilence_s = 1.0\n"
        f'[zenoh]\nlisten = ["{endpoint(free_port())}"]\nconnect = ["{router}"]\n'
    )


def recorded_events(directory: Path) -> list[dict[str, Any]]:
    events = []
    for path in sorted(directory.glob("*.mcap")):
        events += [jsonmsg.to_dict(r.message) for r in read_messages(path, [topics.FLOOR_EVENT])]
    return events


def events_of(watcher: Child, robot: str) -> list[dict[str, Any]]:
    return [
        line["event"]
        for line in watcher.lines
        if line.get("report") == "event" and line["robot"] == robot
    ]


def test_two_daemons_a_router_and_two_watchers(tmp_path: Path, children: list[Child]) -> None:
    router_ep = endpoint(free_port())
    router = Child.node("router", ["router", "--listen", router_ep], tmp_path)
    children.append(router)
    router.expect(lambda line: "ready" in line, 30, "router ready")
    # the subscribers first: they must hear every event from the first one on
    watchers = [
        Child.watch(name, ["--connect", router_ep, "--states"], tmp_path)
        for name in ("watch-a", "watch-b")
    ]
    children.extend(watchers)
    for watcher in watchers:
        watcher.expect(lambda line: line.get("report") == "answered", 30, "first answers")

    daemons = {}
    for robot, seed in ROBOTS.items():
        twins = Child.command(
            f"twins-{robot}",
            ["sim", "--seed", str(seed), "--floors", "3", "--minutes", "10", *SIM_SPEED],
            tmp_path,
        )
        children.append(twins)
        baro = twins.expect(lambda line: "baro" in line, 60, "twin paths")["baro"]
        config = tmp_path / f"{robot}.toml"
        config.write_text(daemon_config(robot, baro, tmp_path / robot, router_ep))
        daemons[robot] = Child(
            robot,
            [
                sys.executable,
                "-m",
                "baromapd.main",
                "--config",
                str(config),
                "--log-format",
                "json",
            ],
            tmp_path,
        )
        children.append(daemons[robot])

    for watcher in watchers:
        for robot in ROBOTS:
            watcher.expect(
                lambda line, r=robot: line.get("report") == "online" and line["robot"] == r,
                60,
                f"{robot} online",
            )
    # each robot decides at least two transitions while everyone listens
    for robot in ROBOTS:
        watchers[0].expect(
            lambda line, r=robot: len(events_of(watchers[0], r)) >= 2, 120, f"{robot}'s events"
        )

    # a late subscriber: each robot's floor at once, from its queryable, through the router
    late = Child.watch("watch-late", ["--connect", router_ep], tmp_path)
    children.append(late)
    answered = late.expect(lambda line: line.get("report") == "answered", 30, "late answers")
    assert answered["robots"] == sorted(ROBOTS)
    for robot in ROBOTS:
        (state,) = [s for s in late.lines if s.get("report") == "state" and s["robot"] == robot]
        assert state["state"]["floors_known"] >= 2

    # r2 stops cleanly (its recording is then complete); r1 is killed
    assert daemons["r2"].close(terminate=True) == 0
    daemons["r1"].kill()
    for watcher in [*watchers, late]:
        for robot in ROBOTS:
            watcher.expect(
                lambda line, r=robot: line.get("report") == "gone" and line["robot"] == r,
                30,
                f"{robot} gone",
            )

    complete = recorded_events(tmp_path / "r2")
    assert len(complete) >= 2
    partial = recorded_events(tmp_path / "r1")  # killed: the last second may be lost
    assert len(partial) >= 1
    for watcher in watchers:
        assert events_of(watcher, "r2") == complete, f"{watcher.name} missed r2's events"
        got = events_of(watcher, "r1")
        assert got[: len(partial)] == partial, f"{watcher.name} missed r1's events"
        assert len(got) <= len(partial) + 1
        assert not [line for line in watcher.lines if line.get("report") == "unreadable"]
    assert events_of(watchers[0], "r1") == events_of(watchers[1], "r1")
