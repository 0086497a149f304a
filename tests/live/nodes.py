"""Processes for the Zenoh tests: a router, a bare listener, and a robot without devices.

The robot is the daemon's publisher fed from a simulated run, for tests that need a robot's
events in seconds and on cue (where the daemon on twins would take a minute): the run goes
through the online floor detector, and every sample, event, state and a health message each
simulated second are offered to :class:`baromapd.live.LivePublisher`, as the daemon's fan-out
does. It talks JSON lines: ``{"ready": ...}`` once its session is open, then it waits for
``go`` on stdin, feeds the run, prints ``{"done": ..., "events": [...]}`` and waits for
``stop`` (or the end of stdin) to shut down cleanly.

    python tests/live/nodes.py router --listen tcp/127.0.0.1:PORT | --config router.json5
    python tests/live/nodes.py robot ID --listen EP --connect EP --seed 1 [--rate 3000]
    python tests/live/nodes.py robot ID --table baromapd.toml --seed 1
    python tests/live/nodes.py listener --mode client --connect EP
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tomllib
from collections.abc import Sequence

from baromap import jsonmsg, logs
from baromap.live.session import close_session, open_session
from baromap.live.settings import LiveSettings, ZenohMode
from baromap.messages import DeviceHealth, DeviceState, FloorEvent, PressureSample

#: Samples between two state offers (the publisher decides what changed).
STATE_EVERY = 5


def say(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def wait_for(word: str) -> None:
    """Block until ``word`` (or the end of stdin)."""
    for line in sys.stdin:
        if line.strip() == word:
            return


def settings(args: argparse.Namespace) -> LiveSettings:
    if args.table:  # a daemon configuration's [zenoh] table, as the daemon will read it
        with open(args.table, "rb") as file:
            return LiveSettings.from_table(tomllib.load(file)["zenoh"])
    mode = ZenohMode(args.mode)
    return LiveSettings(
        mode=mode,
        listen=tuple(args.listen or ()) if mode is ZenohMode.PEER else (),
        connect=tuple(args.connect or ()),
        state_period_s=args.state_period,
        pressure_period_s=0.2,
    )


def run_router(args: argparse.Namespace) -> int:
    import zenoh

    if args.config:
        config = zenoh.Config.from_file(args.config)
    else:
        config = zenoh.Config()
        config.insert_json5("mode", '"router"')
        config.insert_json5("listen/endpoints", json.dumps(args.listen))
        config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("transport/shared_memory/enabled", "false")
    session = zenoh.open(config)
    say(ready="router")
    wait_for("stop")
    close_session(session)
    return 0


def run_robot(args: argparse.Namespace) -> int:
    from baromap.floors import OnlineFloorDetector
    from baromap.sim.scenario import pressure_run
    from baromapd.live import LivePublisher

    run = pressure_run(args.seed, floors=args.floors, minutes=args.minutes, rate_hz=25.0)
    samples = [
        PressureSample(int(t), float(p), float(c))
        for t, p, c in zip(run.t_ns, run.pressure_pa, run.temperature_c, strict=True)
    ]
    publisher = LivePublisher(settings(args), args.id)
    detector = OnlineFloorDetector()
    publisher.start()
    deadline = time.monotonic() + 20.0
    while publisher.health()["state"] != "open":
        if time.monotonic() > deadline:
            say(failed=args.id, health=dict(publisher.health()))
            publisher.stop()
            return 1
        time.sleep(0.02)
    publisher.offer(samples[0])
    detector.update(samples[0])
    publisher.offer(detector.state())
    say(ready=args.id)
    wait_for("go")
    events = []
    start = time.monotonic()
    for i, sample in enumerate(samples[1:], start=1):
        if args.rate > 0:
            ahead = start + i / args.rate - time.monotonic()
            if ahead > 0:
                time.sleep(ahead)
        publisher.offer(sample)
        decided = detector.update(sample)
        for event in decided:
            publisher.offer(event)
        events.extend(e for e in decided if isinstance(e, FloorEvent))  # rides go out too
        if decided or i % STATE_EVERY == 0:
            publisher.offer(detector.state())
        if i % 25 == 0:
            publisher.offer(DeviceHealth(sample.t_ns, "baro", DeviceState.UP, counters={"n": i}))
    last = detector.finish()
    for event in last:
        publisher.offer(event)
    events.extend(e for e in last if isinstance(e, FloorEvent))
    publisher.offer(detector.state())
    time.sleep(0.2)  # let the worker drain before the counters are read
    say(
        done=args.id,
        events=[jsonmsg.to_dict(e) for e in events],
        state=jsonmsg.to_dict(detector.state()),
        health=dict(publisher.health()),
    )
    wait_for("stop")
    publisher.stop()
    say(stopped=args.id, health=dict(publisher.health()))
    return 0


def run_listener(args: argparse.Namespace) -> int:
    """A bare subscriber on every baromap key (a stalled consumer, when stopped by a signal)."""
    session = open_session(settings(args))
    received = [0]
    session.declare_subscriber("baromap/**", lambda _sample: received.__setitem__(0, 1))
    say(ready="listener")
    wait_for("stop")
    close_session(session)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("role", choices=("router", "robot", "listener"))
    parser.add_argument("id", nargs="?", default="node")
    parser.add_argument("--mode", default="peer")
    parser.add_argument("--listen", action="append")
    parser.add_argument("--connect", action="append")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--floors", type=int, default=3)
    parser.add_argument("--minutes", type=float, default=6.0)
    parser.add_argument("--rate", type=float, default=3000.0, help="samples per second, 0: max")
    parser.add_argument("--state-period", type=float, default=5.0)
    parser.add_argument("--table", help="TOML file whose [zenoh] table configures the node")
    parser.add_argument("--config", help="Zenoh JSON5 file of the router")
    args = parser.parse_args(argv)
    logs.configure("console", "INFO")  # to stderr: stdout is the JSON lines
    if args.role == "router":
        return run_router(args)
    if args.role == "listener":
        return run_listener(args)
    return run_robot(args)


if __name__ == "__main__":
    sys.exit(main())
