"""Scoring the live decisions, apart from the post-run segmentation.

The post-run segmentation (:func:`baromap.floors.detect_floors`) is what mapping uses: its
transition bounds are tightened with hindsight. A live consumer sees something else: events
published when the detector decided, and a floor state that changes at those moments. This
module takes the events the live detector published during the run as a consumer would (the
event stream, corrections applied by :func:`baromap.floors.apply_corrections`), scores that
against the truth with the same matching, and checks it against the post-run transitions: the
same floor changes, in the same order, between the same floors, decided at the same moments.
(That a replay publishes what the live run did is tested on its own.)

A transition is decided when a consumer first held it between the floors it ends up between
(:func:`baromap.floors.decided_at`): a correction that only measures the step again does not
move that moment, one that sends the robot to another floor does. Rides are scored on their
announcement: for each true transition, the first ``ride_started`` of a ride that was not
withdrawn, its delay after the car began to move and whether its direction was right.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from baromap.floors.detection import FloorDetection, Segment, Transition
from baromap.floors.evaluation import FloorTruth, Score, score
from baromap.floors.events import apply_corrections, decided_at
from baromap.messages import NS_PER_S, FloorEvent, FloorEventKind, RideEvent, RideEventKind

#: How long before the car moves an announced ride may begin and still be this ride's (the
#: doors closing and their seal can start the change a few seconds early).
RIDE_LEAD_S = 10.0


@dataclass(frozen=True, slots=True)
class RideScore:
    """The rides of one case against its true transitions."""

    #: Per true transition: delay of its ride's announcement after the car began to move
    #: (s; None if no ride was announced for it) and whether the direction was right.
    started: tuple[tuple[float | None, bool], ...]
    announced: int
    withdrawn: int


@dataclass(frozen=True, slots=True)
class LiveScore:
    """The live decisions of one case.

    ``score`` matches the published transitions (corrections applied, their own time bounds,
    decided when first held between their floors) against the truth; its per-sample accuracy
    is the live *state*'s, which changes floor when an event is published. ``agrees`` says
    the live transitions equal the post-run ones. ``corrections`` counts every correction,
    ``moves`` those that sent the robot to another floor, ``retractions`` the transitions
    withdrawn.
    """

    score: Score
    events: int
    corrections: int
    agrees: bool
    disagreement: str = ""
    moves: int = 0
    retractions: int = 0
    rides: RideScore | None = None


def live_score(post_run: FloorDetection, truth: FloorTruth) -> LiveScore:
    """Score what a consumer of the run's events would have known."""
    published = list(post_run.events)
    current = apply_corrections(published)
    agrees, why = _agreement(current, post_run)
    by_id = {e.event_id: e for e in published}
    corrections = [e for e in published if e.kind is FloorEventKind.CORRECTION]
    moves = sum(
        1
        for e in corrections
        if e.replaces is not None
        and (by_id[e.replaces].from_id, by_id[e.replaces].to_id) != (e.from_id, e.to_id)
    )
    return LiveScore(
        score=score(live_detection(published, post_run), truth),
        events=len(published),
        corrections=len(corrections),
        agrees=agrees,
        disagreement=why,
        moves=moves,
        retractions=sum(1 for e in published if e.kind is FloorEventKind.RETRACTION),
        rides=ride_score(post_run.rides, truth) if post_run.rides or post_run.events else None,
    )


def ride_score(rides: Sequence[RideEvent], truth: FloorTruth) -> RideScore:
    withdrawn = {r.ride_id for r in rides if r.kind is RideEventKind.RETRACTED}
    starts = [r for r in rides if r.kind is RideEventKind.STARTED and r.ride_id not in withdrawn]
    lead = round(RIDE_LEAD_S * NS_PER_S)
    used: set[int] = set()
    started: list[tuple[float | None, bool]] = []
    for true in truth.transitions:
        mine = [
            r
            for r in starts
            if r.ride_id not in used and true.t_begin_ns - lead <= r.t_ns <= true.t_end_ns
        ]
        if not mine:
            started.append((None, False))
            continue
        first = mine[0]
        used.add(first.ride_id)
        up = true.to_floor > true.from_floor
        started.append(
            ((first.t_ns - true.t_begin_ns) / NS_PER_S, (first.direction.value == "up") == up)
        )
    return RideScore(
        started=tuple(started),
        announced=sum(1 for r in rides if r.kind is RideEventKind.STARTED),
        withdrawn=len(withdrawn),
    )


def ride_delays(scores: Sequence[RideScore]) -> tuple[list[float], int, int]:
    """Announcement delays of the rides with the right direction (a ride announced the
    wrong way, or not at all, counts as never: +inf), rides right, rides in all."""
    delays = []
    right = 0
    total = 0
    for s in scores:
        for delay, ok in s.started:
            total += 1
            if delay is not None and ok:
                right += 1
                delays.append(delay)
            else:
                delays.append(float("inf"))
    return delays, right, total


def percentile(values: Sequence[float], q: float) -> float:
    """A percentile that keeps +inf (never) in the tail: the p95 of a list whose last 10 %
    are inf is inf, not NaN."""
    if not values:
        return float("nan")
    ordered = sorted(values)
    finite = [v for v in ordered if np.isfinite(v)]
    rank = q / 100.0 * (len(ordered) - 1)
    if rank > len(finite) - 1:
        return float("inf")
    return float(np.percentile(finite, 100.0 * rank / max(len(finite) - 1, 1)))


def live_detection(events: list[FloorEvent], post_run: FloorDetection) -> FloorDetection:
    """The live account of a run as a :class:`FloorDetection`: the events' own time bounds,
    when each transition was decided, and the floor the live state showed at every moment.

    Floors are indexed as post-run (by height over the whole run), through their names,
    which are unique in a run. ``events`` is the stream as published (corrections and
    retractions in it).
    """
    index = {f.name: f.index for f in post_run.floors}
    decided = decided_at(events)
    t = post_run.t_ns
    transitions = tuple(
        Transition(
            t_start_ns=e.t_start_ns,
            t_end_ns=e.t_end_ns,
            t_detect_ns=decided[e.event_id],
            from_floor=index[e.from_name],
            to_floor=index[e.to_name],
            delta_pa=e.delta_pa,
            delta_m=e.delta_m,
            at_end=e.at_end,
        )
        for e in apply_corrections(events)
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
