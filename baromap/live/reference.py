"""A robot's side of a reference station: the station's pressure, handed to the detector.

A barometer that does not move sees only the weather; the online detector subtracts its
change since the start from the robot's pressure (``OnlineFloorDetector.update_reference``),
so a storm front is not mistaken for a floor. The station publishes on
``baromap/reference/<station>/pressure``; this decodes those samples and passes each to a
callback. The callback runs on a Zenoh thread: it must only hand the sample over (to the
detector's input queue, say), never block or touch the detector directly.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import structlog

from baromap.errors import InputFormatError
from baromap.live.keys import Channel, NodeKeys
from baromap.live.payloads import decode
from baromap.messages import PressureSample

if TYPE_CHECKING:
    import zenoh

log = structlog.get_logger(__name__)


class ReferenceListener:
    """Decodes one station's pressure samples for a callback; counts what it could not use."""

    def __init__(self, station: str, callback: Callable[[PressureSample], None]) -> None:
        self.station = station
        self.key = NodeKeys.reference(station).key(Channel.PRESSURE)
        self._callback = callback
        self.received = 0
        self.bad = 0
        self.last_t_ns: int | None = None  # the last sample's time (None: none yet)

    def on_payload(self, payload: bytes) -> None:
        try:
            sample = decode(Channel.PRESSURE, payload)
        except InputFormatError as exc:
            self.bad += 1
            if self.bad == 1:
                log.warning("unreadable reference sample", station=self.station, error=str(exc))
            return
        self.received += 1
        self.last_t_ns = sample.t_ns
        self._callback(sample)

    def declare(self, session: zenoh.Session) -> zenoh.Subscriber[None]:
        """Subscribe on ``session``; the subscription ends with the session or ``undeclare``."""
        return session.declare_subscriber(
            self.key, lambda sample: self.on_payload(sample.payload.to_bytes())
        )

    def counters(self) -> dict[str, int]:
        return {"reference_samples": self.received, "reference_bad": self.bad}
