"""A device's port read by a small process of its own, which stamps every read.

A frame's time comes from the instant its bytes were read (``baromapd.clock.LinePosition``), so a
reader thread that wakes for the bytes but must then wait for the GIL stamps them late: the
recorder compressing a chunk, the Zenoh publisher or another device's reader may hold it for
milliseconds, and on a busy machine a thread that holds it can be preempted with it. The tap is
a process with one thread and no other work: it waits in ``poll`` on the port, reads what came,
takes the monotonic time at once, and hands ``(stamp, bytes)`` records to the daemon through a
pipe. Nothing in the daemon can delay the stamp, and while the daemon is held up the tap keeps
emptying the port (a pipe of up to 1 MB, 20 s of a 500 kbaud line, instead of the tty's few
kilobytes), so nothing is lost either.

The tap wakes for every packet the port delivers (four a scan from the twins, about eight from
a USB adapter with a 1 ms latency timer): a frame's end is stamped from the read that brought
its last bytes, and from every earlier read in it (``baromapd.clock.LinePosition``), so the read
woken by the last packet makes the stamp exact however late any other read was. Those
wake-ups are cheap (a few lines of Python, no lock shared with anything). The daemon tells the
tap how long its frames are (:meth:`Tap.expect`, the laser's scans), and the tap hands a frame
over in one write as soon as it has it: the daemon's reader wakes once a frame.

The daemon keeps the port: it writes to it, sets its speed and flushes its input itself.
After a flush it asks the tap to drop what it has not forwarded (a byte on the tap's standard
input) and discards everything up to the tap's answer, so no byte from before the flush (read
at the old speed during a baud search) reaches the decoder. The tap exits when the port hangs
up or fails (the daemon sees the pipe end and handles it as an unplug), when its standard
input closes, and with the daemon (``PR_SET_PDEATHSIG``).

The tap runs as ``baromapd-tap`` (``daemon/tap.c``, the same protocol byte for byte) when that
was built beside the interpreter (``make setup``: the venv's ``bin``, where ``baromapd`` is),
and as this module otherwise. Both make the same system calls per wake-up; the C one skips the
interpreter's work around them and its megabytes (docs/results.md has the figures). This one
stays: it runs where there is no C compiler, and it is the protocol's readable statement.

    baromapd-tap FD NAME             (started by DeviceSession, with FD passed to it)
    python -m baromapd.tap FD NAME     (the same, where baromapd-tap was not built)
"""

from __future__ import annotations

import collections
import collections.abc
import contextlib
import ctypes
import ctypes.util
import fcntl
import functools
import os
import resource
import select
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Final

from baromapd.osthread import name_os_thread

#: One record: monotonic ns at which the read returned, then the byte count; bytes follow.
RECORD: Final = struct.Struct("<qI")
#: The answer to a flush request: everything before it is stale.
FLUSHED: Final = -1
#: Requests from the daemon: drop what is held and answer FLUSHED; a frame's size in bytes.
FLUSH_REQUEST: Final = b"F"
EXPECT: Final = struct.Struct("<cI")
#: Bytes are handed over after this long without more, and the next start a frame: longer than
#: the pauses within a frame (a USB adapter's packets come every 1 ms, the twins' every 2 ms, a
#: 9600 baud byte takes 1 ms), shorter than the gap between a 500 kbaud laser's scans (6 ms).
QUIET_MS: Final = 4
#: Longest bytes are held while no frame size is known: a line that never goes quiet (a laser
#: at 38400 baud sends its scans back to back, a few milliseconds apart at most) is handed over
#: this often until the daemon has decoded a frame and said its size. Far below the daemon's
#: silence limit (a second), a few times the quiet.
HOLD_MS: Final = 20
#: The tap's SCHED_FIFO priority, when its limits allow one (the unit's ``LimitRTPRIO=``).
PRIORITY: Final = 10
#: Longest wait when idle: the tap checks that its daemon is still there.
IDLE_MS: Final = 1000
#: Most bytes taken in one read.
READ_CHUNK: Final = 65536
#: The pipe to the daemon: Linux lets an unprivileged process ask for up to 1 MB.
PIPE_BYTES: Final = 1 << 20
#: How long the daemon waits for the tap's answer to a flush, and for the tap to exit.
ANSWER_S: Final = 1.0

#: The C tap's program (``daemon/tap.c``), beside the interpreter that runs the daemon.
NATIVE_NAME: Final = "baromapd-tap"

_F_SETPIPE_SZ: Final = 1031
_PR_SET_PDEATHSIG: Final = 1


# ---- the tap process ---------------------------------------------------------------------------
def serve(port: int, out: int, control: int) -> int:
    """Read ``port`` until it hangs up; records to ``out``; requests on ``control``.

    Every read is stamped the moment it returns; what was read goes to the daemon as soon as
    it makes a frame's worth of bytes (the size the daemon said its frames have:
    :meth:`Tap.expect`), or after :data:`QUIET_MS` without bytes, or, while no frame size is
    known, once the oldest of it is :data:`HOLD_MS` old.
    """
    os.set_blocking(control, False)
    poll = select.poll()
    poll.register(control, select.POLLIN)
    poll.register(port, select.POLLIN)
    pack = RECORD.pack
    monotonic_ns = time.monotonic_ns
    pending: list[bytes] = []
    parent = os.getppid()
    requests = bytearray()
    frame = 0  # bytes in one of the device's frames, as the daemon last said (0: unknown)
    held = 0  # bytes read and not yet forwarded
    first_ns = 0  # when the oldest of them was read
    hold_ns = HOLD_MS * 1_000_000
    # One reused read buffer, as the daemon's readers (baromapd.session): os.read(port,
    # READ_CHUNK) allocates READ_CHUNK bytes and shrinks them to what came, and holding the
    # shrunk blocks while reading on fragments the heap (bench/memory.py --old-read).
    chunk = memoryview(bytearray(READ_CHUNK))

    def forward() -> None:
        os.write(out, b"".join(pending))  # a blocking pipe takes it all
        pending.clear()

    while True:
        events = poll.poll(QUIET_MS if pending else IDLE_MS)
        if not events:
            if pending:
                forward()
                held = 0  # the line went quiet: the next bytes start a frame
            elif os.getppid() != parent:
                return 0
            continue
        if len(events) > 1:
            events.sort(key=lambda event: event[0] != control)  # a request first
        for fd, _ in events:
            if fd == control:
                data = os.read(control, 4096)
                if not data:
                    return 0  # the daemon closed the port
                requests += data
                while requests:
                    if requests[0] == FLUSH_REQUEST[0]:
                        del requests[:1]
                        pending.clear()
                        held = 0
                        os.write(out, pack(FLUSHED, 0))
                    elif len(requests) >= EXPECT.size:
                        frame = EXPECT.unpack_from(requests)[1]
                        del requests[: EXPECT.size]
                    else:
                        break
                continue
            try:
                size = os.readv(port, (chunk,))  # OSError (EIO: unplugged) ends the tap
            except BlockingIOError:
                continue  # the daemon flushed the (non-blocking) port between poll and read
            stamp = monotonic_ns()
            if not size:
                return 0  # hang-up
            data = bytes(chunk[:size])
            if not pending:
                first_ns = stamp
            pending.append(pack(stamp, len(data)))
            pending.append(data)
            held += len(data)
            if frame and held >= frame:
                forward()  # a frame's worth: the daemon need not wait for the line to go quiet
                held %= frame  # what came of the next frame already
            elif not frame and stamp - first_ns >= hold_ns:
                forward()  # a line that never goes quiet, frames of a size not known yet
                held = 0


def realtime() -> bool:
    """Run SCHED_FIFO if the process may (``RLIMIT_RTPRIO``, which the unit's ``LimitRTPRIO=``
    sets; root is not asked for more than its limits say either).

    A tap reads, stamps and sleeps: a few tenths of a percent of a core that can never starve
    anything, but on a busy machine a normal process waits for a CPU for milliseconds now and
    then, and every millisecond of that is in the stamp.
    """
    limit = resource.getrlimit(resource.RLIMIT_RTPRIO)[0]
    if limit == 0:
        return False
    priority = PRIORITY if limit == resource.RLIM_INFINITY else min(PRIORITY, limit)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError:
        return False
    return True


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    port, name = int(args[0]), args[1]
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    name_os_thread(f"baromapd-tap-{name}")
    realtime()
    out = sys.stdout.fileno()
    with contextlib.suppress(OSError):
        fcntl.fcntl(out, _F_SETPIPE_SZ, PIPE_BYTES)
    try:
        return serve(port, out, sys.stdin.fileno())
    except OSError:
        return 1  # the port failed or the daemon went away; the daemon sees the pipe end
    except KeyboardInterrupt:
        return 0


# ---- the daemon's side -------------------------------------------------------------------------
def native_program() -> Path:
    """Where the C tap is: beside this interpreter (a venv's ``bin``, as ``make setup`` and the
    README's install build it; the unit's ``/opt/baromap/bin``), so a checkout's venv runs its
    own build and never another's."""
    return Path(sys.executable).parent / NATIVE_NAME


def python_program() -> tuple[str, ...]:
    """This module as the tap."""
    return (sys.executable, "-m", "baromapd.tap")


@functools.cache
def default_program() -> tuple[str, ...]:
    """The C tap when it was built, else this module; logged once, when first asked."""
    import structlog  # here: `python -m baromapd.tap` would carry it (10 MB) and never log

    log = structlog.get_logger(__name__)
    native = native_program()
    if os.access(native, os.X_OK):
        log.info("port tap", implementation="c", program=str(native))
        return (str(native),)
    log.info(
        "port tap",
        implementation="python",
        program="python -m baromapd.tap",
        why=f"{native} not built (make setup builds it with a C compiler)",
    )
    return python_program()


class Tap:
    """The daemon's end of a tap on an open port: (bytes, stamp) records, one at a time
    (:meth:`read`, for a handshake's replies) or all that came (:meth:`read_all`).

    ``program`` is the tap to run (default: :func:`default_program`); the port's descriptor
    and ``name`` are its arguments."""

    def __init__(
        self, port: int, name: str, program: collections.abc.Sequence[str] | None = None
    ) -> None:
        command = default_program() if program is None else program
        self._proc = subprocess.Popen(
            [*command, str(port), name],
            pass_fds=(port,),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            bufsize=0,
        )
        assert self._proc.stdin is not None and self._proc.stdout is not None
        self._control = self._proc.stdin.fileno()
        self._out = self._proc.stdout.fileno()
        self._poll = select.poll()
        self._poll.register(self._out, select.POLLIN)
        self._buffer = bytearray()
        self._pipe = memoryview(bytearray(PIPE_BYTES))  # reused: see serve()
        self._records: collections.deque[tuple[bytes, int]] = collections.deque()

    def read(self, timeout_ms: int) -> tuple[bytes, int] | None:
        """The next record (bytes, monotonic ns of their read), waiting up to ``timeout_ms``."""
        records = self._records
        if not records and self._poll.poll(timeout_ms):
            self._take()
        return records.popleft() if records else None

    def read_all(self, timeout_ms: int) -> list[tuple[bytes, int]]:
        """Every record the pipe holds (waiting up to ``timeout_ms`` for one), in order.

        A scan comes as one write of several records (one per packet the tap read); taking
        them together lets the daemon decode them in one go instead of one loop turn each.
        """
        records = self._records
        if not records and self._poll.poll(timeout_ms):
            self._take()
        out = list(records)
        records.clear()
        return out

    def discard(self) -> None:
        """Drop everything the tap read so far (the daemon has just flushed the port)."""
        self._records.clear()
        self._buffer.clear()
        os.write(self._control, FLUSH_REQUEST)
        deadline = time.monotonic() + ANSWER_S
        while time.monotonic() < deadline:
            if self._poll.poll(10) and self._take(until_flushed=True):
                return
        raise OSError("the port's tap did not answer a flush")

    def expect(self, frame_bytes: int) -> None:
        """The device's frames are this long (0: unknown): the tap hands a frame over as soon
        as it has a frame's worth of bytes, not once the line has gone quiet."""
        os.write(self._control, EXPECT.pack(b"E", frame_bytes))

    def close(self) -> None:
        proc = self._proc
        for stream in (proc.stdin, proc.stdout):
            if stream is not None:
                with contextlib.suppress(OSError):
                    stream.close()
        try:
            proc.wait(ANSWER_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()

    def _take(self, until_flushed: bool = False) -> bool:
        """Read what the pipe holds into records; True if a flush answer was among it (and
        everything up to it dropped)."""
        size = os.readv(self._out, (self._pipe,))
        if not size:
            code = self._proc.poll()
            raise OSError(f"the port's tap ended (exit {code}): the port failed or hung up")
        buffer = self._buffer
        buffer += self._pipe[:size]
        flushed = False
        offset = 0
        size = RECORD.size
        while len(buffer) - offset >= size:
            stamp, length = RECORD.unpack_from(buffer, offset)
            end = offset + size + length
            if end > len(buffer):
                break
            if stamp == FLUSHED:
                self._records.clear()
                flushed = True
            elif not (until_flushed and not flushed):
                self._records.append((bytes(buffer[offset + size : end]), stamp))
            offset = end
        del buffer[:offset]
        return flushed


if __name__ == "__main__":
    raise SystemExit(main())
