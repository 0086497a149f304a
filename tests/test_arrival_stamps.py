"""Late stamps of a backlog set back after the run (baromap.mapping.arrival_stamps).

Streams are made as baromapd stamps them: a frame read promptly is stamped when it was sent;
the frames sent while the reader was held up arrive in one read at its end, each stamped by
the line time of the frames after it in that read.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from hypothesis import given
from hypothesis import strategies as st

from baromap.mapping.arrival_stamps import MIN_FRAMES, stamped_on_arrival, tighten
from baromap.recording import carmen_import, topics

MS = 1_000_000
T0 = 1_796_000_000_000_000_000  # a Unix time in ns: float64 could not hold it to the ns

I64 = npt.NDArray[np.int64]


def sent(count: int, period_ns: int, jitter_ns: int = 0, seed: int = 0) -> I64:
    """When a steady sender sent each frame: a grid, each off it by up to ``jitter_ns``."""
    rng = np.random.default_rng(seed)
    grid = T0 + np.arange(count, dtype=np.int64) * period_ns
    return grid + rng.integers(-jitter_ns, jitter_ns + 1, count)


def held_up(true: I64, holds: list[tuple[int, int]], line_ns: int) -> I64:
    """Stamps of a reader held up over each ``(start, end)`` (ns after the first frame): the
    frames sent meanwhile are read at its end, each bounded by the line time after it."""
    stamps = true.copy()
    for start, end in holds:
        a, b = T0 + start, T0 + end
        inside = np.flatnonzero((true >= a) & (true < b))
        after = np.arange(len(inside))[::-1]  # frames after each one in the read
        stamps[inside] = b - after * line_ns
    return stamps


def test_a_backlog_comes_back_to_the_period_it_was_sent_at() -> None:
    # an LMS200 at 75 Hz over 500 kbaud: a scan is 7.4 ms of line, one every 13.3 ms
    true = sent(3000, 13_333_333)
    stamps = held_up(true, [(10_000 * MS, 10_360 * MS), (30_000 * MS, 30_150 * MS)], 7_400_000)
    late = stamps - true
    assert late.max() > 150 * MS  # the first of the longer backlog, as recorded
    out = tighten(stamps)
    assert out.period_ns == 13_333_333
    # every frame of a backlog late by more than a period, and only those: less is a jittery
    # sender's ordinary spacing, and stays
    moved = out.t_ns != stamps
    assert np.array_equal(moved, late > 13_333_333)
    assert out.set_back == moved.sum() > 30
    assert np.abs(out.t_ns - true)[moved].max() <= 1  # ns: the grid's rounding
    assert (out.t_ns - true).max() < 13_333_333
    assert np.array_equal(out.t_ns[~moved], stamps[~moved])


def test_a_jittery_sender_keeps_its_stamps_and_its_backlogs_come_back() -> None:
    # SIPs every 100 ms, each up to 5 ms off its slot, a SIP 4 ms of line
    true = sent(3000, 100 * MS, 5 * MS, seed=1)
    assert tighten(true).set_back == 0  # read promptly throughout: nothing to set back
    out = tighten(held_up(true, [(50_000 * MS, 50_800 * MS)], 4 * MS))
    error = out.t_ns - true
    assert out.set_back == 7  # of 8 in the backlog: the last was less than a period late
    assert error.max() < 100 * MS  # 700 ms late before
    assert error.min() > -10 * MS  # two slots' jitter at most


def test_a_pause_and_a_change_of_rate_are_no_backlog() -> None:
    before = sent(500, 20 * MS)
    after = sent(500, 10 * MS) + (before[-1] - T0) + 5_000 * MS  # 5 s of silence, then faster
    out = tighten(np.concatenate([before, after]))
    assert out.set_back == 0


def test_too_short_a_stream_says_no_period() -> None:
    stamps = held_up(sent(MIN_FRAMES - 1, 10 * MS), [(50 * MS, 200 * MS)], 2 * MS)
    out = tighten(stamps)
    assert (out.period_ns, out.set_back) == (0, 0)
    assert np.array_equal(out.t_ns, stamps)


@given(
    period_ms=st.floats(5.0, 200.0),
    jitter=st.floats(0.0, 0.1),
    line=st.floats(0.2, 0.9),
    holds=st.lists(st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 0.6)), max_size=6),
    seed=st.integers(0, 2**16),
)
def test_a_stamp_is_never_set_later_nor_earlier_than_the_jitter_allows(
    period_ms: float, jitter: float, line: float, holds: list[tuple[float, float]], seed: int
) -> None:
    period = int(period_ms * MS)
    jitter_ns = int(jitter * period)
    true = sent(400, period, jitter_ns, seed)
    span = int(true[-1] - T0)
    starts = sorted((int(a * span), int(a * span + d * 1e9)) for a, d in holds)
    merged: list[tuple[int, int]] = []
    for a, b in starts:  # a reader is held up by one thing at a time
        if merged and a <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(b, merged[-1][1]))
        else:
            merged.append((a, b))
    stamps = held_up(true, merged, int(line * (period - 2 * jitter_ns)))
    out = tighten(stamps)
    assert np.all(out.t_ns <= stamps)
    assert np.all(np.diff(out.t_ns) >= 0)
    assert (out.t_ns - true).min() >= -2 * jitter_ns - 1


def test_only_a_recording_baromapd_stamped_is_taken_as_arrivals() -> None:
    assert stamped_on_arrival({topics.METADATA_NAME: {"daemon": "baromapd 0.1.0"}})
    assert not stamped_on_arrival({})
    assert not stamped_on_arrival({topics.METADATA_NAME: {"writer": "baromap 0.1.0"}})
    imported = {carmen_import.METADATA_NAME: {carmen_import.STAMPS_KEY: "log"}}
    assert not stamped_on_arrival(imported)
