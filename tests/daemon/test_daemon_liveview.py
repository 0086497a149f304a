"""The daemon with its live view: viewers see what it records; a port in use costs the view,
never the recording.

The live view runs in a process of its own (``baromapd.liveview``); these tests run the real
one, with the daemon on the rig's devices and a ``websockets`` client as the viewer.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import socket
import time

import numpy as np
import pytest
import structlog
from daemon_rig import Rig, RunningDaemon, config_text, read_all
from websockets.asyncio.client import connect

from baromap import messages
from baromap.recording import topics
from baromapd.config import ConfigProblems, DaemonConfig, parse_config
from baromapd.liveview import ChildSettings, LiveView
from baromapd.liveview_front import WEBSOCKET_SUBPROTOCOL

pytestmark = pytest.mark.timeout(180)

#: The live view's process imports the SDK, numpy and scipy: slow on a loaded machine.
START_S = 60.0


def _with_view(rig: Rig, port: int) -> DaemonConfig:
    """The rig's configuration with the live view on ``port``."""
    text = config_text(rig).replace("[live_view]\nenabled = false", f"[live_view]\nport = {port}")
    return parse_config(text)


def _view_health(run: RunningDaemon) -> messages.DeviceHealth:
    (health,) = [h for h in run.daemon.health() if h.device == "live_view"]
    return health


def test_a_port_in_use_costs_the_view_and_not_the_recording(rig: Rig) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with structlog.testing.capture_logs() as logged:
            run = RunningDaemon(_with_view(rig, port))
            with run:
                run.wait_up()
                run.wait_until(
                    lambda: _view_health(run).state is messages.DeviceState.DOWN,
                    START_S,
                    "the live view gave up its port",
                )
                health = _view_health(run)
                time.sleep(1.5)  # the daemon records on; ticks go by without more lines
                assert run.states()["laser"] is messages.DeviceState.UP
    assert "cannot listen on 127.0.0.1" in health.detail
    said = [e for e in logged if e["log_level"] in ("error", "warning", "critical")]
    view_lines = [e for e in said if "live view" in e["event"]]
    assert len(view_lines) == 1, view_lines
    assert "Address already in use" in view_lines[0]["reason"]
    records = read_all(run.daemon.recorder.files, [topics.SCAN, topics.DIAGNOSTICS])
    assert sum(r.topic == topics.SCAN for r in records) > 50
    recorded = [
        r.message
        for r in records
        if isinstance(r.message, messages.DeviceHealth) and r.message.device == "live_view"
    ]
    assert recorded[-1].state is messages.DeviceState.DOWN


def test_a_viewer_sees_the_recorded_channels_and_is_counted(rig: Rig) -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with RunningDaemon(_with_view(rig, port)) as run:
        run.wait_up()
        run.wait_until(
            lambda: _view_health(run).state is messages.DeviceState.UP,
            START_S,
            "the live view serves",
        )

        async def view() -> tuple[set[str], int]:
            async with asyncio.timeout(60):
                async with connect(
                    f"ws://127.0.0.1:{port}", subprotocols=[WEBSOCKET_SUBPROTOCOL], max_size=None
                ) as ws:
                    advertised: dict[str, int] = {}
                    scans = 0
                    while scans < 20 or topics.DIAGNOSTICS not in advertised:
                        frame = await ws.recv()
                        if isinstance(frame, str):
                            message = json.loads(frame)
                            if message["op"] == "advertise":
                                fresh = {c["topic"]: c["id"] for c in message["channels"]}
                                advertised.update(fresh)
                                subscriptions = [{"id": i, "channelId": i} for i in fresh.values()]
                                await ws.send(
                                    json.dumps({"op": "subscribe", "subscriptions": subscriptions})
                                )
                        elif frame[0] == 0x01:  # data: the subscription id is the channel's
                            scans += int.from_bytes(frame[1:5], "little") == advertised.get(
                                topics.SCAN
                            )
                    # the daemon's diagnostics count this viewer
                    while _view_health(run).counters.get("clients") != 1:
                        await asyncio.sleep(0.2)
                    return set(advertised), scans

        seen, scans = asyncio.run(view())
    assert {topics.SCAN, topics.ODOM, topics.TF, topics.BARO, topics.DIAGNOSTICS} <= seen
    assert scans >= 20
    recorded = [
        r.message
        for r in read_all(run.daemon.recorder.files, [topics.DIAGNOSTICS])
        if isinstance(r.message, messages.DeviceHealth) and r.message.device == "live_view"
    ]
    assert max(h.counters["clients"] for h in recorded) == 1
    assert recorded[-1].state is messages.DeviceState.UP


def test_the_live_view_table_is_checked_with_the_rest() -> None:
    base = 'robot = "r"\n[barometer]\nport = "loop://"\n'
    config = parse_config(base)
    assert config.live_view.enabled and config.live_view.address == "127.0.0.1"
    assert config.live_view.port == 8765
    with pytest.raises(ConfigProblems) as bad:
        parse_config(
            base + '[live_view]\naddress = "robot.local"\nport = 70000\nresolution_m = 1.0\n'
            "colour = 1\n"
        )
    keys = sorted(p.key for p in bad.value.problems)
    assert keys == [
        "live_view.address",
        "live_view.colour",
        "live_view.port",
        "live_view.resolution_m",
    ]


def test_a_stopped_view_process_never_holds_the_daemon_up() -> None:
    """The view's process frozen (SIGSTOP): every offer still returns at once, what its pair
    cannot hold is counted as dropped, and nothing is lost from the count."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    view = LiveView(ChildSettings(robot="test", port=port))
    try:
        deadline = time.monotonic() + START_S
        while view.health(0).state is not messages.DeviceState.UP:
            assert time.monotonic() < deadline, view.health(0)
            time.sleep(0.2)
        assert view._proc is not None
        os.kill(view._proc.pid, signal.SIGSTOP)
        n = 5000
        ranges = np.ones(181, np.float32)
        flags = np.zeros(181, np.uint16)
        sent_before = view.sent
        for k in range(n):
            view.offer(messages.LaserScan(k + 1, -1.57, 0.0175, 80.0, ranges, flags))
        assert view.dropped > 0
        assert view.sent - sent_before + view.dropped == n
        os.kill(view._proc.pid, signal.SIGCONT)
        assert view.health(0).state is messages.DeviceState.UP
    finally:
        if view._proc is not None:
            os.kill(view._proc.pid, signal.SIGCONT)
        view.close()


def test_the_view_process_ends_cleanly_when_the_daemon_closes_with_reports_unread() -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    view = LiveView(ChildSettings(robot="test", port=port))
    deadline = time.monotonic() + START_S
    while view.health(0).state is not messages.DeviceState.UP:
        assert time.monotonic() < deadline, view.health(0)
        time.sleep(0.2)
    time.sleep(2.5)  # reports pile up in the daemon's end, unread
    view.close()
    assert view._proc is not None
    assert view._proc.returncode == 0
