"""The daemon's live publisher: what baromapd records also reaches ``baromap watch``."""

from __future__ import annotations

import socket
import time

import pytest
from daemon_rig import Rig, RunningDaemon, config_text

from baromap.live.keys import Channel
from baromap.live.settings import LiveSettings
from baromap.live.watch import FloorWatch, HealthReport, PressureReport, RobotGone, RobotUp
from baromap.messages import DeviceState
from baromapd.app import Daemon
from baromapd.config import parse_config


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.allow_leaks  # Zenoh's runtime keeps its threads for the life of the process
def test_health_and_pressure_reach_a_watcher(rig: Rig) -> None:
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    text = config_text(rig).replace(
        "[zenoh]\nenabled = false", f'[zenoh]\nlisten = ["{endpoint}"]\npressure_period_s = 0.2'
    )
    config = parse_config(text)
    seen: dict[str, DeviceState] = {}
    pressure = 0
    gone = False
    watch = FloorWatch(
        LiveSettings.client((endpoint,)), "test", channels=(Channel.HEALTH, Channel.PRESSURE)
    )
    with RunningDaemon.live(config) as run:
        run.wait_up()
        with watch.open():
            deadline = time.monotonic() + 20
            up = False
            while time.monotonic() < deadline and not (
                up and pressure >= 3 and {"laser", "base", "barometer"} <= set(seen)
            ):
                report = watch.next(timeout=0.5)
                if isinstance(report, RobotUp):
                    up = True
                elif isinstance(report, HealthReport):
                    seen[report.health.device] = report.health.state
                elif isinstance(report, PressureReport):
                    pressure += 1
            run.stop()
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and not gone:
                gone = isinstance(watch.next(timeout=0.5), RobotGone)
    assert up and pressure >= 3
    assert {seen[d] for d in ("laser", "base", "barometer")} <= {
        DeviceState.UP,
        DeviceState.DEGRADED,
    }
    assert gone, "the liveliness token goes when the daemon stops"


def test_zenoh_disabled_in_the_configuration_leaves_no_publisher(rig: Rig) -> None:
    daemon = Daemon(parse_config(config_text(rig)), live=True)  # config_text: enabled = false
    assert daemon.live is None
    assert "zenoh" not in {h.device for h in daemon.health()}
