"""A serial port made of a pseudo-terminal, paced like a real line, with faults on demand.

A pty carries bytes instantly and ignores the baud rate, so the twin paces its own output like
a UART: a message starts on the line when the device has it (or when the line is free), its
bytes follow at baud/10 per second (8N1: ten bit times per byte), and the host never gets a
byte before the instant its stop bit would have arrived. The port writes what is due at least
every few milliseconds (the twin's tick, like a USB adapter's packets) and the last byte of each
message at the instant it is complete (:meth:`PtyPort.next_due`), so the host reads a message's
end when a real line would deliver it; how late the twin's thread managed that is measured
(:attr:`PtyPort.lateness`), so a host's timestamp error can be told apart from the twin's own
scheduling. On Linux the
master reads back the termios speed the host set on the slave (TCGETS2, custom rates too);
when it differs from the device's speed, both directions pass through
:func:`~baromap.sim.twins.uart.misread`, so a host at the wrong speed reads garbage and a baud
search has to really search. Output nobody reads is dropped once the pty's buffer has been full
for :data:`QUEUE_S` of line time, as a device on a cable with no host simply talks into the
void; a host that reads late loses nothing, as a real port's kernel buffer holds a second.

Faults: a burst of garbage, dropped bytes (a frame cut short), a stall (silence for a while),
unplug (the pty is closed and the stable symlink removed, as when a USB adapter is pulled)
and replug (a new pty behind the same symlink, as udev would do).
"""

from __future__ import annotations

import array
import collections
import contextlib
import errno
import fcntl
import os
import termios
import threading
import time
import tty
from pathlib import Path
from typing import Final

import structlog

from baromap.errors import ConfigError
from baromap.sim.twins.uart import misread

log = structlog.get_logger(__name__)

#: Largest chunk written to the master at once.
WRITE_CHUNK = 1024
#: A device's transmit buffer, in seconds of line time: output beyond it is lost whole, as a
#: device that produces faster than its line can carry loses it (a twin sped up past what its
#: baud rate allows). A lone message longer than that (a scan at 9600 baud) still goes out.
QUEUE_S = 0.5

#: Fraction of a byte time by which a byte counts as complete early (float rounding of "now").
_BYTE_EPSILON: Final = 1e-3
#: Message-end delivery delays kept for :attr:`PtyPort.lateness` (the newest).
LATENESS_KEPT: Final = 65536

#: termios speed codes -> baud; BOTHER (a custom rate) is read with TCGETS2.
_SPEED_CODES: Final = {
    getattr(termios, f"B{baud}"): baud
    for baud in (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 921600)
    if hasattr(termios, f"B{baud}")
}
_BOTHER: Final = 0o010000
#: Linux's TCGETS2 on the common architectures (x86, arm): struct termios2 is 44 bytes, its
#: output speed at int index 10.
_TCGETS2: Final = 0x802C542A
_TERMIOS2_INTS: Final = 11


class PtyPort:
    """The device end of a pseudo-terminal; the host opens :attr:`path` (or :attr:`link`)."""

    def __init__(self, baud: int, link: str | Path | None = None) -> None:
        self.baud = baud
        self.link = Path(link) if link is not None else None
        self._lock = threading.Lock()
        self._out = bytearray()
        self._drop = 0
        self._stall_until = 0.0
        #: When the next byte of the queue starts on the line (monotonic s); while the queue is
        #: empty, the earliest a new message may start (the end of the last one).
        self._budget_t = time.monotonic()
        #: (queue position just past a message's last byte, instant that byte is complete).
        self._ends: collections.deque[tuple[int, float]] = collections.deque()
        self._queued = 0  # bytes ever queued
        self._done = 0  # bytes ever written or discarded from the queue
        self.lateness: collections.deque[float] = collections.deque(maxlen=LATENESS_KEPT)
        self.master: int | None = None
        self._slave: int | None = None
        self.slave_path = ""
        self.bytes_sent = 0
        self.bytes_dropped = 0
        self.bytes_misread = 0
        #: Bytes the line carried while the host's buffer was full (a host that did not read).
        self.bytes_unread = 0
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
            self._forget()
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
            self._queue(data, None)

    def drop_next(self, count: int) -> None:
        """Lose the next ``count`` output bytes (a frame arrives cut short)."""
        with self._lock:
            self._drop += count

    def stall(self, seconds: float) -> None:
        """Send nothing for ``seconds``; what the device produces meanwhile is lost."""
        with self._lock:
            self._stall_until = time.monotonic() + seconds
            self._forget()

    @property
    def stalled(self) -> bool:
        return time.monotonic() < self._stall_until

    # ---- data ---------------------------------------------------------------------------------
    def set_baud(self, baud: int) -> None:
        with self._lock:
            self.baud = baud
            self._budget_t = max(self._budget_t, time.monotonic())

    def host_baud(self) -> int | None:
        """The speed the host set on its end, or None if it cannot be read."""
        fd = self.master
        if fd is None:
            return None
        try:
            code = termios.tcgetattr(fd)[5]
        except (termios.error, OSError):
            return None
        if code in _SPEED_CODES:
            return _SPEED_CODES[code]
        if code != _BOTHER:
            return None
        buf = array.array("i", [0] * _TERMIOS2_INTS)
        try:
            fcntl.ioctl(fd, _TCGETS2, buf)
        except OSError:
            return None
        return buf[10] or None

    def _as_received(self, data: bytes, tx_baud: int, rx_baud: int | None) -> bytes:
        if rx_baud is None or rx_baud == tx_baud:
            return data
        self.bytes_misread += len(data)
        return misread(data, tx_baud, rx_baud)

    def send(self, data: bytes, at: float | None = None) -> bool:
        """Queue a message for output (paced by :meth:`pump`); dropped whole if the queue is full.

        The message starts on the line at ``at`` (``time.monotonic()`` seconds: when the device
        had it; default now) or when the line is free, whichever is later: never before.
        True if the bytes went into the queue (possibly cut short by :meth:`drop_next`).
        """
        if not data or self.stalled:
            return False
        with self._lock:
            if self._out and len(self._out) + len(data) > self.baud / 10.0 * QUEUE_S:
                self.bytes_dropped += len(data)
                return False
            if self._drop:
                cut = min(self._drop, len(data))
                self._drop -= cut
                self.bytes_dropped += cut
                data = data[cut:]
            if data:
                self._queue(data, time.monotonic() if at is None else at)
            return True

    def _queue(self, data: bytes, at: float | None) -> None:
        """Append to the queue; a message (``at`` given) has its end's instant noted."""
        byte_s = 10.0 / self.baud
        if not self._out:
            self._budget_t = max(self._budget_t, time.monotonic() if at is None else at)
        self._out += data
        self._queued += len(data)
        if at is not None:
            self._ends.append((self._queued, self._budget_t + len(self._out) * byte_s))

    def _forget(self) -> None:
        """Drop the queue (under the lock)."""
        self._done += len(self._out)
        self._out.clear()
        self._ends.clear()

    def clear(self) -> None:
        """Forget output not yet on the line (the device lost power)."""
        with self._lock:
            self._forget()

    @property
    def pending(self) -> int:
        return len(self._out)

    def next_due(self) -> float | None:
        """When the next queued message is complete on the line (monotonic s), or None.

        The twin's loop wakes then, so the message's last byte reaches the host when a real
        line would have delivered it, not at the next tick.
        """
        with self._lock:
            return self._ends[0][1] if self._ends and self.master is not None else None

    def pump(self) -> None:
        """Write every byte whose line time is over by now (never one before)."""
        with self._lock:
            if self.master is None or not self._out:
                return
            now = time.monotonic()
            # The queue's first byte started on the line at _budget_t (never before it was
            # queued), and a UART keeps sending while the twin's thread waits for a core: a
            # thread held up delivers the whole backlog whose line time is over, as a real
            # line would have.
            while self._out and self._write_due(now):
                pass

    def _write_due(self, now: float) -> bool:
        """Write one chunk of what is due by ``now`` (under the lock); False when no more may go."""
        allowed = int((now - self._budget_t) * self.baud / 10.0 + _BYTE_EPSILON)
        if allowed <= 0 or self.master is None:
            return False
        chunk = bytes(self._out[: min(allowed, WRITE_CHUNK)])
        line = self._as_received(chunk, self.baud, self.host_baud())
        try:
            written = os.write(self.master, line)
        except BlockingIOError:
            if now - self._budget_t < QUEUE_S:
                # A pty's buffer fills sooner than a real port's (tens of kilobytes, a
                # second of the line): a host that reads, only late (a backlog after the
                # twin was held up), loses nothing; the bytes wait for the next pump.
                return False
            written = len(line)  # a host that has not read for long: the bytes are lost
            self.bytes_unread += len(chunk)
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            written = len(line)
        if line is not chunk:
            written = len(chunk)  # garbled bytes are not resent: they were on the line
        del self._out[:written]
        self._budget_t += written * 10.0 / self.baud
        self._done += written
        self.bytes_sent += written
        while self._ends and self._ends[0][0] <= self._done:
            self.lateness.append(now - self._ends.popleft()[1])
        # a partial write: the host's buffer is nearly full, the rest waits for the next pump
        return written == len(chunk)

    def read(self) -> bytes:
        """Whatever the host wrote (non-blocking)."""
        with self._lock:
            if self.master is None:
                return b""
            try:
                data = os.read(self.master, 4096)
                return self._as_received(data, self.host_baud() or self.baud, self.baud)
            except (BlockingIOError, InterruptedError):
                return b""
            except OSError as exc:
                if exc.errno == errno.EIO:
                    return b""
                raise

    def fileno(self) -> int | None:
        return self.master
