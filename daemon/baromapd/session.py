"""One device session: a port, a reader thread, a handshake, health, and recovery.

The abstract :class:`DeviceSession` does everything the three devices share, the way
python-can's ``BusABC`` does for CAN interfaces: it opens the port through
``serial.serial_for_url`` (so tests pass a pty path or ``loop://``), reads with a short
timeout, writes, closes, keeps health and counters, and recovers. A driver implements only
its raw operations: :meth:`handshake` (find the device and set it up), :meth:`handle` (bytes
in, messages out), :meth:`keepalive` and :meth:`shutdown`.

Why one thread per device: blocking reads with a short timeout are the simplest code to
reason about (a handshake is a straight sequence of write, wait-for-reply), a stuck or slow
device cannot stall another, and the work per byte is small enough that three threads cost
less than the event loop machinery (see ``docs/decisions.md``).

Recovery: any failure (the port vanished, a handshake that got no answer, a line of garbage,
a silent device) closes the port, marks the session DOWN with the reason, and retries with
capped exponential backoff; the port is resolved again on every attempt, so a replug at the
same path or the same USB identity at a new path is picked up. A device that announces a
restart (the LMS200's power-on telegram, a barometer board's reset) is set up again on the
same port at once.
"""

from __future__ import annotations

import abc
import os
import select
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from typing import Final, TypeVar

import serial
import structlog

from baromap.discovery import permission_hint, reset_usb_adapter, resolve_port
from baromap.errors import BaromapError, DeviceError
from baromap.messages import DeviceHealth, DeviceState, Message
from baromap.protocols.framing import BadFrame
from baromapd.clock import HostClock
from baromapd.config import Retry
from baromapd.osthread import name_os_thread
from baromapd.tap import Tap

log = structlog.get_logger(__name__)

#: Longest a read blocks: bounds how late a keepalive or a stop request is noticed.
READ_TIMEOUT_S: Final = 0.05
READ_TIMEOUT_MS: Final = round(READ_TIMEOUT_S * 1000)
#: Longest a read blocks while the device streams: a handshake's waits must end on time, a
#: stream only needs its keepalive (the base's PULSE, due every 500 ms) and a stop noticed.
#: A device whose frames come further apart than this wakes for its frames only, not also at
#: a timeout between them (at 50 ms a 10 Hz SIP stream would wake the base's thread at a
#: timeout between most SIPs).
STREAM_READ_TIMEOUT_MS: Final = 200
#: Longest sleep for the rest of a frame (a 9600 baud SIP is ~40 ms; a stop waits no longer).
READ_PAUSE_MAX_NS: Final = 50_000_000
#: The sleep for the rest of a frame ends this long after the frame should have: the read
#: after it then takes the rest in one go. That read is late on purpose; the frame's stamp
#: comes from the prompt read woken by its first bytes (``LinePosition``: within a frame the
#: line does not pause). A USB adapter delivers the last bytes up to its latency timer after
#: they arrived (1 ms when set as the docs say); a read that still comes too early only costs
#: one more wake-up.
READ_PAUSE_OVERSHOOT_NS: Final = 1_000_000
#: Most bytes taken in one read (a second of the fastest line is 50 kB).
READ_CHUNK: Final = 65536
#: A bad frame this recent makes an UP device DEGRADED.
DEGRADED_HOLD_NS: Final = 5_000_000_000

T = TypeVar("T")
Publish = Callable[[Message, int], None]
"""(message, host monotonic ns at which its last byte was read)."""
Decode = Callable[[bytes, int], Iterable[object]]
"""(bytes, host monotonic ns of the read) -> the items they decode to, each already handled."""
Identify = Callable[[str, Mapping[str, str]], None]
"""(metadata record name, its string fields): a device's identity, ``baromap.device.<name>``,
and any record its messages need to be read (``baromap.robot``)."""


class DeviceRestarted(Exception):
    """The device announced a restart: set it up again on the same port, without backoff."""


class DeviceRefused(DeviceError):
    """The device answered but must not be used as configured (retried at the longest delay)."""


class DeviceSession(abc.ABC):
    """A device on a serial port, served by its own reader thread."""

    #: Run :meth:`shutdown` whenever a connection ends (a failure, a lost port, a stop), not
    #: only on a stop after streaming: for a device that must be left safe (the base's motors).
    shutdown_on_every_end: bool = False
    #: Read the port through a tap process (``baromapd.tap``) that stamps every read without
    #: waiting for the GIL: for a device whose frames are stamped with the host's clock alone
    #: (the laser). A port without a file descriptor (``loop://``) is read directly.
    tapped: bool = False

    def __init__(
        self,
        name: str,
        *,
        port: str,
        baud: int,
        retry: Retry,
        clock: HostClock,
        publish: Publish,
        identify: Identify | None = None,
        resolve: Callable[[str], str] = resolve_port,
        usb_reset: bool = False,
        reset_adapter: Callable[[str], object] = reset_usb_adapter,
    ) -> None:
        self.name = name
        #: Reset the port's USB adapter when it stops answering after a reconnect.
        self.usb_reset = usb_reset
        self._reset_adapter = reset_adapter
        self.port_spec = port
        self.baud = baud
        self.retry = retry
        self.clock = clock
        self._publish = publish
        self._identify = identify
        self._resolve = resolve
        self._serial: serial.SerialBase | None = None
        self._fd: int | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self.state = DeviceState.STARTING
        self.detail = "not started"
        self.path = ""
        self.counters: Counter[str] = Counter()
        # The two counters of every read and every message are plain integers of this thread
        # (health() reads them; an int is read whole), not a locked Counter update each time.
        self._bytes_in = 0
        self._reads = 0  # reads that returned bytes: the reader's wake-ups for data
        self._messages = 0
        self._poll: select.poll | None = None
        # Reads land here and leave as a bytes object of exactly their length: os.read(fd,
        # READ_CHUNK) allocates READ_CHUNK bytes per call and shrinks them to what arrived,
        # and hundreds of those a second fragmented the reader thread's malloc arena, which
        # grew without end (0.2-0.6 MB a minute with the laser; bench/memory.py --old-read).
        self._read_buffer = memoryview(bytearray(READ_CHUNK))
        self._tap: Tap | None = None
        self._tap_frame = 0  # the frame size the tap was told
        self.identity: dict[str, str] = {}
        #: Further metadata records a reader needs to interpret this device's messages, by
        #: record name (the base's ``baromap.robot``: the factors its counters were read with).
        self.records: dict[str, dict[str, str]] = {}
        self.heartbeat_ns = time.monotonic_ns()
        self._last_good_ns = 0
        self._last_bad_ns = 0
        self._bytes_since_good = 0
        self._last_byte_ns = 0
        self._last_write_ns = 0
        self._in_shutdown = False
        self._opened = False  # the current connection attempt opened the port

    # ---- lifetime ---------------------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=f"baromapd-{self.name}")
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def stopping(self) -> bool:
        """Asked to stop, and not in the polite shutdown sequence that follows."""
        return self._stop.is_set() and not self._in_shutdown

    # ---- health -----------------------------------------------------------------------------
    def health(self, t_ns: int) -> DeviceHealth:
        with self._lock:
            state, detail = self.state, self.detail
            counters = dict(self.counters)
        if self._bytes_in:
            counters["bytes_in"] = self._bytes_in
        if self._messages:
            counters["messages"] = self._messages
        if self._reads:
            counters["reads"] = self._reads
        if state is DeviceState.UP and time.monotonic_ns() - self._last_bad_ns < DEGRADED_HOLD_NS:
            bad = sum(v for k, v in counters.items() if k.startswith("bad_"))
            state, detail = DeviceState.DEGRADED, f"{bad} bad frames so far, one in the last 5 s"
        return DeviceHealth(t_ns, self.name, state, self.path, detail, counters)

    def _set_state(self, state: DeviceState, detail: str) -> None:
        with self._lock:
            changed = state is not self.state or detail != self.detail
            self.state, self.detail = state, detail
        if changed:
            # Recorded at once: a state can be shorter than the once-a-second health beat.
            self._publish(self.health(self.clock.now_unix_ns()), time.monotonic_ns())
            failed = state is DeviceState.DOWN and detail != "stopped"
            level = log.warning if failed else log.info
            level(
                "device state", device=self.name, state=state.value, detail=detail, port=self.path
            )

    def count(self, key: str, n: int = 1) -> None:
        with self._lock:
            self.counters[key] += n

    def set_counter(self, key: str, value: int) -> None:
        with self._lock:
            self.counters[key] = value

    # ---- raw operations for drivers -----------------------------------------------------------
    def read(self, timeout_ms: int = READ_TIMEOUT_MS) -> tuple[bytes, int]:
        """What arrived within ``timeout_ms``, and the monotonic ns when the read returned.

        A port with a file descriptor is read with one ``poll`` and one ``read``: at
        500 kbaud the bytes come in hundreds of small chunks a second, and pyserial's
        ``read(1)`` + ``in_waiting`` + ``read(n)`` costs three times the system calls.
        """
        fd = self._fd
        tap = self._tap
        read_ns: int | None = None  # a tap's record carries its own read time
        if tap is not None:
            record = tap.read(timeout_ms)
            data, read_ns = record if record is not None else (b"", None)
        elif fd is not None:
            poll = self._poll
            if poll is None:
                poll = self._poll = select.poll()
                poll.register(fd, select.POLLIN)
            ready = poll.poll(timeout_ms)
            data = b""
            if ready:
                size = os.readv(fd, (self._read_buffer,))
                if not size:
                    raise serial.SerialException("the port reported data but returned none")
                data = bytes(self._read_buffer[:size])
        else:
            port = self._port()
            data = port.read(1)
            if data:
                waiting = port.in_waiting
                if waiting:
                    data += port.read(waiting)
        now = self._count_reads(1 if data else 0, len(data))
        return data, now if read_ns is None else read_ns

    def _read_tap(self, tap: Tap) -> tuple[list[tuple[bytes, int]], int]:
        """Every record the tap has handed over (waiting up to the stream's read timeout for
        one), and the monotonic ns now; the same accounting as :meth:`read` (a record is a
        read)."""
        reads = tap.read_all(STREAM_READ_TIMEOUT_MS)
        return reads, self._count_reads(len(reads), sum(len(data) for data, _ in reads))

    def _count_reads(self, reads: int, size: int) -> int:
        """Account reads that returned ``size`` bytes in all; the heartbeat and its time."""
        now = time.monotonic_ns()
        self.heartbeat_ns = now
        self._reads += reads
        self._bytes_in += size
        self._bytes_since_good += size
        if size:
            self._last_byte_ns = now
        return now

    def write(self, data: bytes) -> None:
        self._port().write(data)
        self._last_write_ns = time.monotonic_ns()

    def set_baud(self, baud: int) -> None:
        self._port().baudrate = baud
        self.baud = baud

    def discard_input(self) -> None:
        self._port().reset_input_buffer()
        if self._tap is not None:
            self._tap.discard()

    def sleep(self, seconds: float) -> None:
        """Wait, but wake for a stop request (handshake pauses)."""
        if self._in_shutdown:
            time.sleep(seconds)
        elif self._stop.wait(seconds):
            raise _Stopping
        self.heartbeat_ns = time.monotonic_ns()

    def good_frame(self) -> None:
        self._last_good_ns = time.monotonic_ns()
        self._bytes_since_good = 0

    def bad_frame(self, bad: BadFrame) -> None:
        self.count(f"bad_{bad.reason}")
        self._last_bad_ns = time.monotonic_ns()

    def publish(self, message: Message, read_ns: int) -> None:
        self._messages += 1
        self._publish(message, read_ns)

    def since_write_s(self) -> float:
        return (time.monotonic_ns() - self._last_write_ns) / 1e9

    def wait_for(
        self,
        decode: Decode,
        kind: type[T] | tuple[type[T], ...],
        timeout_s: float,
        match: Callable[[T], bool] | None = None,
    ) -> T | None:
        """A handshake's wait: read and ``decode`` until an item is a ``kind`` that ``match``
        accepts (the first such item of a read), or None after ``timeout_s``.

        ``decode`` does with every item what the driver does with it (a SIP on the way is
        odometry, a frame is placed on the line); the wait only picks its answer out.
        """
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.stopping:
                raise _Stopping
            data, read_ns = self.read()
            if not data:
                continue
            found: T | None = None
            for item in decode(data, read_ns):
                if found is None and isinstance(item, kind) and (match is None or match(item)):
                    found = item
            if found is not None:
                return found
        return None

    # ---- what a driver implements ------------------------------------------------------------
    @abc.abstractmethod
    def handshake(self) -> None:
        """Find the device on the open port and set it up; raise DeviceError if it fails.

        Sets :attr:`identity` (recorded in the recording's metadata).
        """

    @abc.abstractmethod
    def handle(self, data: bytes, read_ns: int) -> None:
        """Decode bytes read at ``read_ns``; publish messages; may raise DeviceRestarted."""

    def handle_reads(self, reads: list[tuple[bytes, int]]) -> None:
        """Several reads in a row, (bytes, read ns) each: what a tap handed over at once.

        One :meth:`handle` each unless a driver does better (the laser decodes a scan's
        reads in one decoder call).
        """
        for data, read_ns in reads:
            self.handle(data, read_ns)

    def up_detail(self) -> str:
        """What health says while the device streams."""
        return "streaming"

    def keepalive(self) -> None:  # noqa: B027 (optional hook, most devices need none)
        """Called after every read: send what the device needs to stay awake."""

    def read_pause_ns(self) -> int:
        """How long the rest of a frame in progress takes on the line (0: none, read at once).

        While streaming, the reader sleeps that long (and :data:`READ_PAUSE_OVERSHOOT_NS`
        more) before its next read instead of waking for every chunk the port delivers
        meanwhile (a 500 kbaud scan comes in four 2 ms packets from the twins or eight 1 ms
        packets from an adapter, a 9600 baud SIP in twenty or forty): two wake-ups a frame.
        The read woken by the frame's first bytes was a prompt one, and it bounds the frame's
        end as tightly as the last read would (:class:`~baromapd.clock.LinePosition`).
        """
        return 0

    def frame_bytes(self) -> int:
        """Size of the frames the device streams, as last seen (0: unknown or varying): a tap
        hands a frame over as soon as it has read a frame's worth of bytes."""
        return 0

    def shutdown(self) -> None:  # noqa: B027 (optional hook)
        """Leave the device as it would like to be found (best effort, port still open)."""

    # ---- the reader thread -------------------------------------------------------------------
    def _port(self) -> serial.SerialBase:
        if self._serial is None:
            raise DeviceError(f"{self.name}: port is not open")
        return self._serial

    def _open(self) -> None:
        self.path = self._resolve(self.port_spec)
        try:
            self._serial = serial.serial_for_url(
                self.path,
                baudrate=self.baud,
                timeout=READ_TIMEOUT_S,
                write_timeout=1.0,
                exclusive=True,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            hint = permission_hint(exc)
            detail = f"; {hint}" if hint else ""
            raise DeviceError(f"cannot open {self.path}: {exc}{detail}") from exc
        self._opened = True
        self._poll = None
        try:
            self._fd = self._serial.fileno()
        except (AttributeError, NotImplementedError, serial.SerialException):
            self._fd = None  # a URL port (loop://, socket://): read through pyserial
        if self.tapped and self._fd is not None:
            try:
                self._tap = Tap(self._fd, self.name)
                self._tap_frame = 0
            except OSError as exc:
                self._close()
                raise DeviceError(
                    f"cannot start the reader process for {self.path}: {exc}"
                ) from exc

    def _close(self) -> None:
        tap, self._tap = self._tap, None
        if tap is not None:
            tap.close()
        port, self._serial = self._serial, None
        self._fd = None
        self._poll = None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError) as exc:
                log.debug("close failed", device=self.name, error=str(exc))

    def _run(self) -> None:
        name_os_thread()
        delay = self.retry.initial_s
        log.info("device session started", device=self.name, port=self.port_spec)
        try:
            while not self._stop.is_set():
                self._opened = False
                reason, was_up = self._connect_and_stream()
                if reason is None:
                    break
                if was_up:
                    delay = self.retry.initial_s
                self.count("failures")
                self._set_state(DeviceState.DOWN, reason)
                if self._opened and not was_up and self.counters["connects"]:
                    self._wedged(reason)
                wait = self.retry.max_s if reason.startswith("refused") else delay
                deadline = time.monotonic() + wait
                while not self._stop.is_set() and time.monotonic() < deadline:
                    self._stop.wait(min(0.2, max(0.0, deadline - time.monotonic())))
                    self.heartbeat_ns = time.monotonic_ns()
                delay = min(delay * 2.0, self.retry.max_s)
        finally:
            self._close()
            self._set_state(DeviceState.DOWN, "stopped")

    def _wedged(self, reason: str) -> None:
        """The port opened but the device, which answered before, did not: a wedged USB
        adapter comes back after a reset (``usb_reset``); else the next attempt only reopens."""
        if not self.usb_reset:
            return
        try:
            self._reset_adapter(self.path)
        except (BaromapError, OSError) as exc:
            self.count("usb_reset_failed")
            log.warning(
                "USB adapter reset failed", device=self.name, port=self.path, error=str(exc)
            )
            return
        self.count("usb_resets")
        log.warning("USB adapter reset", device=self.name, port=self.path, after=reason)

    def _connect_and_stream(self) -> tuple[str | None, bool]:
        """One connection: (None when asked to stop, else why it ended; whether it was up)."""
        up = False
        try:
            self._set_state(DeviceState.STARTING, f"opening {self.port_spec}")
            self._open()
            while True:
                self._set_state(DeviceState.STARTING, self.detail if up else "handshake")
                self.handshake()
                self.count("connects")
                self._publish_identity()
                self._set_state(DeviceState.UP, self.up_detail())
                self.good_frame()
                up = True
                try:
                    self._stream()
                    return None, up
                except DeviceRestarted as exc:
                    self.count("restarts")
                    self._set_state(DeviceState.STARTING, f"re-initialising: {exc}")
        except _Stopping:
            return None, up
        except DeviceRefused as exc:
            return f"refused: {exc}", up
        except (serial.SerialException, OSError) as exc:
            return f"port failed (unplugged?): {exc}", up
        except BaromapError as exc:
            return str(exc), up
        except Exception as exc:  # a fault in a driver: this device goes down, not the daemon
            log.exception("device session failed", device=self.name)
            return f"internal error: {type(exc).__name__}: {exc}", up
        finally:
            ending = self._stop.is_set() and up
            if self._serial is not None and (ending or self.shutdown_on_every_end):
                self._in_shutdown = True
                try:
                    self.shutdown()
                except (BaromapError, serial.SerialException, OSError) as exc:
                    log.warning("shutdown sequence failed", device=self.name, error=str(exc))
                finally:
                    self._in_shutdown = False
            self._close()

    def _stream(self) -> None:
        retry = self.retry
        while not self._stop.is_set():
            tap = self._tap
            if tap is not None:  # the tap stamps, and pauses through frames, itself
                reads, read_ns = self._read_tap(tap)
                if reads:
                    self.handle_reads(reads)
                    frame = self.frame_bytes()
                    if frame != self._tap_frame:
                        tap.expect(frame)
                        self._tap_frame = frame
            else:
                data, read_ns = self.read(STREAM_READ_TIMEOUT_MS)
                if data:
                    self.handle(data, read_ns)
                    pause_ns = self.read_pause_ns()
                    if pause_ns > 0:
                        pause_ns += READ_PAUSE_OVERSHOOT_NS - (time.monotonic_ns() - read_ns)
                        if pause_ns > 0:
                            time.sleep(min(pause_ns, READ_PAUSE_MAX_NS) / 1e9)
            self.keepalive()
            # Silent is no byte at all; bytes that make no frame are garbage, however long
            # they last (a laser's silence limit is shorter than the garbage limit).
            quiet_s = (read_ns - self._last_good_ns) / 1e9
            silent_s = (read_ns - max(self._last_byte_ns, self._last_good_ns)) / 1e9
            if silent_s > retry.silence_s:
                self._stream_failed(f"silent: no data for {silent_s:.1f} s")
            if quiet_s > retry.garbage_s and self._bytes_since_good > 0:
                self._stream_failed(
                    f"garbage: {self._bytes_since_good} bytes and no good frame for {quiet_s:.1f} s"
                )

    def _stream_failed(self, reason: str) -> None:
        note = self.reinitialise_note(reason)
        if note is not None:
            raise DeviceRestarted(f"{reason}; {note}")
        raise DeviceError(reason)

    def reinitialise_note(self, reason: str) -> str | None:
        """Why a stream failure should be met by setting the device up again on the same port
        (without closing it or backing off), or None to close and retry as usual."""
        return None

    def _publish_identity(self) -> None:
        if self._identify is None:
            return
        if self.identity:
            self._identify(f"baromap.device.{self.name}", dict(self.identity))
        for record, data in self.records.items():
            self._identify(record, dict(data))


class _Stopping(Exception):
    """Raised out of a handshake pause when the daemon stops."""
