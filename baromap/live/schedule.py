"""What a node publishes, and when: messages in, publications out, no I/O and no threads.

The daemon offers every message it has; this decides what goes on the wire:

- floor events at once, as decided (corrections included): they are the point; ride events
  (a ride announced, ended, withdrawn) at once too;
- floor state when it changes, and at least every ``state_period_s`` for anyone who missed it;
  a change is a change of any field that is not a measurement (floor, name, phase, since,
  floors known), so a drifting level or a ticking stamp does not count;
- pressure as the mean of each ``pressure_period_s`` of sample time: a barometer at 50 Hz
  would be 50 messages a second of noise, a block mean is both decimated and smoothed (and,
  unlike an exponential average, it has no memory beyond its block);
- the latest health of each device every ``health_period_s``;
- nothing else (laser scans and odometry stay in the recording).

Periodic output is driven by the caller's monotonic clock, pressure blocks by sample time, so
a replay of the same samples gives the same pressure publications.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from baromap.jsonmsg import field_names
from baromap.live.keys import Channel
from baromap.live.settings import LiveSettings
from baromap.messages import (
    NS_PER_S,
    DeviceHealth,
    FloorEvent,
    FloorState,
    PressureSample,
    RideEvent,
)

PublishedMessage = FloorEvent | RideEvent | FloorState | PressureSample | DeviceHealth


@dataclass(frozen=True, slots=True)
class Outgoing:
    """One publication: a message on a channel of this node."""

    channel: Channel
    message: PublishedMessage


def _significant(state: FloorState) -> tuple[object, ...]:
    """What must differ for a state to count as changed: every field but stamps and floats.

    The names come from a cache and the tuple from a list, at its size: a tuple built from a
    generator for every state fed CPython's free lists (see ``jsonmsg.field_names``)."""
    return tuple(
        [
            value
            for name in field_names(FloorState)
            if name != "t_ns" and not isinstance(value := getattr(state, name), float)
        ]
    )


class PressureDecimator:
    """Means of consecutive blocks of ``period_ns`` of sample time (0: every sample as is).

    The mean is stamped with the last sample of its block, so it is causal: it never claims a
    time before the data it holds was read.
    """

    __slots__ = ("_count", "_due", "_p", "_t_count", "_temp", "ignored", "period_ns")

    def __init__(self, period_ns: int) -> None:
        self.period_ns = period_ns
        self._due = -1
        self._p = self._temp = 0.0
        self._count = self._t_count = 0
        self.ignored = 0

    def push(self, sample: PressureSample) -> PressureSample | None:
        if not math.isfinite(sample.pressure_pa):
            self.ignored += 1
            return None
        if self.period_ns == 0:
            return sample
        t = sample.t_ns
        if self._due < 0:
            self._due = t + self.period_ns
        self._p += sample.pressure_pa
        self._count += 1
        temperature = sample.temperature_c
        if temperature is not None and math.isfinite(temperature):
            self._temp += temperature
            self._t_count += 1
        if t < self._due:
            return None
        mean = PressureSample(
            t_ns=t,
            pressure_pa=self._p / self._count,
            temperature_c=self._temp / self._t_count if self._t_count else None,
        )
        self._p = self._temp = 0.0
        self._count = self._t_count = 0
        self._due += self.period_ns
        if self._due <= t:  # a gap in the samples: start the blocks afresh
            self._due = t + self.period_ns
        return mean


class PublishSchedule:
    """Decides the publications of one node (see the module docstring).

    ``station`` nodes (reference barometers) publish pressure and health only.
    """

    #: Message types that are ever published; anything else can be discarded unqueued.
    ACCEPTED = (FloorEvent, RideEvent, FloorState, PressureSample, DeviceHealth)

    def __init__(self, settings: LiveSettings, *, station: bool = False) -> None:
        self.station = station
        self._pressure = PressureDecimator(round(settings.pressure_period_s * NS_PER_S))
        self._state_period = round(settings.state_period_s * NS_PER_S)
        self._health_period = round(settings.health_period_s * NS_PER_S)
        self._state: FloorState | None = None
        self._state_sent: tuple[object, ...] | None = None
        self._state_due = 0
        self._health: dict[str, DeviceHealth] = {}
        self._health_due = -1
        self.ignored = 0

    @property
    def state(self) -> FloorState | None:
        """The latest floor state offered (what a late joiner is told)."""
        return self._state

    @property
    def ignored_pressure(self) -> int:
        return self._pressure.ignored

    def offer(self, message: object, now_ns: int) -> list[Outgoing]:
        """Take one message; returns what to publish now because of it."""
        if isinstance(message, PressureSample):
            mean = self._pressure.push(message)
            return [Outgoing(Channel.PRESSURE, mean)] if mean is not None else []
        if isinstance(message, DeviceHealth):
            self._health[message.device] = message
            if self._health_due < 0:
                self._health_due = now_ns
            return []
        if self.station:
            self.ignored += 1
            return []
        if isinstance(message, FloorEvent):
            return [Outgoing(Channel.EVENT, message)]
        if isinstance(message, RideEvent):
            return [Outgoing(Channel.RIDE, message)]
        if isinstance(message, FloorState):
            self._state = message
            if _significant(message) != self._state_sent:
                return [self._send_state(now_ns)]
            return []
        self.ignored += 1
        return []

    def due(self, now_ns: int) -> list[Outgoing]:
        """Periodic publications that are due at ``now_ns`` (monotonic)."""
        out = []
        if self._state is not None and now_ns >= self._state_due:
            out.append(self._send_state(now_ns))
        if self._health and now_ns >= self._health_due:
            out.extend(Outgoing(Channel.HEALTH, h) for h in self._health.values())
            self._health_due += self._health_period
            if self._health_due <= now_ns:
                self._health_due = now_ns + self._health_period
        return out

    def next_due_ns(self) -> int | None:
        """When :meth:`due` will next have something (None: not before a new message)."""
        times = []
        if self._state is not None:
            times.append(self._state_due)
        if self._health:
            times.append(self._health_due)
        return min(times) if times else None

    def _send_state(self, now_ns: int) -> Outgoing:
        assert self._state is not None
        self._state_sent = _significant(self._state)
        self._state_due = now_ns + self._state_period
        return Outgoing(Channel.STATE, self._state)
