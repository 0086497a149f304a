"""The settle test of the online detector: were the latest samples still all along?

A change of floor ends when, over the last ``settle_s`` seconds, the smoothed pressure stayed
within the band a slow vertical speed would cross in that time and the least-squares slope of
the raw pressures is below that speed. This module keeps that window so the test costs O(1)
per sample at any sample rate.
"""

from __future__ import annotations

from collections import deque

from baromap.messages import NS_PER_S

#: How often the window's running sums are recomputed around a new origin, ns (keeps the sums
#: small, so subtracting the samples that leave the window loses no precision).
_REBASE_NS = 60 * NS_PER_S


class StillWindow:
    """The latest samples spanning at least ``window_ns``: were they still all along?

    Holds the shortest run of recent samples that spans the window and counts at least
    ``min_samples`` (a barometer read more slowly than that many per window, every 2 s
    against a window of 1.5 s, still gets a line through enough points), with running sums for a
    least-squares line through the raw pressures (:meth:`slope`) and monotonic queues for the
    highest and lowest smoothed pressure (:meth:`spread`), so each sample costs O(1) amortised
    at any sample rate. Sums are taken about an origin that is moved every ``_REBASE_NS``, so
    they stay small and removing old samples does not eat their precision.
    """

    __slots__ = (
        "_highs",
        "_lows",
        "_p0",
        "_samples",
        "_sx",
        "_sxx",
        "_sxy",
        "_sy",
        "_t0",
        "min_samples",
        "window_ns",
    )

    def __init__(self, window_ns: int, min_samples: int = 1) -> None:
        self.window_ns = window_ns
        self.min_samples = min_samples
        self._samples: deque[tuple[int, float, float]] = deque()  # (t_ns, x s, y Pa)
        self._highs: deque[tuple[int, float]] = deque()  # (t_ns, smoothed), decreasing
        self._lows: deque[tuple[int, float]] = deque()  # (t_ns, smoothed), increasing
        self._t0 = 0
        self._p0 = 0.0
        self._sx = self._sxx = self._sy = self._sxy = 0.0

    @property
    def count(self) -> int:
        return len(self._samples)

    @property
    def start_ns(self) -> int:
        """Time of the oldest sample in the window (-1 when empty)."""
        return self._samples[0][0] if self._samples else -1

    def clear(self) -> None:
        self._samples.clear()
        self._highs.clear()
        self._lows.clear()
        self._sx = self._sxx = self._sy = self._sxy = 0.0

    def push(self, t: int, p: float, smoothed: float) -> None:
        samples = self._samples
        if not samples:
            self._t0, self._p0 = t, p
        elif t - self._t0 > _REBASE_NS:
            self._rebase(t, p)
        x = (t - self._t0) * 1e-9
        y = p - self._p0
        samples.append((t, x, y))
        self._sx += x
        self._sxx += x * x
        self._sy += y
        self._sxy += x * y
        highs = self._highs
        while highs and highs[-1][1] <= smoothed:
            highs.pop()
        highs.append((t, smoothed))
        lows = self._lows
        while lows and lows[-1][1] >= smoothed:
            lows.pop()
        lows.append((t, smoothed))
        limit = t - self.window_ns
        keep = max(1, self.min_samples)
        while len(samples) > keep and samples[1][0] <= limit:
            _, x, y = samples.popleft()
            self._sx -= x
            self._sxx -= x * x
            self._sy -= y
            self._sxy -= x * y
        oldest = samples[0][0]
        while highs[0][0] < oldest:
            highs.popleft()
        while lows[0][0] < oldest:
            lows.popleft()

    def slope(self) -> float:
        """Least-squares slope of the raw pressures over the window, Pa/s (0 if undefined)."""
        n = len(self._samples)
        sxx = n * self._sxx - self._sx * self._sx
        if n < 2 or sxx <= 0.0:
            return 0.0
        return (n * self._sxy - self._sx * self._sy) / sxx

    def spread(self) -> float:
        """Highest minus lowest smoothed pressure over the window, Pa."""
        if not self._samples:
            return 0.0
        return self._highs[0][1] - self._lows[0][1]

    def _rebase(self, t: int, p: float) -> None:
        shift_y = self._p0 - p
        self._t0, self._p0 = t, p
        old = list(self._samples)
        self._samples.clear()
        self._sx = self._sxx = self._sy = self._sxy = 0.0
        for ti, _, yi in old:
            x = (ti - t) * 1e-9
            y = yi + shift_y
            self._samples.append((ti, x, y))
            self._sx += x
            self._sxx += x * x
            self._sy += y
            self._sxy += x * y
