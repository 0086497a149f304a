"""What a consumer of floor events does with them: apply the corrections.

Events arrive in order; a correction stands in the place of the event it ``replaces``. The
transitions that result are the detector's current account of the run, and what a replay of
the same inputs gives.
"""

from __future__ import annotations

from collections.abc import Iterable

from baromap.errors import InputFormatError
from baromap.messages import FloorEvent, FloorEventKind


def apply_corrections(events: Iterable[FloorEvent]) -> list[FloorEvent]:
    """The transitions of an event stream, each in its latest version, in order.

    A correction naming an event never seen is an error in the stream (events were lost or
    reordered), not something to guess around.
    """
    current: list[FloorEvent] = []
    position: dict[int, int] = {}
    for event in events:
        if event.kind is FloorEventKind.CORRECTION:
            if event.replaces is None or event.replaces not in position:
                raise InputFormatError(
                    f"floor event {event.event_id} corrects {event.replaces}, never seen"
                )
            k = position.pop(event.replaces)
            current[k] = event
        else:
            k = len(current)
            current.append(event)
        position[event.event_id] = k
    return current
