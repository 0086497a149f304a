"""Print the payload examples of ``docs/zenoh.md`` as they come off the wire.

A simulated run goes through the online floor detector into the daemon's publisher; a Zenoh
subscriber in this process keeps the first sample of every key (the last floor event and ride) and
asks the state queryable, and what it received is printed as Markdown. Paste it between the
markers in the doc; ``test_zenoh_doc.py`` checks the doc's examples are still real payloads.

    .venv/bin/python tests/live/doc_examples.py
"""

from __future__ import annotations

import json
import socket
import time

import zenoh

from baromap import logs
from baromap.floors import OnlineFloorDetector
from baromap.live.session import close_session, open_session
from baromap.live.settings import LiveSettings
from baromap.messages import DeviceHealth, DeviceState, PressureSample
from baromap.sim.scenario import pressure_run
from baromapd.live import LivePublisher

ROBOT = "pioneer-1"


def main() -> None:
    logs.configure("console", "WARNING")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    publisher = LivePublisher(LiveSettings(listen=(endpoint,)), ROBOT)
    publisher.start()
    while publisher.health()["state"] != "open":
        time.sleep(0.01)
    seen: dict[str, tuple[str, bytes]] = {}

    def keep(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if key not in seen or key.endswith(("/floor/event", "/floor/ride")):
            seen[key] = (str(sample.encoding), sample.payload.to_bytes())

    session = open_session(LiveSettings.client((endpoint,)))
    session.declare_subscriber("baromap/**", keep)
    time.sleep(0.5)
    run = pressure_run(0, floors=3, minutes=6, rate_hz=25.0)
    detector = OnlineFloorDetector()
    for i, (t, p, c) in enumerate(
        zip(run.t_ns.tolist(), run.pressure_pa.tolist(), run.temperature_c.tolist(), strict=True)
    ):
        sample = PressureSample(t, p, c, seq=i % 65536)
        publisher.offer(sample)
        for event in detector.update(sample):
            publisher.offer(event)
        if i % 5 == 0:
            publisher.offer(detector.state())
        if i % 25 == 0:
            publisher.offer(
                DeviceHealth(
                    t, "baro", DeviceState.UP, "/dev/baromap-baro", "", {"frames": i, "crc": 0}
                )
            )
        if i % 250 == 0:
            time.sleep(0.01)
    time.sleep(1.5)
    answers = [
        (str(r.ok.key_expr), str(r.ok.encoding), r.ok.payload.to_bytes())
        for r in session.get(f"baromap/{ROBOT}/floor/state", timeout=5.0)
        if r.ok is not None
    ]
    close_session(session)
    publisher.stop()

    for key in sorted(seen):
        encoding, payload = seen[key]
        print(f"`{key}` (encoding `{encoding}`):\n")
        print("```json\n" + json.dumps(json.loads(payload), indent=2) + "\n```\n")
    for key, encoding, payload in answers:
        print(f"Reply of the queryable `{key}` (encoding `{encoding}`):\n")
        print("```json\n" + json.dumps(json.loads(payload), indent=2) + "\n```\n")


if __name__ == "__main__":
    main()
