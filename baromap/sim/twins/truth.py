"""The truth of what a twin sent: for each frame, the instant its content was true.

A daemon stamps every message with its own estimate of when the device acquired it (receive
time, corrected for line time or a device clock). To measure how wrong that estimate is, the
twin records the true instant on the host's ``time.monotonic_ns()`` clock (CLOCK_MONOTONIC:
one clock for every process on the machine, so a daemon in another process can compare), keyed
so a recorded message can be matched to it:

- barometer: the SAMPLE frame's ``seq`` (and ``boot``, as seq restarts at 0 after a power-up);
  the instant the sample was measured;
- LMS200: ``index``, the number of scan telegrams sent since the twin started; the instant the
  scan was taken (the twin samples one pose per telegram, just before sending it);
- P3-AT: ``index``, the number of SIPs sent since the twin started; the instant of its pose.

The log is bounded (the oldest records go first) and thread-safe; a sink (for example
:class:`JsonlTruthWriter`, what ``baromap sim --truth-log`` uses) receives every record as it
is made.
"""

from __future__ import annotations

import collections
import json
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import IO, Final

from baromap.errors import ConfigError

#: Records kept in memory per twin: over ten minutes of the fastest stream (75 scans/s).
DEFAULT_TRUTH_RECORDS: Final = 65536
#: A JSONL writer flushes at least this often, so a reader in another process keeps up.
FLUSH_INTERVAL_S: Final = 0.5


@dataclass(frozen=True, slots=True)
class FrameTruth:
    """When one frame's content was true.

    ``index`` counts the frames of this kind the twin has sent since it started (0-based,
    across power cycles); ``boot`` counts power-ups before this frame (0 = the first);
    ``seq`` is the frame's own sequence number where the protocol has one (barometer SAMPLE).
    ``t_sim_s`` is the simulated time the content belongs to: route time for a SIP's pose and a
    scan (it stands still while the robot's watchdog holds it), the run's clock for a sample.
    """

    device: str
    index: int
    t_mono_ns: int
    t_sim_s: float
    boot: int = 0
    seq: int | None = None

    def to_json(self) -> str:
        return json.dumps({k: v for k, v in asdict(self).items() if v is not None})


TruthSink = Callable[[FrameTruth], None]


class TruthLog:
    """The last ``capacity`` truth records of one twin, looked up by index or sequence number."""

    def __init__(
        self, device: str, capacity: int = DEFAULT_TRUTH_RECORDS, sink: TruthSink | None = None
    ) -> None:
        if capacity < 1:
            raise ConfigError(f"a truth log keeps at least one record, not {capacity}")
        self.device = device
        self.sink = sink
        self._records: collections.deque[FrameTruth] = collections.deque(maxlen=capacity)
        self._lock = threading.Lock()
        self._next_index = 0

    def record(
        self, t_mono_ns: int, t_sim_s: float, *, boot: int = 0, seq: int | None = None
    ) -> FrameTruth:
        """Note one frame sent; the caller measured ``t_mono_ns`` when its content was true."""
        with self._lock:
            truth = FrameTruth(self.device, self._next_index, t_mono_ns, t_sim_s, boot, seq)
            self._next_index += 1
            self._records.append(truth)
        if self.sink is not None:
            self.sink(truth)
        return truth

    @property
    def count(self) -> int:
        """Frames recorded since the start (including those no longer kept)."""
        return self._next_index

    def records(self) -> list[FrameTruth]:
        """A snapshot of the records kept, oldest first."""
        with self._lock:
            return list(self._records)

    def by_index(self, index: int) -> FrameTruth | None:
        with self._lock:
            if not self._records:
                return None
            first = self._records[0].index
            if not first <= index < first + len(self._records):
                return None
            return self._records[index - first]

    def by_seq(self, seq: int, boot: int | None = None) -> FrameTruth | None:
        """The latest kept record with this sequence number (of this boot, if given)."""
        with self._lock:
            for truth in reversed(self._records):
                if truth.seq == seq and (boot is None or truth.boot == boot):
                    return truth
        return None


class JsonlTruthWriter:
    """Truth records from any number of twins, one JSON object per line, flushed often.

    Close it when the twins stop (``contextlib.closing``).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self._file: IO[str] = self.path.open("w", encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"cannot write the truth log {self.path}: {exc}") from exc
        self._lock = threading.Lock()
        self._flushed = time.monotonic()

    def __call__(self, truth: FrameTruth) -> None:
        line = truth.to_json() + "\n"
        with self._lock:
            if self._file.closed:
                return
            self._file.write(line)
            now = time.monotonic()
            if now - self._flushed >= FLUSH_INTERVAL_S:
                self._file.flush()
                self._flushed = now

    def close(self) -> None:
        with self._lock:
            if not self._file.closed:
                self._file.close()


def read_truth_log(path: str | Path) -> list[FrameTruth]:
    """Every record of a JSONL truth log (a partly written last line is skipped)."""
    out: list[FrameTruth] = []
    with Path(path).open(encoding="utf-8") as handle:
        for line in handle:
            try:
                fields = json.loads(line)
            except json.JSONDecodeError:
                continue
            out.append(FrameTruth(**fields))
    return out
