"""The names the live detector gave a run's floors, read back from the recording.

build-maps finds floors by replaying the detector on the recorded pressure, with its default
settings: the start floor is "0" and names count storeys of 3.5 m. The daemon named the
floors with the ``[floors]`` settings its user gave (a start floor, a storey height, a
building model), and those are the names a person saw live and expects in
``building.yaml``. They are in the recording: every floor event on ``/floor/event``. A floor
of the replay gets the name the live account gave the robot's floor over its stays (the name
most of its stays had at their midpoint), so the replay's own names never reach a user when
the daemon's are there.
"""

from __future__ import annotations

from bisect import bisect_right
from collections import Counter
from collections.abc import Iterable, Sequence
from pathlib import Path

import structlog

from baromap.errors import InputFormatError
from baromap.floors.detection import Segment
from baromap.floors.events import apply_corrections
from baromap.messages import FloorEvent
from baromap.recording import topics
from baromap.recording.reader import read_messages

log = structlog.get_logger(__name__)


def recorded_floor_events(parts: Iterable[Path]) -> list[FloorEvent]:
    """The floor events the daemon recorded, in the order it published them."""
    return [
        record.message
        for part in parts
        for record in read_messages(part, [topics.FLOOR_EVENT])
        if isinstance(record.message, FloorEvent)
    ]


def live_floor_names(events: Sequence[FloorEvent], segments: Sequence[Segment]) -> dict[int, str]:
    """Per floor of the replay's stays (``segments``), the name the live account gave the
    robot's floor during its stays there; empty when the recording holds no floor events, or
    a stream that does not apply (events lost: then no live name is better than a wrong one)."""
    if not events or not segments:
        return {}
    try:
        current = apply_corrections(events)
    except InputFormatError as exc:
        log.warning("recorded floor events not used for names", error=str(exc))
        return {}
    if not current:
        return {}
    current.sort(key=lambda e: e.t_end_ns)
    ends = [e.t_end_ns for e in current]
    votes: dict[int, Counter[str]] = {}
    for segment in segments:
        middle = (segment.t_start_ns + segment.t_end_ns) // 2
        k = bisect_right(ends, middle)
        name = current[k - 1].to_name if k else current[0].from_name
        votes.setdefault(int(segment.floor), Counter())[name] += 1
    return {floor: count.most_common(1)[0][0] for floor, count in votes.items()}
