"""The daemon's floor tracker: the online detector run in place, on the threads that offer it.

It publishes exactly what a replay of the same samples decides, from the thread that offered
the deciding sample (no queue, no thread of its own); messages offered from several threads
at once (pressure from the barometer's reader, odometry from the base's, a reference station
from Zenoh's) reach the detector one at a time; a detector that fails is fed no more and the
daemon stops pinging the watchdog for it.
"""

from __future__ import annotations

import itertools
import threading
import time
from pathlib import Path
from typing import Any

from baromap.floors import FloorDetectorConfig, OnlineFloorDetector
from baromap.messages import NS_PER_S, FloorEvent, FloorState, Message, Odometry, PressureSample
from baromap.sim.scenario import pressure_run
from baromapd.app import Daemon
from baromapd.config import parse_config
from baromapd.floors import FloorTracker


def _samples() -> list[PressureSample]:
    run = pressure_run(0, floors=3, minutes=6, rate_hz=25)
    return [
        PressureSample(t, p, c)
        for t, p, c in zip(
            run.t_ns.tolist(), run.pressure_pa.tolist(), run.temperature_c.tolist(), strict=True
        )
    ]


def test_the_tracker_publishes_in_place_what_a_replay_of_the_same_samples_decides() -> None:
    samples = _samples()
    replay = OnlineFloorDetector()
    expected = [event for s in samples for event in replay.update(s)] + replay.finish()
    assert expected, "the run must have floor changes for this test to mean anything"

    published: list[tuple[Message, int]] = []
    tracker = FloorTracker(
        FloorDetectorConfig(), lambda m: published.append((m, threading.get_ident()))
    )
    for sample in samples:
        tracker.offer(sample)
    tracker.close()

    events = [m for m, _ in published if isinstance(m, FloorEvent)]
    assert events == expected
    assert tracker.events == len(expected)
    assert {thread for _, thread in published} == {threading.get_ident()}
    states = [m.t_ns for m, _ in published if isinstance(m, FloorState)]
    gaps = [b - a for a, b in itertools.pairwise(states)]
    period = samples[1].t_ns - samples[0].t_ns
    assert states[0] == samples[0].t_ns and max(gaps) <= NS_PER_S + period


class _OneAtATime:
    """A detector that notices two callers inside it at once (each call lets go of the GIL)."""

    def __init__(self) -> None:
        self.inside = 0
        self.overlaps = 0
        self.calls = 0

    def _enter(self) -> None:
        self.inside += 1
        if self.inside > 1:
            self.overlaps += 1
        time.sleep(0.0002)
        self.calls += 1
        self.inside -= 1

    def update(self, sample: PressureSample) -> list[FloorEvent]:
        self._enter()
        return []

    def update_odometry(self, odometry: Odometry) -> None:
        self._enter()

    def update_reference(self, sample: PressureSample) -> None:
        self._enter()

    def state(self) -> Any:
        return None


def test_messages_from_several_threads_reach_the_detector_one_at_a_time() -> None:
    tracker = FloorTracker(FloorDetectorConfig(), lambda m: None)
    detector = _OneAtATime()
    tracker.detector = detector  # type: ignore[assignment]
    n = 200
    offers = [
        lambda i: tracker.offer(PressureSample(i * NS_PER_S, 100_000.0)),
        lambda i: tracker.offer(Odometry(i * NS_PER_S, 0.0, 0.0, 0.0)),
        lambda i: tracker.offer_reference(PressureSample(i * NS_PER_S, 100_000.0)),
    ]
    threads = [
        threading.Thread(target=lambda o=offer: [o(i) for i in range(n)]) for offer in offers
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert detector.calls == 3 * n
    assert detector.overlaps == 0


def test_a_failing_detector_is_fed_no_more_and_stops_the_watchdog(tmp_path: Path) -> None:
    config = parse_config(
        f'robot = "r"\n[recording]\ndirectory = "{tmp_path}"\n'
        '[barometer]\nport = "loop://"\n[zenoh]\nenabled = false\n'
    )
    daemon = Daemon(config, live=False, view=False)
    tracker = daemon.floors
    assert tracker is not None
    now = time.monotonic_ns()
    calls: list[PressureSample] = []

    def update(sample: PressureSample) -> list[FloorEvent]:
        calls.append(sample)
        if len(calls) == 3:
            raise ZeroDivisionError("a bug in the detector")
        return []

    tracker.detector.update = update  # type: ignore[method-assign]
    for i in range(2):
        tracker.offer(PressureSample(i * NS_PER_S // 25, 100_000.0))
    assert tracker.error is None and "floors" not in daemon.stuck_parts(now)
    for i in range(2, 10):
        tracker.offer(PressureSample(i * NS_PER_S // 25, 100_000.0))
    assert len(calls) == 3
    assert tracker.error == "ZeroDivisionError: a bug in the detector"
    assert "floors" in daemon.stuck_parts(now)
    tracker.close()  # no finish() on a failed detector either
    assert len(calls) == 3
