"""Opening a text log for one of the line parsers (CSV pressure, IPIN).

A log is read as UTF-8 with undecodable bytes replaced: a line they spoil is the parser's to
count and skip, like any other malformed line, so only a file that cannot be opened or read
at all stops the import (as an InputFormatError naming it).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TypeVar

from baromap.errors import InputFormatError

T = TypeVar("T")


def parse_text_log(path: str | Path, parse: Callable[[Iterable[str], str], T]) -> T:
    """``parse(lines, source)`` over the lines of the file at ``path``."""
    try:
        with open(path, encoding="utf-8", errors="replace") as handle:
            return parse(handle, str(path))
    except OSError as exc:
        raise InputFormatError(f"cannot read {path}: {exc}") from exc
