"""The SLAM run more than once, keeping the run whose revisits agree best with the scans.

Why: one run of the SLAM is one draw. Its discrete choices (the candidate a search keeps, the
closure that passes a threshold, the group of weak closures that forms first) flip under
changes of the odometry far below any sensor's noise, and on a sparse log (a scan every metre
or more, where each choice weighs much) the figures after them spread widely: on a scan every
2-3 m the same seed's ATE against GMapping's poses spans 0.12 to 0.45 m over four runs with
the odometry moved by half a micrometre (docs/mapping.md, "Restarts"). A particle filter
such as GMapping keeps several such histories and the one whose scans agree best; this does the
same with whole runs, judged without a reference by :mod:`baromap.mapping.revisits`: every
run's scans against the scans of the same places seen after a long way round, all runs on
the pairs the first run chose, so no run picks the pairs that flatter it.

What it cannot judge it does not choose: a run with no revisit at all (a corridor driven
once) has nothing to score, and the first run is kept without the others being made.

The runs do not depend on each other (only their scoring waits for the first), so with
``workers`` > 1 runs 2.. are made in forked processes while the first is made here: the same
runs, bit for bit, in about two thirds of the time on two cores.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing import get_context
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess

import numpy as np
import structlog

from baromap.arrays import BoolArray, FloatArray, IntArray
from baromap.errors import ConfigError
from baromap.mapping.revisits import ScanGeometry, consistency, revisit_partners
from baromap.mapping.scans import ScanBlock
from baromap.mapping.slam import BETWEEN_FLOORS, SlamConfig, SlamResult, run_slam

log = structlog.get_logger(__name__)

#: Each run after the first sees the odometry moved by at most this much in every
#: coordinate (metres, radians): nothing a robot's sensors could tell apart, enough for the
#: SLAM's discrete choices to fall anew (a change of 5e-7 already does, docs/mapping.md,
#: "Restarts").
RESTART_JITTER = 1e-6
#: A later run replaces the first only if its revisits agree better by more than this share.
#: Runs of one quality differ by up to 1 % (their ATE within a centimetre of each other), a
#: run gone wrong at a revisit by 8-90 %; when the runs agree about equally the score cannot
#: tell them apart, and the first run, the odometry as given, is kept. 2 % costs a few
#: millimetres of the mean ATE against no margin and still keeps every run gone wrong out
#: (docs/decisions.md, "The best agreeing of K runs, judged without a reference").
RESTART_MARGIN = 0.02
#: Mixed into the seed of each run's jitter, so it is its own stream, apart from the bench's
#: draws (``laser_logs.perturbed``).
_RESTART_STREAM = 2611


def check_runs(runs: int, workers: int = 1) -> None:
    """A run count (and a count of processes to make them in) a caller can check before the
    work that leads to the SLAM."""
    for name, value in (("runs", runs), ("workers", workers)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ConfigError(
                f"the SLAM's {name} must be a whole number of at least 1, got {value!r}"
            )


def jittered(odom: FloatArray, stream: list[int], amount: float) -> FloatArray:
    """``odom`` moved by at most ``amount`` in every coordinate, the same for the same
    ``stream`` (the seed words of its own generator): a change no sensor could tell apart, for
    the SLAM's discrete choices to fall anew (these runs, the bench's draws)."""
    rng = np.random.default_rng(stream)
    moved: FloatArray = odom + rng.uniform(-amount, amount, np.shape(odom))
    return moved


def _jittered(odom: FloatArray, run: int) -> FloatArray:
    """Run ``run``'s odometry (0-based; run 0 sees it as given)."""
    return odom if run == 0 else jittered(odom, [_RESTART_STREAM, run], RESTART_JITTER)


@dataclass(frozen=True, slots=True)
class _Inputs:
    """What every run maps: all but the jitter of its odometry."""

    scans: ScanBlock
    odom: FloatArray
    floor: IntArray
    visit: IntArray
    config: SlamConfig | None
    travel: FloatArray | None
    blind: BoolArray | None
    breaks: BoolArray | None

    def run(self, run: int, progress: Callable[[int], None] | None = None) -> SlamResult:
        """Run ``run`` (0-based) of the SLAM on these inputs."""
        return run_slam(
            self.scans,
            _jittered(self.odom, run),
            self.floor,
            self.visit,
            config=self.config,
            progress=progress,
            travel=self.travel,
            blind=self.blind,
            breaks=self.breaks,
        )


def _make_runs(send: Connection, inputs: _Inputs, runs: list[int]) -> None:
    """A worker process: make these runs and send each back as it is done."""
    for run in runs:
        send.send((run, inputs.run(run)))
    send.close()


class _Workers:
    """Runs 2.. made in forked processes while the first is made in the caller's.

    Forked, a worker inherits the scans instead of having them pickled to it; only its
    results travel back. A run a worker could not deliver (the process killed, out of
    memory) is made in the caller's process instead, so nothing is lost but time.
    """

    def __init__(self, workers: int, runs: list[int], inputs: _Inputs) -> None:
        self._inputs = inputs
        self._done: dict[int, SlamResult] = {}
        self._links: list[tuple[Connection, BaseProcess]] = []
        if threading.active_count() > 1:
            # a fork copies other threads' locks in whatever state they are (a daemon, a
            # live publisher): the runs are made here
            log.info("slam restarts made in one process: this one runs other threads")
            return
        try:
            context = get_context("fork")
        except ValueError as exc:  # a platform without fork: the runs are made here
            log.info("slam restarts made in one process", error=str(exc))
            return
        for share in (runs[i::workers] for i in range(workers)):
            if not share:
                continue
            receive, send = context.Pipe(duplex=False)
            process = context.Process(target=_make_runs, args=(send, inputs, share), daemon=True)
            try:
                process.start()
            except (OSError, RuntimeError) as exc:  # no more processes: made here instead
                log.warning("slam restarts made in fewer processes", error=str(exc))
                receive.close()
                send.close()
                break
            send.close()
            self._links.append((receive, process))

    @property
    def processes(self) -> int:
        """Processes making the runs, the caller's among them."""
        return 1 + len(self._links)

    def result(self, run: int) -> SlamResult:
        """Run ``run``, waiting for the worker that makes it."""
        while run not in self._done and self._links:
            receive = self._links[0][0]
            try:
                got, result = receive.recv()
            except EOFError:  # that worker has sent all it will
                self._end(*self._links.pop(0))
                continue
            self._done[got] = result
        if run not in self._done:
            log.warning("slam restart made here: its worker process ended without it", run=run)
            self._done[run] = self._inputs.run(run)
        return self._done.pop(run)

    def stop(self) -> None:
        """End the workers, whatever they were doing."""
        for link in self._links:
            self._end(*link)
        self._links = []

    @staticmethod
    def _end(receive: Connection, process: BaseProcess) -> None:
        process.terminate()  # nothing if it has ended
        process.join()
        process.close()
        receive.close()


def run_slam_best_of(
    scans: ScanBlock,
    odom: FloatArray,
    floor: IntArray,
    visit: IntArray,
    *,
    runs: int = 1,
    config: SlamConfig | None = None,
    progress: Callable[[int], None] | None = None,
    geometry: ScanGeometry | None = None,
    workers: int = 1,
    travel: FloatArray | None = None,
    blind: BoolArray | None = None,
    breaks: BoolArray | None = None,
) -> SlamResult:
    """:func:`run_slam` ``runs`` times, the odometry of runs 2.. jittered by
    :data:`RESTART_JITTER`; the run whose revisits agree best with the scans is returned, the
    first unless another agrees better by more than :data:`RESTART_MARGIN`.

    Its ``stats`` gain ``runs`` (made), ``run_kept`` (0-based), ``revisits_mm`` (the kept
    run's score; NaN when there was nothing to score) and ``run_processes`` (the processes
    they were made in). ``progress`` follows the first run.
    ``geometry``: ``scans`` prepared for scoring, by a caller that holds them already (a log
    mapped for several seeds); made here otherwise. ``workers``: processes to make the runs
    in, this one among them (runs 2.. go to the others; the result does not depend on it).
    ``travel``, ``blind``, ``breaks``: the odometry's drive up to each scan, the scans it said
    nothing about and where it broke, for every run (see :func:`run_slam`).
    """
    check_runs(runs, workers)
    later = list(range(1, runs))
    # runs 2.. start in other processes before the first is made here, and are stopped
    # unread if nothing can be scored
    inputs = _Inputs(scans, odom, floor, visit, config, travel, blind, breaks)
    pool = _Workers(workers - 1, later, inputs) if workers > 1 and later else None
    try:
        first = inputs.run(0, progress)
        processes = 1 if pool is None else pool.processes
        first.stats.update(runs=1, run_kept=0, revisits_mm=float("nan"), run_processes=1)
        if runs == 1:
            return first
        geometry = geometry or ScanGeometry(scans)
        group = np.where(np.asarray(floor) == BETWEEN_FLOORS, -1, floor)
        partners = revisit_partners(first.scan_poses, geometry.radius_m, group=group)
        scores = [consistency(geometry, first.scan_poses, partners).mean_m]
        if not np.isfinite(scores[0]):
            log.info("slam restarts skipped: the run has no revisit to judge them by")
            return first
        best, kept = first, 0
        for run in later:
            result = pool.result(run) if pool is not None else inputs.run(run)
            scores.append(consistency(geometry, result.scan_poses, partners).mean_m)
            if scores[-1] < min(scores[:-1]) and scores[-1] < scores[0] * (1 - RESTART_MARGIN):
                best, kept = result, run
    finally:
        if pool is not None:
            pool.stop()
    best.stats.update(
        runs=runs, run_kept=kept, revisits_mm=scores[kept] * 1000, run_processes=processes
    )
    log.info(
        "slam restarts",
        runs=runs,
        kept=kept,
        revisits_mm=[round(s * 1000, 1) for s in scores],
    )
    return best
