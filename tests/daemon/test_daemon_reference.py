"""A reference station's pressure, received over Zenoh, is recorded on ``/reference/pressure``.

Post-run detection (``baromap detect``, ``build-maps``) corrects the robot's pressure with the
station's only if the recording has the station's samples; the live detector has them already.
A station publisher sends samples the robot's daemon follows (``[reference] station``); the
daemon's recording must hold each sample it received, with its time and pressure, on its own
topic, apart from the robot's ``/baro``.
"""

from __future__ import annotations

import socket
import time

import pytest
from daemon_rig import Rig, RunningDaemon, config_text, read_all

from baromap.live.settings import LiveSettings
from baromap.messages import NS_PER_S, PressureSample
from baromap.recording import topics
from baromapd.config import parse_config
from baromapd.live import LivePublisher

#: Station readings far from any the robot's twin reports, so they cannot be mistaken.
STATION_PA = 90_000.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _station_sample(i: int) -> PressureSample:
    return PressureSample(1_700_000_000 * NS_PER_S + i * NS_PER_S // 5, STATION_PA + i, 15.0)


@pytest.mark.allow_leaks  # Zenoh's runtime keeps its threads for the life of the process
def test_reference_samples_received_over_zenoh_are_recorded(rig: Rig) -> None:
    station_ep = f"tcp/127.0.0.1:{_free_port()}"
    text = config_text(rig, ("barometer",)).replace(
        "[zenoh]\nenabled = false",
        f'[zenoh]\nlisten = []\nconnect = ["{station_ep}"]\n[reference]\nstation = "lobby"',
    )
    station = LivePublisher(
        LiveSettings(listen=(station_ep,), pressure_period_s=0.0), "lobby", station=True
    )
    station.start()
    sent: list[PressureSample] = []
    try:
        with RunningDaemon.live(parse_config(text)) as run:
            run.wait_up(("barometer",))
            live = run.daemon.live
            assert isinstance(live, LivePublisher)

            def received() -> int:
                return int(live.health().get("reference_samples", 0))

            # Offer until the daemon's subscription has met the station (samples before that
            # are lost to the network, as they would be live), then send 20 more.
            deadline = time.monotonic() + 20
            while received() == 0 and time.monotonic() < deadline:
                sent.append(_station_sample(len(sent)))
                station.offer(sent[-1])
                time.sleep(0.05)
            assert received() > 0, "the daemon never received the station's samples"
            for _ in range(20):
                sent.append(_station_sample(len(sent)))
                station.offer(sent[-1])
            run.wait_until(lambda: received() >= 21, 20, "21 station samples received")
            count = received()
    finally:
        station.close()

    records = read_all(run.daemon.recorder.files, [topics.REFERENCE_PRESSURE, topics.BARO])
    reference = [r.message for r in records if r.topic == topics.REFERENCE_PRESSURE]
    own = [r.message for r in records if r.topic == topics.BARO]
    assert len(reference) == count  # every sample the daemon received, once
    assert set(reference) <= set(sent)
    assert reference[-20:] == sent[-20:]  # the last ones, in order, with time and pressure
    assert own and all(isinstance(m, PressureSample) for m in own)
    assert not set(own) & set(sent)  # the robot's own samples stay apart on /baro
