"""Logging set-up for entry points.

Library code only ever calls ``structlog.get_logger(__name__)`` and never prints. The entry
points choose the rendering: JSON lines for a service (journald, log shippers), coloured
key=value for a person at a terminal.
"""

from __future__ import annotations

import logging
import sys
from typing import Literal

import structlog

Renderer = Literal["console", "json"]


class _CurrentStderr:
    """Writes to whatever ``sys.stderr`` is *now*, not what it was at configuration time.

    Test runners and daemons swap stderr; holding the old object would write into a closed
    capture buffer.
    """

    def write(self, text: str) -> int:
        return sys.stderr.write(text)

    def flush(self) -> None:
        sys.stderr.flush()


def configure(renderer: Renderer = "console", level: str | int = "INFO") -> None:
    """Route structlog and stdlib logging to stderr with one renderer."""
    numeric = logging.getLevelName(level.upper()) if isinstance(level, str) else level
    if not isinstance(numeric, int):
        raise ValueError(f"unknown log level {level!r}")
    processors: list[structlog.typing.Processor] = [
        structlog.contextvars.merge_contextvars,
        structlog.processors.add_log_level,
        structlog.processors.TimeStamper(fmt="iso", utc=True),
        structlog.processors.StackInfoRenderer(),
    ]
    if renderer == "json":
        processors += [structlog.processors.format_exc_info, structlog.processors.JSONRenderer()]
    else:
        processors.append(structlog.dev.ConsoleRenderer(colors=sys.stderr.isatty()))
    structlog.configure(
        processors=processors,
        wrapper_class=structlog.make_filtering_bound_logger(numeric),
        logger_factory=structlog.PrintLoggerFactory(file=_CurrentStderr()),  # type: ignore[arg-type]
        cache_logger_on_first_use=False,
    )
    logging.basicConfig(
        level=numeric, stream=_CurrentStderr(), format="%(levelname)s %(name)s: %(message)s"
    )
