"""Child processes that speak JSON lines, read with deadlines (no reader threads to leak)."""

from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pytest

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
NODES = HERE / "nodes.py"


def free_port() -> int:
    """A loopback port nothing listens on now (tests never use the fixed 7447)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def endpoint(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


class Child:
    """A child process whose stdout is JSON lines; stderr goes to ``log``."""

    def __init__(self, name: str, argv: Sequence[str], log_dir: Path) -> None:
        self.name = name
        self.log = log_dir / f"{name}.log"
        self.lines: list[dict[str, Any]] = []
        self._buffer = b""
        with self.log.open("wb") as err:
            self.proc = subprocess.Popen(
                list(argv),
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=err,
                cwd=REPO,
                env={**os.environ, "PYTHONPATH": str(REPO)},
            )

    @classmethod
    def node(cls, name: str, args: Sequence[str], log_dir: Path) -> Child:
        return cls(name, [sys.executable, str(NODES), *args], log_dir)

    @classmethod
    def command(cls, name: str, args: Sequence[str], log_dir: Path) -> Child:
        """A ``baromap`` subcommand."""
        return cls(name, [sys.executable, "-m", "baromap.cli.main", *args], log_dir)

    @classmethod
    def watch(cls, name: str, args: Sequence[str], log_dir: Path) -> Child:
        argv = [sys.executable, "-m", "baromap.cli.main", "watch", "--json", *args]
        return cls(name, argv, log_dir)

    def _read(self, timeout: float) -> None:
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        ready, _, _ = select.select([fd], [], [], max(0.0, timeout))
        if not ready:
            return
        chunk = os.read(fd, 65536)
        if not chunk:
            raise EOFError
        self._buffer += chunk
        *complete, self._buffer = self._buffer.split(b"\n")
        for line in complete:
            if line.strip():
                self.lines.append(json.loads(line))

    def expect(self, what: Callable[[dict[str, Any]], bool], timeout: float, about: str) -> Any:
        """The first line (seen before or arriving within ``timeout``) that ``what`` accepts."""
        deadline = time.monotonic() + timeout
        seen = 0
        while True:
            for line in self.lines[seen:]:
                if what(line):
                    return line
            seen = len(self.lines)
            left = deadline - time.monotonic()
            if left <= 0:
                break
            try:
                self._read(min(left, 0.2))
            except EOFError:
                break
        pytest.fail(
            f"{self.name}: no {about} within {timeout:g} s (exit {self.proc.poll()}); "
            f"last lines {self.lines[-3:]}; log:\n{self.log.read_text()[-3000:]}"
        )

    def collect(self, seconds: float) -> None:
        """Read whatever arrives for ``seconds``."""
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            try:
                self._read(min(left, 0.2))
            except EOFError:
                return

    def send(self, word: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(f"{word}\n".encode())
        self.proc.stdin.flush()

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait(10)

    def close(
        self, *, interrupt: bool = False, terminate: bool = False, timeout: float = 20.0
    ) -> int:
        """Ask the child to stop (``stop`` on stdin, SIGINT for ``baromap watch``, SIGTERM for
        ``baromapd`` and ``baromap sim``); kill it if it hangs."""
        if self.proc.stdout is not None and self.proc.stdout.closed:
            return self.proc.wait()  # closed before
        if self.proc.poll() is None:
            try:
                if interrupt:
                    self.proc.send_signal(signal.SIGINT)
                elif terminate:
                    self.proc.send_signal(signal.SIGTERM)
                else:
                    self.send("stop")
            except (BrokenPipeError, OSError):
                pass
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait(10)
        if self.proc.stdout is not None:  # what it printed before it ended
            try:
                while True:
                    self._read(1.0)
            except EOFError:
                pass
        for pipe in (self.proc.stdin, self.proc.stdout):
            if pipe is not None:
                with contextlib.suppress(BrokenPipeError):
                    pipe.close()
        return code
