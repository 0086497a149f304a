"""A serial port made of a pseudo-terminal, paced like a real line, with faults on demand.

A pty carries bytes instantly and ignores the baud rate the host sets (the host's termios
speed is not even visible from the master side), so the twin paces its own output: it never
sends more than baud/10 bytes per second (8N1: ten bit times per byte). Output nobody reads is
dropped when the pty's buffer is full, as a device on a cable with no host simply talks into
the void.

Faults: a burst of garbage, dropped bytes (a frame cut short), a stall (silence for a while),
unplug (the pty is closed and the stable symlink removed, as when a USB adapter is pulled)
and replug (a new pty behind the same symlink, as udev would do).
"""

from __future__ import annotations

import contextlib
import errno
import os
import threading
import time
import tty
from pathlib import Path

import structlog

from baromap.errors import ConfigError

log = structlog.get_logger(__name__)

#: Largest chunk written to the master at once.
WRITE_CHUNK = 1024
#: A device's transmit buffer, in seconds of line time: output beyond it is lost whole, as a
#: device that produces faster than its line can carry loses it (a twin sped up past what its
#: baud rate allows). A lone message longer than that (a scan at 9600 baud) still goes out.
QUEUE_S = 0.5


class PtyPort:
    """The device end of a pseudo-terminal; the host opens :attr:`path` (or :attr:`link`)."""

    def __init__(self, baud: int, link: str | Path | None = None) -> None:
        self.baud = baud
        self.link = Path(link) if link is not None else None
        self._lock = threading.Lock()
        self._out = bytearray()
        self._drop = 0
        self._stall_until = 0.0
        self._budget_t = time.monotonic()
        self.master: int | None = None
        self._slave: int | None = None
        self.slave_path = ""
        self.bytes_sent = 0
        self.bytes_dropped = 0
        self._open()

    # ---- lifetime ---------------------------------------------------------------------------
    def _open(self) -> None:
        master, slave = os.openpty()
        try:
            tty.setraw(slave)
            os.set_blocking(master, False)
            slave_path = os.ttyname(slave)
            if self.link is not None:
                self.link.parent.mkdir(parents=True, exist_ok=True)
                with contextlib.suppress(FileNotFoundError):
                    self.link.unlink()
                self.link.symlink_to(slave_path)
        except OSError as exc:
            os.close(master)
            os.close(slave)
            raise ConfigError(f"cannot link {self.link} to a pseudo-terminal: {exc}") from exc
        self.master, self._slave = master, slave
        self.slave_path = slave_path
        self._budget_t = time.monotonic()
        log.debug("pty open", path=self.slave_path, link=str(self.link))

    @property
    def path(self) -> str:
        """Where a host should open the port: the stable link if there is one."""
        return str(self.link) if self.link is not None else self.slave_path

    @property
    def plugged(self) -> bool:
        return self.master is not None

    def close(self) -> None:
        with self._lock:
            for fd in (self.master, self._slave):
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self.master = self._slave = None
            self._out.clear()
            if self.link is not None:
                with contextlib.suppress(FileNotFoundError):
                    if self.link.is_symlink():
                        self.link.unlink()

    # ---- faults -------------------------------------------------------------------------------
    def unplug(self) -> None:
        """Close the pty and remove the symlink: the host's reads fail, its port is gone."""
        self.close()
        log.debug("device unplugged", link=str(self.link))

    def replug(self) -> None:
        """A fresh pty behind the same symlink (a new slave path, as after a real replug)."""
        if self.plugged:
            self.close()
        with self._lock:
            self._open()
        log.debug("device replugged", path=self.path)

    def inject_garbage(self, data: bytes) -> None:
        with self._lock:
            self._out += data

    def drop_next(self, count: int) -> None:
        """Lose the next ``count`` output bytes (a frame arrives cut short)."""
        with self._lock:
            self._drop += count

    def stall(self, seconds: float) -> None:
        """Send nothing for ``seconds``; what the device produces meanwhile is lost."""
        with self._lock:
            self._stall_until = time.monotonic() + seconds
            self._out.clear()

    @property
    def stalled(self) -> bool:
        return time.monotonic() < self._stall_until

    # ---- data ---------------------------------------------------------------------------------
    def set_baud(self, baud: int) -> None:
        with self._lock:
            self.baud = baud
            self._budget_t = max(self._budget_t, time.monotonic())

    def send(self, data: bytes) -> None:
        """Queue bytes for output (paced by :meth:`pump`); dropped whole if the queue is full."""
        if not data or self.stalled:
            return
        with self._lock:
            if self._out and len(self._out) + len(data) > self.baud / 10.0 * QUEUE_S:
                self.bytes_dropped += len(data)
                return
            if self._drop:
                cut = min(self._drop, len(data))
                self._drop -= cut
                self.bytes_dropped += cut
                data = data[cut:]
            self._out += data

    @property
    def pending(self) -> int:
        return len(self._out)

    def pump(self) -> None:
        """Write what the line could have carried by now."""
        with self._lock:
            if self.master is None or not self._out:
                self._budget_t = max(self._budget_t, time.monotonic())
                return
            now = time.monotonic()
            self._budget_t = max(self._budget_t, now - 0.05)
            allowed = int((now - self._budget_t) * self.baud / 10.0)
            if allowed <= 0:
                return
            chunk = bytes(self._out[: min(allowed, WRITE_CHUNK)])
            try:
                written = os.write(self.master, chunk)
            except BlockingIOError:
                written = len(chunk)  # nobody reads: the bytes are lost on the line
            except OSError as exc:
                if exc.errno != errno.EIO:
                    raise
                written = len(chunk)
            del self._out[:written]
            self._budget_t += written * 10.0 / self.baud
            self.bytes_sent += written

    def read(self) -> bytes:
        """Whatever the host wrote (non-blocking)."""
        with self._lock:
            if self.master is None:
                return b""
            try:
                return os.read(self.master, 4096)
            except (BlockingIOError, InterruptedError):
                return b""
            except OSError as exc:
                if exc.errno == errno.EIO:
                    return b""
                raise

    def fileno(self) -> int | None:
        return self.master
