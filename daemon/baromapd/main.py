"""Entry point of ``baromapd``: ``--config FILE`` runs the daemon, ``--check-config FILE`` checks.

Exit codes: 0 clean stop (SIGTERM/SIGINT finish the recording first), 1 a failure at start,
2 a configuration problem (the unit's ``RestartPreventExitStatus=2``: restarting cannot fix a
bad file), 3 the recorder gave up (repeated writer faults other than a full disk) or its thread
died: systemd's ``Restart=on-failure`` starts a new run, 4 a stop that left a part behind
(a thread still blocked, say in a write to a stalled disk, after the stop's time: the process
ends without it, so that a stop never outlasts the unit's ``TimeoutStopSec=``). Logs are JSON
lines under systemd (journald sets ``JOURNAL_STREAM``, and systemd ``INVOCATION_ID``) and
readable text on a terminal.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from collections.abc import Mapping, Sequence
from types import FrameType

import structlog

from baromap import __version__, logs
from baromap.errors import BaromapError
from baromapd.app import EXIT_RECORDER, Daemon
from baromapd.config import ConfigProblems, DaemonConfig, load_config
from baromapd.notify import Notifier

EXIT_FAILURE = 1
EXIT_CONFIG = 2
EXIT_LEFT_BEHIND = 4
#: Every exit status but 0, by meaning (the module's docstring says when each happens).
EXIT_CODES = {
    EXIT_FAILURE: "failure at start",
    EXIT_CONFIG: "configuration problem",
    EXIT_RECORDER: "the recorder gave up",
    EXIT_LEFT_BEHIND: "a part did not stop in time",
}


def log_renderer(choice: str, environ: Mapping[str, str], stderr_tty: bool) -> logs.Renderer:
    if choice in ("json", "console"):
        return "json" if choice == "json" else "console"
    if environ.get("JOURNAL_STREAM") or environ.get("INVOCATION_ID"):
        return "json"
    return "console" if stderr_tty else "json"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="baromapd",
        description="baromap acquisition daemon: records the laser, the base and the barometer.",
    )
    parser.add_argument("--version", action="version", version=f"baromapd {__version__}")
    action = parser.add_mutually_exclusive_group(required=True)
    action.add_argument("--config", metavar="FILE", help="run with this configuration")
    action.add_argument(
        "--check-config", metavar="FILE", help="report every problem of FILE and exit"
    )
    parser.add_argument("--log-level", default=None, help="debug, info, warning, error")
    parser.add_argument(
        "--log-format",
        choices=("auto", "json", "console"),
        default="auto",
        help="auto: JSON under systemd, text on a terminal",
    )
    return parser


def summary(config: DaemonConfig) -> str:
    devices = [
        f"{name} on {device.port}"
        for name, device in (
            ("laser", config.laser),
            ("base", config.base),
            ("barometer", config.barometer),
        )
        if device is not None
    ]
    return f"robot {config.robot} ({config.role}): " + ", ".join(devices)


def check_config(path: str) -> int:
    try:
        config = load_config(path)
    except ConfigProblems as exc:
        print(f"baromapd: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    print(f"{path}: ok; {summary(config)}; recording into {config.recording.directory}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.check_config:
        return check_config(args.check_config)
    try:
        config = load_config(args.config)
    except ConfigProblems as exc:
        print(f"baromapd: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    renderer = log_renderer(args.log_format, os.environ, sys.stderr.isatty())
    logs.configure(renderer, args.log_level or config.log_level)
    log = structlog.get_logger("daemon")
    with Notifier() as notifier:
        try:
            daemon = Daemon(config, notifier=notifier)
        except BaromapError as exc:
            log.error("cannot start", error=str(exc))
            return EXIT_FAILURE

        def stop(signum: int, frame: FrameType | None) -> None:
            daemon.request_stop()

        signal.signal(signal.SIGTERM, stop)
        signal.signal(signal.SIGINT, stop)
        log.info("starting", summary=summary(config), watchdog_s=notifier.watchdog_s)
        code = daemon.run()
    left = left_behind()
    if left:
        # Interpreter shutdown would wait for these forever: end the process without them.
        log.error("parts did not stop: exiting without them", threads=left)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code or EXIT_LEFT_BEHIND)
    return code


def left_behind() -> list[str]:
    """Threads other than this one that would hold the process open (not daemon threads)."""
    main_thread = threading.main_thread()
    return [
        t.name
        for t in threading.enumerate()
        if t is not main_thread and t.is_alive() and not t.daemon
    ]


if __name__ == "__main__":
    raise SystemExit(main())
