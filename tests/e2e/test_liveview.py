"""The demo's live view, as a third-party client saw it while the demo ran.

``tests/liveview/js/view.js`` is ``@foxglove/ws-protocol``'s FoxgloveClient under Node,
offering only ``foxglove.websocket.v1`` (as Lichtblick and older Foxglove releases do). It
joined the address the demo printed, subscribed to every channel, decoded every message with
the schema the server sent, and wrote what it saw (``demo_run.py`` runs it beside the demo).
"""

from __future__ import annotations

import itertools
import json
from typing import Any

import pytest
from demo_run import DEMO_TIMEOUT_S, DemoRun

from baromap.recording import topics

# the first test to ask for the demo runs it (tests/e2e/conftest.py)
pytestmark = pytest.mark.timeout(DEMO_TIMEOUT_S + 120)

#: Channels a viewer must see live: the recording's, and the live map's.
LIVE_CHANNELS = (
    topics.SCAN,
    topics.ODOM,
    topics.TF,
    topics.TF_STATIC,
    topics.BARO,
    topics.FLOOR_STATE,
    topics.FLOOR_EVENT,
    topics.DIAGNOSTICS,
    "/live/map",
    "/live/path",
    "/live/map/info",
)
#: The map's floor may lag the detector's by this much (message time, s): the map is
#: published once a second, a state at least once a second of samples. Either way: the map's
#: time is its newest scan's or odometry's, and a state's its pressure sample's, which on a
#: busy machine can be stamped that much after the scans the map had when the state came.
FLOOR_LAG_S = 3.0


@pytest.fixture(scope="module")
def seen(demo: DemoRun) -> dict[str, Any]:
    if demo.viewer_skipped:
        pytest.skip(f"the Node viewer did not run: {demo.viewer_skipped}")
    assert demo.viewer.exists(), (demo.out / "viewer.log").read_text()
    data: dict[str, Any] = json.loads(demo.viewer.read_text())
    return data


def test_a_foxglove_websocket_v1_client_connects_read_only(seen: dict[str, Any]) -> None:
    assert seen["negotiated"] == "foxglove.websocket.v1"
    assert seen["serverInfo"]["capabilities"] == []
    assert seen["errors"] == []
    assert seen["closed"] == "server closed"  # it stayed until the daemon stopped


def test_every_channel_arrives_and_decodes(seen: dict[str, Any]) -> None:
    channels = seen["channels"]
    for topic in LIVE_CHANNELS:
        assert topic in channels, f"{topic} not advertised"
        counts = channels[topic]
        assert counts["messages"] > 0, f"nothing on {topic}"
        assert counts["decoded"] == counts["messages"], f"{topic}: {counts}"
    assert channels[topics.SCAN]["schemaName"] == "foxglove.LaserScan"
    assert channels["/live/map"]["schemaName"] == "foxglove.Grid"
    assert seen["scan"] == {"frame": "laser", "beams": 181}
    assert {"odom->base_link", "base_link->laser", "map->odom"} <= set(seen["transforms"])


def test_the_live_grid_grows_while_the_robot_drives(seen: dict[str, Any]) -> None:
    grids = seen["grids"]
    assert len(grids) > 20
    assert all(frame == "map" for *_, frame, _ in grids)
    known = [g[3] for g in grids]
    assert len(set(known)) > 10, "the grid hardly changed"
    # within a floor's visit, the known area only grows (grid and info share their stamp)
    floor_at = {round(t, 6): floor for t, floor, *_ in seen["mapInfos"]}
    visit = [(floor_at.get(round(g[0], 6)), g[3]) for g in grids]
    for (floor_a, a), (floor_b, b) in itertools.pairwise(visit):
        if floor_a is not None and floor_a == floor_b:
            assert b >= a


def _settled_floor_at(states: list[list[Any]], t: float) -> int | None:
    floor = None
    for t_state, floor_id, _phase in states:
        if t_state > t:
            break
        floor = floor_id
    return floor


def test_the_live_grid_follows_the_detectors_floor(seen: dict[str, Any]) -> None:
    states = seen["floorStates"]
    infos = seen["mapInfos"]
    detector = [floor for _, floor, _ in states if floor is not None]
    visits = [f for i, f in enumerate(detector) if i == 0 or f != detector[i - 1]]
    assert len(visits) >= 3, f"the mission rides between floors; the detector said {visits}"
    # before the first settled pressure the map's floor is not named yet (it is the start's)
    mapped = [floor for _, floor, *_ in infos if floor is not None]
    map_visits = [f for i, f in enumerate(mapped) if i == 0 or f != mapped[i - 1]]
    assert map_visits == visits
    # each grid is of the floor the detector decided, up to the lag of their two periods
    for t, floor, *_ in infos:
        if floor is None:
            continue
        before, now, after = (
            _settled_floor_at(states, t + d) for d in (-FLOOR_LAG_S, 0, FLOOR_LAG_S)
        )
        assert floor in (before, now, after), (
            f"grid of floor {floor} at {t}; detector {before}->{now}->{after}"
        )
    # a floor visited again is resumed, not started afresh
    revisited = {f for i, f in enumerate(map_visits) if f in map_visits[:i]}
    assert revisited, "the demo's mission revisits a floor"
    assert any(resumed for _, floor, _, resumed in infos if floor in revisited)
