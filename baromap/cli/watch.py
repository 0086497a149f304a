"""``baromap watch``: robots' floors live over Zenoh, as lines a person (or a script) reads.

The work is :class:`baromap.live.watch.FloorWatch`; this turns its reports into lines: the
current state at start (from each robot's queryable), then events as they happen, and a line
when a robot disappears or comes back.
"""

from __future__ import annotations

import argparse
import json
import time
from datetime import datetime
from pathlib import Path
from typing import Any

from baromap.messages import NS_PER_S

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"


def register(subparsers: Any) -> None:
    watch = subparsers.add_parser(
        "watch", help="follow robots' floor state and events live over Zenoh"
    )
    watch.add_argument("--robot", metavar="ID", help="only this robot (default: every robot)")
    watch.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help=f"Zenoh router or robot to connect to (repeatable; default {DEFAULT_CONNECT})",
    )
    watch.add_argument(
        "--zenoh-config", metavar="FILE", help="Zenoh JSON5 configuration (TLS, credentials)"
    )
    watch.add_argument(
        "--rides", action="store_true", help="also print rides as they start and end"
    )
    watch.add_argument("--states", action="store_true", help="also print every state published")
    watch.add_argument("--pressure", action="store_true", help="also print decimated pressure")
    watch.add_argument("--health", action="store_true", help="also print device health")
    watch.add_argument("--json", action="store_true", help="print JSON lines")
    watch.add_argument(
        "--seconds", type=float, metavar="S", help="stop after S seconds (default: Ctrl-C)"
    )
    watch.add_argument(
        "--query-timeout",
        type=float,
        default=2.0,
        metavar="S",
        help="how long robots may take to answer the state question (default 2)",
    )
    watch.set_defaults(run=run_watch)


def run_watch(args: argparse.Namespace) -> int:
    from baromap.errors import ConfigError
    from baromap.live.keys import Channel
    from baromap.live.settings import LiveSettings
    from baromap.live.watch import FloorWatch

    if args.seconds is not None and not args.seconds > 0:
        raise ConfigError(f"--seconds must be above 0, got {args.seconds}")
    if not 0 < args.query_timeout <= 600:
        raise ConfigError(
            f"--query-timeout must be above 0 and at most 600, got {args.query_timeout}"
        )
    connect = tuple(args.connect or (DEFAULT_CONNECT,))
    config = Path(args.zenoh_config) if args.zenoh_config else None
    try:
        settings = LiveSettings.client(connect, config_file=config)
    except ConfigError as exc:  # name the options, not the daemon's configuration keys
        message = str(exc).replace("zenoh.config_file", "--zenoh-config")
        raise ConfigError(message.replace("zenoh.connect", "--connect")) from None
    channels = [Channel.EVENT]
    for flag, channel in (
        (args.rides, Channel.RIDE),
        (args.states, Channel.STATE),
        (args.pressure, Channel.PRESSURE),
        (args.health, Channel.HEALTH),
    ):
        if flag:
            channels.append(channel)
    render = _json_line if args.json else _text_line
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    with FloorWatch(
        settings, args.robot, channels=tuple(channels), query_timeout_s=args.query_timeout
    ) as watch:
        if not args.json:
            who = f"robot {args.robot}" if args.robot else "every robot"
            print(f"watching {who} via {', '.join(connect)}", flush=True)
        while deadline is None or time.monotonic() < deadline:
            wait = 0.5 if deadline is None else min(0.5, max(0.0, deadline - time.monotonic()))
            report = watch.next(wait)
            if report is not None:
                print(render(report, connect), flush=True)
    return 0


def _clock(t_ns: int) -> str:
    """Local wall time of a stamp, to the millisecond (the day is rarely in doubt live)."""
    return datetime.fromtimestamp(t_ns / NS_PER_S).strftime("%H:%M:%S.%f")[:-3]


def _text_line(report: Any, connect: tuple[str, ...]) -> str:
    from baromap.live import watch as w
    from baromap.messages import FloorEventKind, FloorPhase, RideEventKind

    now = _clock(time.time_ns())
    match report:
        case w.RobotUp(robot=robot, returned=returned):
            return f"{now} {robot}: {'back online' if returned else 'online'}"
        case w.RobotGone(robot=robot):
            return f"{now} {robot}: gone (liveliness lost)"
        case w.QueryDone(robots=()):
            return (
                f"{now} no robot answered with its floor state (none reachable via {connect[0]}?)"
            )
        case w.QueryDone():
            return f"{now} state known for {', '.join(report.robots)}"
        case w.StateReport(robot=robot, state=s, answered=answered):
            how = "state" if answered else "state published"
            since = f"{s.phase.value} since {_clock(s.since_ns)}"
            if s.floor_id is None:
                return f"{now} {robot}: {how}: floor not known yet ({since})"
            line = (
                f"{now} {robot}: {how}: floor {s.name} ({since}), {s.height_m:+.2f} m from the "
                f"start floor, {s.floors_known} floor(s) known"
            )
            if s.phase is FloorPhase.STOPPED:
                at = f"floor {s.stop_name}" if s.stop_name is not None else "no known floor"
                line += f"; stopped in a ride at {at} ({s.level_m:+.2f} m)"
            elif s.phase is FloorPhase.CHANGING:
                line += f"; moving, now at {s.level_m:+.2f} m"
            return line
        case w.EventReport(robot=robot, event=e) if e.kind is FloorEventKind.RETRACTION:
            return (
                f"{now} {robot}: retraction of event {e.replaces}: floor {e.from_name} -> "
                f"{e.to_name} did not happen (the car brought the robot back), decided "
                f"{_clock(e.t_ns)} [event {e.event_id}]"
            )
        case w.EventReport(robot=robot, event=e):
            what = (
                f"correction of event {e.replaces}: " if e.kind is FloorEventKind.CORRECTION else ""
            )
            end = " (decided as the input ended)" if e.at_end else ""
            return (
                f"{now} {robot}: {what}floor {e.from_name} -> {e.to_name} ({e.delta_m:+.2f} m, "
                f"{e.delta_pa:+.1f} Pa; {e.height_m:+.2f} m from the start floor), moving "
                f"{_clock(e.t_start_ns)} to {_clock(e.t_end_ns)}, decided {_clock(e.t_ns)}{end} "
                f"[event {e.event_id}]"
            )
        case w.RideReport(robot=robot, ride=r):
            if r.kind is RideEventKind.STARTED:
                told = f"{r.direction.value} from floor {r.from_name}"
            elif r.kind is RideEventKind.ENDED:
                told = f"ended on floor {r.to_name} (event {r.floor_event_id})"
            else:
                told = f"withdrawn: {r.reason}"
            return f"{now} {robot}: ride {r.ride_id} {told} at {_clock(r.t_ns)}"
        case w.PressureReport(robot=robot, sample=p):
            return f"{now} {robot}: pressure {p.pressure_pa:.2f} Pa at {_clock(p.t_ns)}"
        case w.HealthReport(robot=robot, health=h):
            detail = f" ({h.detail})" if h.detail else ""
            return f"{now} {robot}: {h.device} {h.state.value}{detail}"
        case w.Unreadable(key=key, reason=reason):
            return f"{now} unreadable sample on {key}: {reason}"
    raise TypeError(f"no line for {report!r}")


def _json_line(report: Any, _connect: tuple[str, ...]) -> str:
    from baromap import jsonmsg
    from baromap.live import watch as w

    out: dict[str, Any] = {"received_ns": time.time_ns()}
    match report:
        case w.RobotUp(robot=robot, returned=returned):
            out |= {"report": "back" if returned else "online", "robot": robot}
        case w.RobotGone(robot=robot):
            out |= {"report": "gone", "robot": robot}
        case w.QueryDone(robots=robots):
            out |= {"report": "answered", "robots": list(robots)}
        case w.StateReport(robot=robot, state=s, answered=answered):
            kind = "state" if answered else "state_published"
            out |= {"report": kind, "robot": robot, "state": jsonmsg.to_dict(s)}
        case w.EventReport(robot=robot, event=e):
            out |= {"report": "event", "robot": robot, "event": jsonmsg.to_dict(e)}
        case w.RideReport(robot=robot, ride=r):
            out |= {"report": "ride", "robot": robot, "ride": jsonmsg.to_dict(r)}
        case w.PressureReport(robot=robot, sample=p):
            out |= {"report": "pressure", "robot": robot, "pressure": jsonmsg.to_dict(p)}
        case w.HealthReport(robot=robot, health=h):
            out |= {"report": "health", "robot": robot, "health": jsonmsg.to_dict(h)}
        case w.Unreadable(key=key, reason=reason):
            out |= {"report": "unreadable", "key": key, "reason": reason}
    return json.dumps(out, allow_nan=False)
