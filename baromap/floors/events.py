"""What a consumer of floor events does with them: apply the corrections.

Events arrive in order; a correction stands in the place of the event it ``replaces``, a
retraction removes it. The transitions that result are the detector's current account of
the run, and what a replay of the same inputs gives. Ride events are no part of that
account: a consumer that wants final floors ignores them.
"""

from __future__ import annotations

from collections.abc import Iterable

from baromap.errors import InputFormatError
from baromap.messages import FloorEvent, FloorEventKind


def apply_corrections(events: Iterable[FloorEvent]) -> list[FloorEvent]:
    """The transitions of an event stream, each in its latest version, in order.

    A correction or retraction naming an event never seen is an error in the stream (events
    were lost or reordered), not something to guess around.
    """
    current: list[FloorEvent | None] = []
    position: dict[int, int] = {}
    for event in events:
        if event.kind is FloorEventKind.TRANSITION:
            k = len(current)
            current.append(event)
            position[event.event_id] = k
            continue
        if event.replaces is None or event.replaces not in position:
            raise InputFormatError(
                f"floor event {event.event_id} revises {event.replaces}, never seen"
            )
        k = position.pop(event.replaces)
        if event.kind is FloorEventKind.RETRACTION:
            current[k] = None
        else:
            current[k] = event
            position[event.event_id] = k
    return [event for event in current if event is not None]


def decided_at(events: Iterable[FloorEvent]) -> dict[int, int]:
    """When each transition of the account was decided: by its latest ``event_id``, the
    ``t_ns`` of the earliest version in its chain of corrections that goes between the same
    two floors. A correction that only measures the step again (same floors) leaves the
    decision where it was; one that moves the robot to another floor is a decision of its
    own."""
    by_id: dict[int, FloorEvent] = {}
    first: dict[int, int] = {}
    for event in events:
        by_id[event.event_id] = event
        if event.kind is FloorEventKind.RETRACTION or event.replaces is None:
            first[event.event_id] = event.t_ns
            continue
        old = by_id.get(event.replaces)
        same = old is not None and (old.from_id, old.to_id) == (event.from_id, event.to_id)
        first[event.event_id] = first[event.replaces] if same else event.t_ns
    return first
