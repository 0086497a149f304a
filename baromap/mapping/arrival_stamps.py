"""Stamps a host made as frames arrived, with the late ones of a backlog set back.

baromapd stamps a scan or a SIP by the reads that brought its bytes: the stamp is an upper
bound of when the device sent it, tight when the reader was prompt. When a reader (or the line's
far end) is held up, the frames sent meanwhile arrive together and each is bounded only by the
line time of the bytes after it: a backlog sent a period apart is stamped a line time apart,
its first frame late by the whole hold-up. On a loaded machine that is hundreds of
milliseconds, and a scan that late in a fast turn is placed tens of degrees off. Live, nothing
better is known when the frame is published, and the recording keeps the stamps as they were
published. After the run every later frame is known, and a device that sends at a steady rate
bounds each frame by every later one: frame ``k`` was sent no later than frame ``k + j``'s stamp
less ``j`` periods.

The period is the stream's own, not the device's documented one (the demo's twins run several
times faster than the devices they imitate): the lower quartile of its spacing over the run. A
steady sender's spacing is its period nearly always; a jittery sender's lower quartile lies
below its mean spacing, so that no frame is set earlier than it was sent by more than the
jitter; backlogs are a small share of a run and do not move it. A frame is set back only where
the bound undercuts its stamp by more than a period: within that is a jittery sender's ordinary
spacing, not a backlog (at half a period, 168 of a demo run's 6020 SIPs moved where only 6 were
over 20 ms late, and 58 of them ended more than 5 ms early). The bound looks at most
:data:`WINDOW_S` ahead.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from baromap.arrays import IntArray
from baromap.recording import topics

#: The share of a stream's spacings under its period as taken (a quartile: see above).
PERIOD_QUANTILE: Final = 25.0
#: Fewest frames whose spacing tells a period.
MIN_FRAMES: Final = 32
#: How far ahead a later frame bounds an earlier one (s): a backlog lasts less.
WINDOW_S: Final = 1.0


@dataclass(frozen=True, slots=True)
class Tightened:
    """A stream's stamps with its backlogs set back, and what was done."""

    t_ns: IntArray
    period_ns: int  # 0: too few frames to tell
    set_back: int  # frames set back
    most_ns: int  # the most any frame was set back


def stamped_on_arrival(metadata: dict[str, dict[str, str]]) -> bool:
    """Whether the recording's scans and odometry were stamped by a host as they arrived
    (baromapd), not by a clock that was there when they were measured (an imported log)."""
    header = metadata.get(topics.METADATA_NAME, {})
    return header.get(topics.DAEMON_KEY, "").startswith(topics.DAEMON_NAME)


def tighten(t_ns: IntArray) -> Tightened:
    """The stamps of one steady stream (in arrival order) with its backlogs set back."""
    t = np.asarray(t_ns, dtype=np.int64)
    n = len(t)
    if n < MIN_FRAMES:
        return Tightened(t, 0, 0, 0)
    period = int(np.percentile(np.diff(t), PERIOD_QUANTILE))
    if period <= 0:
        return Tightened(t, 0, 0, 0)
    bound = t.copy()
    for j in range(1, min(n - 1, max(1, int(WINDOW_S * 1e9 / period))) + 1):
        np.minimum(bound[:-j], t[j:] - j * period, out=bound[:-j])
    late = t - bound > period
    if not late.any():
        return Tightened(t, period, 0, 0)
    # never out of order (a bound at the window's edge may undercut a frame before it)
    out = np.maximum.accumulate(np.where(late, bound, t))
    return Tightened(out, period, int(late.sum()), int((t - out).max()))
