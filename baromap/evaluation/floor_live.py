"""Scoring the live decisions, apart from the post-run segmentation.

The post-run segmentation (:func:`baromap.floors.detect_floors`) is what mapping uses: its
transition bounds are tightened with hindsight. A live consumer sees something else: events
published when the detector decided, and a floor state that changes at those moments. This
module takes the events the live detector published during the run as a consumer would (the
event stream, corrections applied by :func:`baromap.floors.apply_corrections`), scores that
against the truth with the same matching, and checks it against the post-run transitions: the
same floor changes, in the same order, between the same floors, decided at the same moments.
(That a replay publishes what the live run did is tested on its own.)
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from baromap.floors.detection import FloorDetection, Segment, Transition
from baromap.floors.evaluation import FloorTruth, Score, score
from baromap.floors.events import apply_corrections
from baromap.messages import FloorEvent, FloorEventKind


@dataclass(frozen=True, slots=True)
class LiveScore:
    """The live decisions of one case.

    ``score`` matches the published transitions (corrections applied, their own time bounds)
    against the truth; its per-sample accuracy is the live *state*'s, which changes floor when
    an event is published. ``agrees`` says the live transitions equal the post-run ones.
    """

    score: Score
    events: int
    corrections: int
    agrees: bool
    disagreement: str = ""


def live_score(post_run: FloorDetection, truth: FloorTruth) -> LiveScore:
    """Score what a consumer of the run's events would have known."""
    published = list(post_run.events)
    current = apply_corrections(published)
    agrees, why = _agreement(current, post_run)
    return LiveScore(
        score=score(live_detection(current, post_run), truth),
        events=len(published),
        corrections=sum(1 for e in published if e.kind is FloorEventKind.CORRECTION),
        agrees=agrees,
        disagreement=why,
    )


def live_detection(events: list[FloorEvent], post_run: FloorDetection) -> FloorDetection:
    """The live account of a run as a :class:`FloorDetection`: the events' own time bounds
    and decision times, and the floor the live state showed at every moment.

    Floors are indexed as post-run (by height over the whole run), through their names,
    which are unique in a run.
    """
    index = {f.name: f.index for f in post_run.floors}
    t = post_run.t_ns
    transitions = tuple(
        Transition(
            t_start_ns=e.t_start_ns,
            t_end_ns=e.t_end_ns,
            t_detect_ns=e.t_ns,
            from_floor=index[e.from_name],
            to_floor=index[e.to_name],
            delta_pa=e.delta_pa,
            delta_m=e.delta_m,
            at_end=e.at_end,
        )
        for e in events
    )
    segments = []
    start = int(t[0])
    floor = transitions[0].from_floor if transitions else (post_run.segments[0].floor)
    for tr in transitions:
        segments.append(Segment(start, tr.t_detect_ns, floor))
        start, floor = tr.t_detect_ns, tr.to_floor
    segments.append(Segment(start, int(t[-1]), floor))
    return dataclasses.replace(
        post_run, method="online-live", transitions=transitions, segments=tuple(segments)
    )


def _agreement(events: list[FloorEvent], post_run: FloorDetection) -> tuple[bool, str]:
    index = {f.name: f.index for f in post_run.floors}
    if len(events) != len(post_run.transitions):
        return False, f"{len(events)} live transitions, {len(post_run.transitions)} post-run"
    for k, (event, tr) in enumerate(zip(events, post_run.transitions, strict=True)):
        live = (index.get(event.from_name), index.get(event.to_name), event.t_ns)
        post = (tr.from_floor, tr.to_floor, tr.t_detect_ns)
        if live != post:
            return False, f"transition {k}: live {live}, post-run {post}"
    return True, ""
