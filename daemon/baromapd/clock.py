"""Clocks: the host's monotonic clock mapped to Unix time once, and device clocks fitted to it.

Every message is stamped on the host's monotonic clock and converted to Unix nanoseconds with
one mapping taken at start (``t = wall0 + monotonic - mono0``): an NTP step or a person
setting the date during a run cannot bend the data. The mapping is recorded in the metadata,
so a reader can redo it against a better wall clock later.

The barometer board stamps each sample with its own microsecond clock, which is far less
jittery than USB delivery but runs at its own rate (a ceramic resonator is off by up to
0.5 %), wraps every 71.6 minutes and restarts when the board resets. :class:`DeviceClockFit`
maps it to host time with a *lower envelope*: USB and scheduling can only ever delay a frame,
so the receive times lie on or above the line ``host = a + b * device`` and the line is the
support of their lower convex hull. Of all lines below every point, the one closest to the
points on average touches the hull above the mean device time (the linear programme of Moon,
Skelly and Towsley, "Estimation and removal of clock skew from network delay measurements",
1999). Points are thinned to the lowest per bucket of device time, so the hull holds at most a
window's worth of buckets and costs nothing per sample.
"""

from __future__ import annotations

import itertools
import time
from collections import deque
from collections.abc import Callable
from typing import Final

NS_PER_US: Final = 1000
TIME_MODULO_US: Final = 1 << 32


class HostClock:
    """Host monotonic nanoseconds to Unix nanoseconds, by one offset taken at start.

    ``wall_ns`` and ``mono_ns`` are injectable so tests can step the wall clock.
    """

    def __init__(
        self,
        wall_ns: Callable[[], int] = time.time_ns,
        mono_ns: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self._mono = mono_ns
        before = mono_ns()
        wall = wall_ns()
        after = mono_ns()
        self.mono0_ns = (before + after) // 2
        self.wall0_ns = wall

    def monotonic_ns(self) -> int:
        return self._mono()

    def unix_ns(self, mono_ns: int) -> int:
        return self.wall0_ns + mono_ns - self.mono0_ns

    def now_unix_ns(self) -> int:
        return self.unix_ns(self._mono())

    def metadata(self) -> dict[str, str]:
        return {
            "clock": "unix_ns = wall0_ns + CLOCK_MONOTONIC_ns - mono0_ns",
            "clock_wall0_ns": str(self.wall0_ns),
            "clock_mono0_ns": str(self.mono0_ns),
        }


def transmission_ns(byte_count: int, baud: int) -> int:
    """Line time of ``byte_count`` bytes at 8N1 (ten bit times per byte)."""
    return byte_count * 10 * 1_000_000_000 // baud


class LinePosition:
    """When a decoded frame's last byte arrived, from the reads that brought it.

    Every read that returned bytes bounds the frame's end from above. A read at ``t`` that
    brought the frame's end and ``n`` bytes after it: the end was at most ``t`` minus the line
    time of those ``n`` bytes (they followed it, perhaps after a pause). A read at ``t`` that
    ended inside the frame, ``r`` bytes short of its end: the end was at most ``t`` plus the
    line time of those ``r`` bytes, because within a frame the line does not pause. A read that
    came late (a busy machine, the GIL held elsewhere) gives a loose bound and a prompt one a
    tight bound, so the stamp is the least of them: one prompt read anywhere in the frame is
    enough. That is also what lets a reader sleep through the rest of a frame once it has seen
    the frame's first bytes (``DeviceSession.read_pause_ns``): the read after the sleep is late
    on purpose, the one woken by the frame's first bytes is not. Reads that ended before the
    frame began say nothing (the line may have been idle). Positions count bytes fed and bytes
    the decoder accounted for; a resync (discarded bytes reported late) can only make a
    bytes-after count too large, which the read's length caps.
    """

    #: Reads remembered for a frame in progress (a 9600 baud SIP in 1 ms packets is ~40).
    READS_KEPT: Final = 64

    def __init__(self) -> None:
        self._reads: deque[tuple[int, int, int]] = deque(maxlen=self.READS_KEPT)
        self.reset()

    def reset(self) -> None:
        self.fed = 0
        self.consumed = 0
        self._read_ns = 0
        self._reads.clear()  # (bytes fed up to the read's end, its length, when it returned)

    def chunk(self, size: int, read_ns: int) -> None:
        """A read of ``size`` bytes returned at ``read_ns`` (call before decoding it)."""
        self.consumed = min(self.consumed, self.fed)
        self.fed += size
        self._read_ns = read_ns
        self._reads.append((self.fed, size, read_ns))

    @property
    def pending(self) -> int:
        """Bytes read that no decoded frame has accounted for yet (a frame in progress)."""
        return max(0, self.fed - self.consumed)

    def skip(self, size: int) -> None:
        """Bytes that were no frame (discarded, a lone ACK)."""
        self.consumed += size
        self._forget_before(self.consumed)

    def end_ns(self, size: int, baud: int) -> int:
        """Arrival of the last byte of the next decoded frame, ``size`` bytes on the line."""
        started = self.consumed
        end = self.consumed = started + size
        best = self._read_ns
        for fed, length, read_ns in self._reads:
            if fed <= started:
                continue  # ended before the frame began
            if fed < end:
                bound = read_ns + transmission_ns(end - fed, baud)
            else:
                bound = read_ns - transmission_ns(min(length, fed - end), baud)
            best = min(best, bound)
            if fed >= end:
                break  # later reads only add bytes after the end: looser
        self._forget_before(end)
        return best

    def _forget_before(self, position: int) -> None:
        """Drop reads that ended at or before ``position``: no later frame can use them."""
        reads = self._reads
        while len(reads) > 1 and reads[0][0] <= position:
            reads.popleft()


class DeviceClockFit:
    """A device's microsecond clock to host monotonic ns, by a running lower-envelope fit.

    :meth:`update` takes the device stamp (u32, wrapping) and the host time the frame was
    *sent* (receive time of its last byte minus its line time); it returns the host time of
    the device stamp, never later than the send time. A device clock that runs backwards is a
    device reset: the fit starts again (so does :meth:`reset`, for a HELLO after a reset).

    Stamps always increase, across resets too: while the fit is young its line moves at every
    new bucket, and a frame stamped at its send time (the line above it) can be followed by one
    the lowered line puts earlier (a clock running fast, as the demo's 6x twins' do). A later
    frame is never stamped before an earlier one; it gets the earlier stamp plus 1 ns at least.
    """

    def __init__(self, window_s: float = 60.0, bucket_s: float = 1.0) -> None:
        self._bucket_us = max(1, round(bucket_s * 1e6))
        self._buckets: deque[tuple[int, int]] = deque(maxlen=max(2, round(window_s / bucket_s)))
        self.resets = 0
        self._last_ns: int | None = None  # the last stamp given: the next is later
        self.reset()
        self.resets = 0

    def reset(self) -> None:
        self._last_raw: int | None = None
        self._device_us = 0
        self._buckets.clear()
        self._current: tuple[int, int] | None = None  # lowest (device_us, residual) this bucket
        self._current_bucket = -1
        # Line: host_ns = device_us * 1000 + offset0 + slope * (device_us - x0)
        self._x0 = 0
        self._offset0 = 0.0
        self._slope = 0.0
        self._fitted = False
        self.resets += 1

    @property
    def skew_ppm(self) -> float:
        """How fast the device clock runs against the host's, in parts per million."""
        return -self._slope / NS_PER_US * 1e6 if self._fitted else 0.0

    def unwrap(self, raw_us: int) -> int | None:
        """Continuous device microseconds, or None if the clock ran backwards (a reset)."""
        if self._last_raw is None:
            self._device_us = raw_us
        else:
            delta = (raw_us - self._last_raw) % TIME_MODULO_US
            if delta >= TIME_MODULO_US // 2:
                return None
            self._device_us += delta
        self._last_raw = raw_us
        return self._device_us

    def update(self, raw_us: int, sent_ns: int) -> int:
        device_us = self.unwrap(raw_us)
        if device_us is None:
            self.reset()
            device_us = self.unwrap(raw_us)
            assert device_us is not None
        residual = sent_ns - device_us * NS_PER_US
        bucket = device_us // self._bucket_us
        changed = False
        if bucket != self._current_bucket:
            if self._current is not None:
                self._buckets.append(self._current)
            self._current_bucket = bucket
            self._current = (device_us, residual)
            changed = True
        elif self._current is None or residual < self._current[1]:
            self._current = (device_us, residual)
            changed = True
        if changed or not self._fitted:
            self._fit()
        estimate = device_us * NS_PER_US + round(
            self._offset0 + self._slope * (device_us - self._x0)
        )
        stamp = min(estimate, sent_ns)
        if self._last_ns is not None and stamp <= self._last_ns:
            stamp = self._last_ns + 1
        self._last_ns = stamp
        return stamp

    def _fit(self) -> None:
        points = list(self._buckets)
        if self._current is not None:
            points.append(self._current)
        if not points:
            return
        x0 = points[0][0]
        xs = [float(x - x0) for x, _ in points]
        ys = [float(r) for _, r in points]
        hull = _lower_hull(xs, ys)
        self._x0 = x0
        self._fitted = True
        if len(hull) == 1:
            self._offset0, self._slope = ys[hull[0]], 0.0
            return
        mean_x = sum(xs) / len(xs)
        a, b = hull[0], hull[1]
        for a, b in itertools.pairwise(hull):  # noqa: B007 (the segment found is used below)
            if xs[b] >= mean_x:
                break
        slope = (ys[b] - ys[a]) / (xs[b] - xs[a])
        self._slope = slope
        self._offset0 = ys[a] - slope * xs[a]


def _lower_hull(xs: list[float], ys: list[float]) -> list[int]:
    """Indices of the lower convex hull of points sorted by x (Andrew's monotone chain)."""
    hull: list[int] = []
    for i in range(len(xs)):
        while len(hull) >= 2:
            a, b = hull[-2], hull[-1]
            cross = (xs[b] - xs[a]) * (ys[i] - ys[a]) - (ys[b] - ys[a]) * (xs[i] - xs[a])
            if cross > 0:
                break
            hull.pop()
        if hull and xs[hull[-1]] == xs[i]:
            if ys[i] < ys[hull[-1]]:
                hull[-1] = i
            continue
        hull.append(i)
    return hull
