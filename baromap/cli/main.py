"""The ``baromap`` command.

Each part of baromap registers its own subcommands from a small ``cli`` module with a cheap
``register(subparsers)`` (heavy imports happen inside the command's function), so
``baromap --help`` stays fast and each part owns its own arguments.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence
from typing import Any

import structlog

from baromap import __version__, logs
from baromap.errors import BaromapError

#: Modules that contribute subcommands, in the order ``--help`` lists them.
COMMAND_MODULES: tuple[str, ...] = (
    "baromap.cli.demo",
    "baromap.cli.sim",
    "baromap.cli.floors",
    "baromap.cli.mapping",
    "baromap.cli.recording",
    "baromap.cli.watch",
    "baromap.cli.export",
    "baromap.cli.devices",
)

Runner = Callable[[argparse.Namespace], int]


def register_modules(subparsers: Any, modules: Sequence[str]) -> None:
    """Let each module add its subcommands (a missing one is a packaging fault: it raises)."""
    for name in modules:
        importlib.import_module(name).register(subparsers)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="baromap",
        description="Map multi-floor buildings with a robot, a laser and a barometer.",
    )
    parser.add_argument("--version", action="version", version=f"baromap {__version__}")
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING, ERROR")
    parser.add_argument(
        "--log-json", action="store_true", help="log JSON lines instead of console text"
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    register_modules(subparsers, COMMAND_MODULES)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logs.configure("json" if args.log_json else "console", args.log_level)
    run: Runner | None = getattr(args, "run", None)
    if run is None:
        parser.print_help(sys.stderr)
        return 2
    try:
        return run(args)
    except BaromapError as exc:
        if args.log_json:
            structlog.get_logger("baromap.cli").error("command failed", error=str(exc))
        else:
            print(f"baromap: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        # Last resort: a file or device problem no part turned into a BaromapError.
        print(f"baromap: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
