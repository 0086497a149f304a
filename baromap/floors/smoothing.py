"""The paper's double exponential (Holt) smoothing, as a streaming filter and in batch.

``S_t = a y_t + (1 - a)(S_{t-1} + b_{t-1})``, ``b_t = g (S_t - S_{t-1}) + (1 - g) b_{t-1}``,
started with ``S_1 = y_1`` and ``b_1 = y_2 - y_1``. The level ``S`` follows the pressure without
the lag of a plain moving average during a steady climb, because the trend ``b`` (pressure
change per sample) extrapolates it; ``b`` is the "rate of change" the paper thresholds.

The recursion is a linear time-invariant filter, so the batch version runs it through
``scipy.signal.lfilter`` (a second-order IIR for ``S``, a first-order one for ``b``) from the
state after the first two samples; the result equals the streaming filter to rounding.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from baromap.errors import ConfigError


def _check(alpha: float, gamma: float) -> None:
    if not (0.0 < alpha <= 1.0 and 0.0 < gamma <= 1.0):
        raise ConfigError(f"smoothing constants must be in (0, 1], not {alpha}, {gamma}")


class DoubleExponentialSmoother:
    """Streaming Holt smoother with the paper's per-sample constants.

    The paper starts the trend from the *second* sample (``b_1 = y_2 - y_1``); a stream cannot
    look ahead, but ``S_1 = y_1`` does not depend on ``b_1``, so the first output is exact and
    ``b_1`` is filled in when the second sample arrives. ``trend`` is 0 until then.
    """

    __slots__ = ("_first", "_n", "alpha", "gamma", "level", "trend")

    def __init__(self, alpha: float, gamma: float) -> None:
        _check(alpha, gamma)
        self.alpha = alpha
        self.gamma = gamma
        self.level = 0.0
        self.trend = 0.0
        self._first = 0.0
        self._n = 0

    def update(self, y: float) -> tuple[float, float]:
        """Feed one sample, return ``(S_t, b_t)``."""
        n = self._n
        if n >= 2:
            previous = self.level
            level = self.alpha * y + (1.0 - self.alpha) * (previous + self.trend)
            self.trend = self.gamma * (level - previous) + (1.0 - self.gamma) * self.trend
            self.level = level
        elif n == 0:
            self.level = self._first = y
        else:
            # b_1 = y_2 - y_1 makes S_2 = y_2 and b_2 = b_1 exactly.
            self.trend = y - self._first
            self.level = y
        self._n = n + 1
        return self.level, self.trend


def double_exponential_smoothing(
    y: npt.ArrayLike, alpha: float, gamma: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Batch Holt smoothing: arrays ``S`` and ``b`` (per sample) for the series ``y``."""
    from scipy.signal import lfilter, lfiltic

    _check(alpha, gamma)
    x = np.asarray(y, dtype=np.float64)
    n = x.shape[0]
    level = np.empty(n)
    trend = np.zeros(n)
    if n == 0:
        return level, trend
    level[0] = x[0]
    if n == 1:
        return level, trend
    level[1] = x[1]
    trend[0] = trend[1] = x[1] - x[0]
    if n > 2:
        a, g = alpha, gamma
        num = [a, -a * (1.0 - g)]
        den = [1.0, -(2.0 - a - a * g), 1.0 - a]
        zi = lfiltic(num, den, y=[level[1], level[0]], x=[x[1], x[0]])
        level[2:], _ = lfilter(num, den, x[2:], zi=zi)
        # b_t - (1-g) b_{t-1} = g (S_t - S_{t-1}), started from b_2.
        zb = lfiltic([g, -g], [1.0, -(1.0 - g)], y=[trend[1]], x=[level[1]])
        trend[2:], _ = lfilter([g, -g], [1.0, -(1.0 - g)], level[2:], zi=zb)
    return level, trend
