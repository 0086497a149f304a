"""The demo's child processes (the twins, baromapd, baromap watch) and their output, merged.

Each child's stdout and stderr are read line by line on threads into one queue, in the order
the lines arrive, and copied to a log file per child; the demo takes them off the queue and
shows what a person should see as it happens. Children are stopped the way their service
manager would stop them (SIGTERM, SIGINT for ``baromap watch``), killed only if they hang,
and always reaped: a demo that fails half-way must not leave twins or a daemon behind. They
share the demo's process group, so Ctrl-C at the terminal stops them all at once (each stops
cleanly on SIGINT) and the demo then reaps them.
"""

from __future__ import annotations

import contextlib
import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO

from baromap.errors import BaromapError


class ChildFailed(BaromapError):
    """A child process could not start, or ended when it should not have."""


@dataclass(frozen=True, slots=True)
class Line:
    """One line a child printed (``stream`` is ``"out"`` or ``"err"``); ``text`` is None once
    the stream has ended."""

    child: str
    stream: str
    text: str | None


def command(script: str, module: str) -> list[str]:
    """How to run one of baromap's commands: its script beside this interpreter (what a user
    types), else the module through this interpreter (a checkout that was not installed)."""
    beside = Path(sys.executable).with_name(script)
    if beside.is_file() and os.access(beside, os.X_OK):
        return [str(beside)]
    found = shutil.which(script)
    if found and Path(found).resolve().parent == Path(sys.executable).resolve().parent:
        return [found]
    return [sys.executable, "-m", module]


class Child:
    def __init__(self, name: str, argv: Sequence[str], log: Path, lines: queue.Queue[Line]):
        self.name = name
        self.argv = list(argv)
        self.log = log
        try:
            self._log = log.open("w", encoding="utf-8")
            self.proc = subprocess.Popen(
                self.argv,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
                bufsize=1,
                env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )
        except OSError as exc:
            raise ChildFailed(f"cannot start {name} ({self.argv[0]}): {exc}") from exc
        self._lock = threading.Lock()
        self._readers = [
            threading.Thread(
                target=self._pump, args=(stream, label, lines), name=f"{name}-{label}", daemon=True
            )
            for stream, label in ((self.proc.stdout, "out"), (self.proc.stderr, "err"))
        ]
        for reader in self._readers:
            reader.start()

    def _pump(self, stream: IO[str] | None, label: str, lines: queue.Queue[Line]) -> None:
        if stream is None:
            return
        for raw in stream:
            text = raw.rstrip("\n")
            with self._lock:
                if not self._log.closed:
                    self._log.write(f"{label}: {text}\n")
                    self._log.flush()
            lines.put(Line(self.name, label, text))
        lines.put(Line(self.name, label, None))

    @property
    def running(self) -> bool:
        return self.proc.poll() is None

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 30.0) -> int:
        """Send ``sig`` and wait; kill after ``timeout``. Returns the exit code."""
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(sig)
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait()
        for reader in self._readers:
            reader.join(5.0)
        with self._lock:
            self._log.close()
        return code


class Children:
    """The demo's children; a context manager that stops whichever are still running."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.lines: queue.Queue[Line] = queue.Queue()
        self._children: list[Child] = []

    def start(self, name: str, argv: Sequence[str]) -> Child:
        child = Child(name, argv, self.log_dir / f"{name}.log", self.lines)
        self._children.append(child)
        return child

    def next_line(self, timeout: float) -> Line | None:
        try:
            return self.lines.get(timeout=max(0.0, timeout))
        except queue.Empty:
            return None

    def __enter__(self) -> Children:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        for child in reversed(self._children):
            if child.running:
                child.stop(signal.SIGTERM, timeout=10.0)
