"""The loop closer's proposals: closures that wait for another to agree (loops.py,
``LoopCloser._propose``), on the bookkeeping of the waiting list alone."""

from __future__ import annotations

from collections import Counter
from types import SimpleNamespace

import numpy as np

from baromap.mapping.pose_graph import Edge
from baromap.mapping.slam.loops import LoopCloser


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
