"""The daemon's floor tracker: the online detector run in place, on the threads that offer it.

It returns exactly what a replay of the same samples decides, on the thread that offered the
deciding sample (no queue, no thread of its own), and the fanout hands that to the consumers,
never back to a stage; messages offered from several threads at once (pressure from the
barometer's reader, odometry from the base's, a reference station from Zenoh's) reach the
detector one at a time; a detector that fails is fed no more and the daemon stops pinging the
watchdog for it.
"""

from __future__ import annotations

import itertools
import threading
import time
from pathlib import Path
from typing import Any

from baromap.floors import FloorDetectorConfig, OnlineFloorDetector
from baromap.messages import (
    NS_PER_S,
    FloorEvent,
    FloorState,
    Message,
    Odometry,
    PressureSample,
    RideEvent,
)
from baromap.sim.scenario import pressure_run
from baromapd.app import Daemon
from baromapd.config import parse_config
from baromapd.fanout import Fanout
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
    fanout = Fanout()
    fanout.subscribe(_Collect(published))
    tracker = FloorTracker(FloorDetectorConfig())
    fanout.attach(tracker)
    for sample in samples:
        fanout.publish(sample)
    fanout.finish_stages()

    events = [m for m, _ in published if isinstance(m, FloorEvent | RideEvent)]
    assert events == expected
    assert tracker.events == len(expected)
    assert {thread for _, thread in published} == {threading.get_ident()}
    states = [m.t_ns for m, _ in published if isinstance(m, FloorState)]
    gaps = [b - a for a, b in itertools.pairwise(states)]
    period = samples[1].t_ns - samples[0].t_ns
    assert states[0] == samples[0].t_ns and max(gaps) <= NS_PER_S + period
    # the consumer got the samples too, each before what it decided
    assert sum(isinstance(m, PressureSample) for m, _ in published) == len(samples)


class _Collect:
    def __init__(self, into: list[tuple[Message, int]]) -> None:
        self.into = into

    def offer(self, message: Message) -> None:
        self.into.append((message, threading.get_ident()))

    def close(self) -> None:
        pass


class _Echo:
    """A stage that takes what it makes: fed its own output, it would loop for ever."""

    accepts: tuple[type, ...] = (PressureSample,)

    def __init__(self) -> None:
        self.calls = 0

    def process(self, message: Message) -> list[Message]:
        self.calls += 1
        return [message]

    def finish(self) -> list[Message]:
        return [PressureSample(0, 1.0)]


def test_what_a_stage_makes_goes_to_the_consumers_and_never_back_to_a_stage() -> None:
    published: list[tuple[Message, int]] = []
    fanout = Fanout()
    fanout.subscribe(_Collect(published))
    echo, other = _Echo(), _Echo()
    fanout.attach(echo)
    fanout.attach(other)
    fanout.publish(PressureSample(1, 100_000.0))
    # each stage saw the reader's sample once; the consumer got it and both copies
    assert (echo.calls, other.calls) == (1, 1)
    assert [m for m, _ in published] == [PressureSample(1, 100_000.0)] * 3
    fanout.finish_stages()
    assert (echo.calls, other.calls) == (1, 1) and len(published) == 5


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
    tracker = FloorTracker(FloorDetectorConfig())
    detector = _OneAtATime()
    tracker.detector = detector  # type: ignore[assignment]
    n = 200
    offers = [
        lambda i: tracker.process(PressureSample(i * NS_PER_S, 100_000.0)),
        lambda i: tracker.process(Odometry(i * NS_PER_S, 0.0, 0.0, 0.0)),
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
        daemon.publish(PressureSample(i * NS_PER_S // 25, 100_000.0))
    assert tracker.error is None and "floors" not in daemon.stuck_parts(now)
    for i in range(2, 10):
        daemon.publish(PressureSample(i * NS_PER_S // 25, 100_000.0))
    assert len(calls) == 3
    assert tracker.error == "ZeroDivisionError: a bug in the detector"
    assert "floors" in daemon.stuck_parts(now)
    assert tracker.finish() == []  # no finish() on a failed detector either
    assert len(calls) == 3
