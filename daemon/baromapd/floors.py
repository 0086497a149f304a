"""The online floor detector inside the daemon: pressure (and odometry) in, floor events out.

Odometry tells the detector whether the robot rode a change standing in a car (the stop is
then decided as the car stops) and whether it drove off at a stop
(``OnlineFloorDetector.update_odometry``).

It is a stage of the fanout and runs in place, on the thread that offers it a message (the
barometer's reader for pressure, the base's for odometry, a Zenoh thread for a reference
station), under a lock, so the detector sees one message at a time in the order they came,
as a queue would give them. A thread behind its own queue would cost a wake-up per pressure
sample (50 a second, on a VM where a wake-up costs more CPU than the detector's work on the
sample) and a queue hop in every floor event. The detector's work per sample is a few
arithmetic steps (no level solve: that is post-run); an event adds a registry look-up and
the messages it publishes. What it delays is the barometer's next read, by that much, and a
late read bends nothing: the samples are stamped from the board's clock through a
lower-envelope fit that only prompt reads move, and the tty buffers the bytes meanwhile.

What it decides (floor events, ride events, states) it returns, and the fanout hands that to
the consumers (recorded on ``/floor/event`` and ``/floor/ride``, offered to the live
publisher), never back to a stage: the flow is one-way. The state goes out at every event
and once a second of sample time, so a late reader of the recording or a late subscriber
always has a recent answer.

A detector that raises is not fed again: the error is logged and kept, and the daemon's main
loop then stops pinging the watchdog (as it did for a consumer thread that died), so systemd
restarts the service instead of it recording on without floors.
"""

from __future__ import annotations

import threading
from typing import Final

import structlog

from baromap.floors import FloorDetectorConfig, OnlineFloorDetector
from baromap.messages import (
    NS_PER_S,
    FloorEvent,
    Message,
    Odometry,
    PressureSample,
    RideEvent,
)

log = structlog.get_logger(__name__)

STATE_EVERY_NS: Final = NS_PER_S


class FloorTracker:
    """Feeds the detector with pressure samples and odometry; returns what it decides."""

    name = "floors"
    #: What the fanout offers it (everything else never reaches :meth:`process`).
    accepts: tuple[type, ...] = (PressureSample, Odometry)

    def __init__(self, config: FloorDetectorConfig) -> None:
        self.detector = OnlineFloorDetector(config)
        self._lock = threading.Lock()
        self._last_state_ns: int | None = None
        self._closed = False
        self.events = 0
        self.error: str | None = None

    def process(self, message: Message) -> list[Message]:
        """Run the detector on a robot's pressure sample or odometry, here and now; returns
        the events and state to publish."""
        with self._lock:
            if self.error is not None or self._closed:
                return []
            try:
                if isinstance(message, PressureSample):
                    return self._sample(message)
                if isinstance(message, Odometry):  # did the robot ride, or drive off?
                    self.detector.update_odometry(message)
            except Exception as exc:
                self._failed(exc)
            return []

    def offer_reference(self, sample: PressureSample) -> None:
        """A reference station's reading (from a Zenoh thread), in turn with the robot's own."""
        with self._lock:
            if self.error is not None or self._closed:
                return
            try:
                self.detector.update_reference(sample)
            except Exception as exc:
                self._failed(exc)

    def finish(self) -> list[Message]:
        """The stream ended (the readers have stopped): decide what was in progress."""
        with self._lock:
            if self.error is not None or self._closed:
                return []
            self._closed = True
            try:
                events = self.detector.finish()
            except Exception as exc:
                self._failed(exc)
                return []
            out: list[Message] = []
            for event in events:
                out.append(self._event(event))
            if events:
                out.append(self.detector.state())
            return out

    def state(self) -> Message:
        with self._lock:
            return self.detector.state()

    def _sample(self, sample: PressureSample) -> list[Message]:
        out: list[Message] = [self._event(e) for e in self.detector.update(sample)]
        due = self._last_state_ns is None or sample.t_ns - self._last_state_ns >= STATE_EVERY_NS
        if out or due:
            self._last_state_ns = sample.t_ns
            out.append(self.detector.state())
        return out

    def _event(self, event: FloorEvent | RideEvent) -> Message:
        self.events += 1
        if isinstance(event, FloorEvent):
            log.info(
                "floor event",
                event_id=event.event_id,
                kind=event.kind.value,
                replaces=event.replaces,
                from_floor=event.from_name,
                to_floor=event.to_name,
                delta_m=round(event.delta_m, 2),
            )
        else:
            log.info(
                "ride event",
                ride_id=event.ride_id,
                kind=event.kind.value,
                direction=event.direction.value,
                from_floor=event.from_name,
                to_floor=event.to_name,
                reason=event.reason or None,
            )
        return event

    def _failed(self, exc: Exception) -> None:
        self.error = f"{type(exc).__name__}: {exc}"
        log.exception("floor detector failed: no more floor events", consumer=self.name)
