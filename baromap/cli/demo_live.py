"""The demo's live part: baromapd records the twins while ``baromap watch`` follows it.

Order matters. The daemon starts first, on ports that do not exist yet (as a service waits
for its devices), so it records the mission from its first seconds when the twins are
switched on; ``baromap watch`` joins over Zenoh once the barometer is up (the daemon's state
queryable answers once there is a state), long before the first ride ends. When the mission
is over the daemon gets SIGTERM (it stops the devices, finishes the detector, closes the
recording), the watcher sees the robot go, and the twins are switched off.

Everything the children print comes back as :class:`Shown` items through ``show``: the
watcher's lines as they arrive, the daemon's device states from its JSON log, and a progress
line every few seconds. The caller decides how to print them.
"""

from __future__ import annotations

import contextlib
import json
import signal
import tempfile
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from baromap.cli.demo_children import Child, ChildFailed, Children, Line, command
from baromap.cli.demo_config import (
    daemon_config,
    floor_naming,
    free_loopback_port,
    port_is_free,
    twin_ports,
    twin_settings,
)
from baromap.cli.demo_mission import Mission

#: How long a child may take to get going on a loaded machine (imports, a Zenoh session).
START_TIMEOUT_S = 90.0
#: A progress line this often (wall seconds).
PROGRESS_EVERY_S = 10.0
#: After the mission's last simulated second, this long for the last frames to be recorded.
TAIL_S = 1.0
#: The live view's usual port, taken when it is free.
VIEW_PORT = 8765


@dataclass(frozen=True, slots=True)
class Shown:
    """Something to show the user: ``source`` is ``watch``, ``baromapd`` or ``progress``."""

    source: str
    text: str


@dataclass(slots=True)
class LiveRun:
    """What the live part left behind."""

    config: Path
    recordings: list[Path]
    truth_log: Path
    logs: dict[str, Path]
    endpoint: str
    daemon_exit: int
    watch_lines: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    #: where the daemon served its live view (None if it did not)
    view_url: str | None = None


class _Session:
    """The running children and what they said, for one mission."""

    def __init__(self, children: Children, show: Callable[[Shown], None]) -> None:
        self.children = children
        self.show = show
        self.watch_lines: list[str] = []
        self.device_states: dict[str, str] = {}
        self.been_up: set[str] = set()
        self.twin_paths: dict[str, str] | None = None
        self.daemon_events: set[str] = set()
        self.view_url: str | None = None

    def handle(self, line: Line) -> None:
        if line.text is None:  # a stream ended; the child's exit is checked where it matters
            return
        if line.child == "watch" and line.stream == "out":
            self.watch_lines.append(line.text)
            self.show(Shown("watch", line.text))
        elif line.child == "watch" and "error" in line.text:
            self.show(Shown("watch", line.text))
        elif line.child == "baromapd" and line.stream == "err":
            self._daemon_log(line.text)
        elif line.child == "twins" and line.stream == "out" and self.twin_paths is None:
            with contextlib.suppress(ValueError, TypeError):
                self.twin_paths = dict(json.loads(line.text))

    def _daemon_log(self, text: str) -> None:
        try:
            entry = json.loads(text)
        except ValueError:
            return  # a line that is not the daemon's log (its log file has it)
        if not isinstance(entry, dict):
            return
        event = str(entry.get("event", ""))
        self.daemon_events.add(event)
        level = entry.get("level")
        if event == "device state":
            device, state = str(entry.get("device")), str(entry.get("state"))
            previous = self.device_states.get(device)
            if previous != state:
                self.device_states[device] = state
                if state != "up" and device not in self.been_up:
                    return  # not there yet: the daemon retries until the twins appear
                self.been_up.add(device)
                detail = entry.get("detail")
                text = f"{device} {state}" + (f": {detail}" if detail else "")
                self.show(Shown("baromapd", text))
        elif event == "live view serving":
            self.view_url = str(entry.get("url"))
            self.show(
                Shown("baromapd", f"live view on {self.view_url} (Foxglove: Open connection)")
            )
        elif level in ("warning", "error", "critical"):
            self.show(Shown("baromapd", f"{level}: {event}"))

    def pump(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            line = self.children.next_line(left)
            if line is not None:
                self.handle(line)

    def wait_for(self, what: Callable[[], bool], child: Child, timeout: float, about: str) -> None:
        deadline = time.monotonic() + timeout
        while not what():
            if not child.running:
                self.pump(0.2)  # its last words
                raise ChildFailed(
                    f"{child.name} ended (exit {child.proc.returncode}) before {about}; "
                    f"see {child.log}"
                )
            if time.monotonic() > deadline:
                raise ChildFailed(f"no {about} within {timeout:g} s; see {child.log}")
            line = self.children.next_line(0.2)
            if line is not None:
                self.handle(line)


def _clock(seconds: float) -> str:
    return f"{int(seconds // 60):02d}:{int(seconds % 60):02d}"


def _size_mb(directory: Path) -> float:
    return sum(p.stat().st_size for p in directory.glob("*.mcap")) / 1e6


@dataclass(frozen=True, slots=True)
class Additions:
    """What a bench adds to the demo's set-up (the demo itself uses none of it).

    ``config``: daemon tables merged into the generated configuration (rotation, a Zenoh
    router to connect to, ``live_view``); ``twins``: twin settings (``faults``);
    ``scale_detector=False`` leaves the floor detector at its real-time defaults;
    ``watch_connect``: where the watcher connects (default: the daemon itself);
    ``every_second``: called about once a second during the mission with the simulated time
    and the daemon's pid (sampling, restarting a router).
    """

    config: Mapping[str, Mapping[str, object]] = field(default_factory=dict)
    twins: Mapping[str, object] = field(default_factory=dict)
    scale_detector: bool = True
    watch_connect: str | None = None
    every_second: Callable[[float, int], None] | None = None


def _write_settings(
    mission: Mission, out: Path, link_dir: Path, endpoint: str, additions: Additions
) -> tuple[Path, Path]:
    """baromapd.toml and twins.toml in ``out``."""
    extra = {table: dict(values) for table, values in additions.config.items()}
    scaled = mission.floor_settings() if additions.scale_detector else {}
    extra["floors"] = {
        **floor_naming(mission.route[0]),
        **scaled,
        **extra.get("floors", {}),
    }
    config = out / "baromapd.toml"
    text = daemon_config(
        mission.robot,
        twin_ports(link_dir),
        out / "recording",
        endpoint,
        base_baud=mission.base_baud,
        view_port=VIEW_PORT if port_is_free(VIEW_PORT) else free_loopback_port(),
        extra=extra,
    )
    config.write_text(text, encoding="utf-8")
    twins = out / "twins.toml"
    twins.write_text(twin_settings(mission.base_baud, dict(additions.twins)), encoding="utf-8")
    return config, twins


def run_live(
    mission: Mission,
    out: Path,
    show: Callable[[Shown], None],
    additions: Additions | None = None,
    keep_alive: bool = False,
) -> LiveRun:
    """Play the mission on the twins with the real daemon recording and a watcher following.

    ``keep_alive``: when the mission is over, the daemon (and its live view) runs on until
    Ctrl-C or SIGTERM, for a person to look; then everything stops as usual.

    ``out`` receives ``baromapd.toml``, ``twins.toml``, ``recording/``, ``twins-truth.jsonl``
    and ``logs/``.
    """
    more = additions or Additions()
    recording_dir = out / "recording"
    log_dir = out / "logs"
    for directory in (recording_dir, log_dir):
        directory.mkdir(parents=True, exist_ok=True)
    for old in recording_dir.glob("*.mcap"):  # the last demo's run: this one replaces it
        old.unlink()
    truth_log = out / "twins-truth.jsonl"
    endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="baromap-demo-") as links, Children(log_dir) as kids:
        link_dir = Path(links)
        config, twins_file = _write_settings(mission, out, link_dir, endpoint, more)
        session = _Session(kids, show)
        daemon = kids.start(
            "baromapd",
            [
                *command("baromapd", "baromapd.main"),
                "--config",
                str(config),
                "--log-format",
                "json",
            ],
        )
        session.wait_for(
            lambda: "zenoh session open" in session.daemon_events,
            daemon,
            START_TIMEOUT_S,
            "Zenoh session of baromapd",
        )
        baromap = command("baromap", "baromap.cli.main")
        sim_argv = [*baromap, "sim", *mission.sim_args(), "--json", "--link-dir", str(link_dir)]
        sim_argv += ["--truth-log", str(truth_log), "--twins", str(twins_file)]
        sim_argv += ["--duration", f"{mission.wall_s + 120:.0f}"]
        twins = kids.start("twins", sim_argv)
        session.wait_for(lambda: session.twin_paths is not None, twins, START_TIMEOUT_S, "twins")
        mission_t0 = time.monotonic()
        session.wait_for(
            lambda: session.device_states.get("barometer") == "up",
            daemon,
            START_TIMEOUT_S,
            "barometer up in baromapd",
        )
        watch_argv = [*baromap, "watch", "--connect", more.watch_connect or endpoint]
        watch = kids.start("watch", watch_argv)
        session.wait_for(
            lambda: any("state known for" in s for s in session.watch_lines),
            watch,
            START_TIMEOUT_S,
            "floor state answered to baromap watch",
        )
        _follow(
            mission,
            session,
            (daemon, watch, twins),
            mission_t0=mission_t0,
            recording_dir=recording_dir,
            additions=more,
        )
        if keep_alive:
            _linger(session, daemon)
        daemon_exit = daemon.stop(signal.SIGTERM, timeout=60.0)
        deadline = time.monotonic() + 15.0
        while time.monotonic() < deadline and not any("gone" in s for s in session.watch_lines):
            session.pump(0.2)
        watch.stop(signal.SIGINT, timeout=15.0)
        twins.stop(signal.SIGTERM, timeout=15.0)
        session.pump(0.1)
    return LiveRun(
        config=config,
        recordings=sorted(recording_dir.glob("*.mcap")),
        truth_log=truth_log,
        logs={name: log_dir / f"{name}.log" for name in ("baromapd", "watch", "twins")},
        endpoint=endpoint,
        daemon_exit=daemon_exit,
        watch_lines=session.watch_lines,
        wall_s=time.monotonic() - started,
        view_url=session.view_url,
    )


def _linger(session: _Session, daemon: Child) -> None:
    """The mission is over: the daemon serves on until Ctrl-C (or SIGTERM), then stops."""
    where = session.view_url or "the live view (not serving: see the daemon's log)"
    session.show(
        Shown("progress", f"mission over; baromapd keeps serving {where}: Ctrl-C to finish")
    )
    try:
        while daemon.running:
            session.pump(1.0)
    except KeyboardInterrupt:
        session.show(Shown("progress", "finishing: the daemon closes the recording"))


def _follow(
    mission: Mission,
    session: _Session,
    children: tuple[Child, ...],
    *,
    mission_t0: float,
    recording_dir: Path,
    additions: Additions,
) -> None:
    """Until the mission's end: show what comes, a progress line now and then."""
    end = mission_t0 + mission.wall_s + TAIL_S
    next_progress = mission_t0 + PROGRESS_EVERY_S
    next_tick = mission_t0 + 1.0
    daemon = children[0]
    while (now := time.monotonic()) < end:
        for child in children:
            if not child.running:
                raise ChildFailed(
                    f"{child.name} ended early (exit {child.proc.returncode}); see {child.log}"
                )
        simulated = min((now - mission_t0) * mission.speed, mission.minutes * 60)
        if now >= next_tick:
            next_tick += 1.0
            if additions.every_second is not None:
                additions.every_second(simulated, daemon.proc.pid)
        if now >= next_progress:
            next_progress += PROGRESS_EVERY_S
            session.show(
                Shown(
                    "progress",
                    f"mission {_clock(simulated)} of {_clock(mission.minutes * 60)} simulated "
                    f"(x{mission.speed:g}); recording {_size_mb(recording_dir):.1f} MB",
                )
            )
        session.pump(max(0.0, min(end, next_progress, next_tick) - time.monotonic()))
