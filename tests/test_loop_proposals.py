"""The loop closer's proposals: closures that wait for another to agree (loops.py,
``LoopCloser._propose``), on the bookkeeping of the waiting list alone; and the chain that
takes closures (state.py, ``Chain.accept_loop``)."""

from __future__ import annotations

from collections import Counter
from types import SimpleNamespace
from typing import cast

import numpy as np

from baromap.mapping.pose_graph import Edge
from baromap.mapping.slam.loops import LoopCloser
from baromap.mapping.slam.state import Chain, Submaps


def _proposal(i: int, j: int, x: float) -> Edge:
    return Edge(i, j, np.array([x, 0.0, 0.0]), np.eye(3), "loop")


def test_proposals_of_the_same_keyframes_pair_are_taken_by_identity() -> None:
    """Two waiting proposals of one keyframe against one anchor (the same ``i`` and ``j``,
    different corrections) and a later closure that agrees with the second: the second is
    taken and leaves the list, the first keeps waiting. An Edge compares its arrays, so a
    list's own ``remove`` cannot find the second past the first (it raised ValueError, and
    the run died)."""
    taken: list[Edge] = []
    closer = LoopCloser.__new__(LoopCloser)
    closer.stats = Counter()
    closer.beyond = []
    closer.chain = SimpleNamespace(  # type: ignore[assignment]
        graph=SimpleNamespace(poses=np.zeros((20, 3))),
        accept_loop=lambda edge, score: taken.append(edge),
    )
    first, second = _proposal(3, 10, 0.0), _proposal(3, 10, 0.5)
    closer.pending = [(first, 0.4), (second, 0.45)]
    closer._agree = lambda a, b, poses: a is second  # type: ignore[method-assign]
    later = _proposal(4, 12, 0.5)
    closer._propose(later, 0.42)
    # by identity: comparing Edges by equality is the trap itself
    assert [id(e) for e in taken] == [id(second), id(later)]
    assert [id(e) for e, _ in closer.pending] == [id(first)]
    assert closer.stats["loop_groups"] == 1


def test_a_closure_found_twice_between_the_same_keyframes_enters_the_graph_once() -> None:
    """Two loop targets can frame one revisited keyframe, and a wide search against the run
    around it is then the same search twice (the gate's Infinite Corridor took the first
    closure of its wide groups twice): one scan matched against one place is one
    measurement, weighed once, and the first finding stands."""
    stats: Counter[str] = Counter()
    chain = Chain(cast(Submaps, None), stats)
    for pose in ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]):
        chain.graph.add_node(pose)
    chain.accept_loop(_proposal(0, 2, 1.0), 0.6)
    chain.accept_loop(_proposal(0, 2, 1.1), 0.7)
    chain.accept_loop(_proposal(1, 2, 0.0), 0.6)
    assert chain.loops == [(0, 2), (1, 2)]
    assert chain.graph.edge_count == 2
    assert stats["loop_repeats"] == 1
    assert np.allclose(chain.loop_motions[0], [1.0, 0.0, 0.0])
