"""The trajectory error measures of baromap.evaluation.trajectory."""

from __future__ import annotations

import numpy as np

from baromap.evaluation.trajectory import similarity_error, trajectory_error
from baromap.mapping import se2


def _walk(seed: int, n: int = 200) -> np.ndarray:
    rng = np.random.default_rng(seed)
    steps = np.column_stack([rng.uniform(0.3, 0.7, n), np.zeros(n), rng.normal(0.0, 0.2, n)])
    poses = np.zeros((n + 1, 3))
    for i, step in enumerate(steps):
        poses[i + 1] = se2.compose(poses[i], step)
    return poses


def test_a_uniformly_stretched_trajectory_is_all_scale_to_the_similarity() -> None:
    reference = _walk(0)
    stretched = reference.copy()
    stretched[:, :2] *= 1.004  # 0.4 % too large
    moved = se2.compose(np.array([3.0, -2.0, 0.7]), stretched)
    rms, scale = similarity_error(moved, reference)
    assert rms < 1e-9
    assert abs(scale - 1.0 / 1.004) < 1e-9
    assert trajectory_error(moved, reference).rms_m > 0.01  # the rigid fit cannot take it


def test_a_bent_trajectory_keeps_its_error_after_the_similarity() -> None:
    reference = _walk(1)
    bent = reference.copy()
    bent[100:, :2] += np.array([0.0, 0.5])  # one half moved sideways
    rms, scale = similarity_error(bent, reference)
    assert rms > 0.1
    assert abs(scale - 1.0) < 0.05
