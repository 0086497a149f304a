"""Did the robot drive off during a stop? Odometry's answer, for the floor detector.

Inside an elevator car the robot stands still (or turns, or shuffles to make room); leaving
the car means driving a metre or more. The barometer cannot see that, the wheels can: a stop
at a storey's height is a visit once the robot moved ``leave_m`` from where it stood when the
pressure came to rest, and is still part of the ride otherwise.

The pressure comes to rest before the detector knows it (its settle test looks back over a
window), so the watch starts from the pose at the window's start: a short history of poses
is kept for that, bounded in time and length. Odometry drifts in heading, not in a metre of
straight travel, so displacement from that pose is all that is measured.
"""

from __future__ import annotations

import math
from collections import deque

from baromap.messages import NS_PER_S, Odometry

#: Odometry older than this is no evidence about now: the P3-AT itself stops its motors when
#: its host has been silent for 2 s (P2OS watchdog), and a SIP comes every 100 ms.
STALE_NS = 2 * NS_PER_S
#: How far back poses are kept (the settle window and clock jitter between the two streams).
HISTORY_NS = 10 * NS_PER_S
#: At most this many poses kept (10 s of SIPs at 10 Hz, with room for faster sources).
MAX_HISTORY = 1000


class StopWatch:
    """Displacement of the robot since a stop began, from its odometry."""

    __slots__ = ("_history", "_last_t", "_origin", "_since", "moved_m", "samples")

    def __init__(self) -> None:
        self._history: deque[tuple[int, float, float]] = deque(maxlen=MAX_HISTORY)
        self._last_t = -1
        self._origin: tuple[float, float] | None = None
        self._since = -1
        self.moved_m = 0.0
        self.samples = 0

    def live(self, t_ns: int) -> bool:
        """Whether odometry is arriving (a pose within :data:`STALE_NS` of ``t_ns``)."""
        return self._last_t >= 0 and t_ns - self._last_t <= STALE_NS

    def update(self, odometry: Odometry) -> bool:
        """Take a pose; False (and ignored) if it is not finite or older than the last."""
        t, x, y = odometry.t_ns, odometry.x_m, odometry.y_m
        if t < self._last_t or not (math.isfinite(x) and math.isfinite(y)):
            return False
        self._last_t = t
        self.samples += 1
        history = self._history
        history.append((t, x, y))
        while history[0][0] < t - HISTORY_NS:
            history.popleft()
        if self._since >= 0 and t >= self._since:
            self._measure(x, y)
        return True

    def watch(self, since_ns: int) -> None:
        """Start measuring from the pose at ``since_ns`` (moves after it count)."""
        self._since = since_ns
        self._origin = None
        self.moved_m = 0.0
        for t, x, y in self._history:
            if t <= since_ns or self._origin is None:
                self._origin = (x, y)
            if t > since_ns:
                self._measure(x, y)

    def stop(self) -> None:
        self._since = -1
        self._origin = None
        self.moved_m = 0.0

    def _measure(self, x: float, y: float) -> None:
        if self._origin is None:
            self._origin = (x, y)
            return
        distance = math.hypot(x - self._origin[0], y - self._origin[1])
        self.moved_m = max(self.moved_m, distance)
