"""How far is the ground truth from GMapping's poses? Freiburg 079's relations, solved alone.

    .venv/bin/python bench/relations_trajectory.py [--seeds 0] [--draws 20]

Issue 14 judges Freiburg 079 by the ATE against GMapping's corrected poses, an estimate
itself. The log's Kuemmerle relations are ground truth, relative motions between 960 of its
scans (1615 usable), and most of them join into one graph over the whole run: solved as a pose
graph of the relations alone, they pin a trajectory of their own. Its ATE against GMapping's
poses is what a SLAM as accurate as the relations would score against that reference; beside
it, ours (``run_prepared`` on the seeds given) against both.

The relations are the robot's motion; the log's poses are the laser's, which its
``PARAM robot_frontlaser_offset -0.04`` puts 4 cm behind the robot's centre, so the pinned
trajectory is carried to the laser before comparing. How well the relations pin it: the
relations perturbed by noise of their robust scatter (after the fit: the median residual as a
Gaussian's, 1.5 times for the fit's own degrees of freedom), solved again, ``--draws`` times,
and again with the fit's residuals themselves resampled (outliers and all, a pessimistic bound).
Not part of the package: a check of the bench's reference (docs/results.md, Freiburg 079's ATE).
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

REPO = Path(__file__).resolve().parent.parent
LASER = Path(os.environ.get("BAROMAP_SHARED_DATA", REPO.parent / "shared" / "data")) / "laser"

#: Freiburg 079's laser in the robot's frame (its PARAM robot_frontlaser_offset)
MOUNT = (-0.04, 0.0, 0.0)
#: a relation's weight in the solve: centimetres and under a degree, Cauchy beyond 3 sigmas
SIGMA_M = 0.03
SIGMA_DEG = 0.5
ROBUST_C = 3.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0", help="our SLAM's seeds to compare ('' none)")
    parser.add_argument("--draws", type=int, default=20)
    args = parser.parse_args()
    import logging

    import structlog

    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.WARNING))
    from baromap.evaluation.laser_logs import PreparedLog, run_prepared
    from baromap.evaluation.trajectory import trajectory_error
    from baromap.mapping import se2
    from baromap.mapping.pose_graph import Edge, PoseGraph
    from baromap.mapping.relations import relation_pairs

    log = PreparedLog(LASER, "fr079")
    assert log.relations is not None
    i1, i2, motion, _ = relation_pairs(log.times, log.relations)
    nodes, ends = np.unique(np.concatenate([i1, i2]), return_inverse=True)
    a, b = ends[: len(i1)], ends[len(i1) :]
    # the largest connected part of the relations' graph (the rest cannot be placed)
    joined = sparse.coo_matrix((np.ones(len(a)), (a, b)), shape=(len(nodes), len(nodes)))
    _, label = connected_components(joined, directed=False)
    part = label == np.bincount(label).argmax()
    kept = part[a]
    print(
        f"Freiburg 079: {len(i1)} relations over {len(nodes)} scans; the largest connected "
        f"part {int(part.sum())} scans ({int(nodes[part].min())}-{int(nodes[part].max())}), "
        f"{int(kept.sum())} relations"
    )
    information = np.diag([1 / SIGMA_M**2, 1 / SIGMA_M**2, 1 / math.radians(SIGMA_DEG) ** 2])
    mount = np.array(MOUNT)

    def solve(z: np.ndarray) -> np.ndarray:
        """The robot's poses at every node (those outside the part stay where they start)."""
        graph = PoseGraph()
        for pose in log.reference[nodes]:
            graph.add_node(pose)
        for ia, ib, zk in zip(a[kept], b[kept], z[kept], strict=True):
            graph.add_edge(Edge(int(ia), int(ib), zk.copy(), information, "loop", ROBUST_C))
        graph.optimize(iterations=100)
        poses: np.ndarray = graph.poses.copy()
        return poses

    def laser(robot: np.ndarray) -> np.ndarray:
        moved: np.ndarray = se2.compose(robot, np.broadcast_to(mount, robot.shape))
        return moved[part]

    scans = nodes[part]
    gmapping = log.reference[scans]
    robot = solve(motion)
    pinned = laser(robot)
    print(
        "  the relations' trajectory against GMapping's poses: "
        f"ATE {trajectory_error(gmapping, pinned).rms_m:.4f} m"
    )
    for seed in [int(v) for v in args.seeds.split(",") if v]:
        ours = run_prepared(log, seed).result.scan_poses[scans]
        print(
            f"  ours, seed {seed}: against the relations' trajectory "
            f"{trajectory_error(ours, pinned).rms_m:.4f} m, against GMapping's poses "
            f"{trajectory_error(ours, gmapping).rms_m:.4f} m"
        )
    residual = se2.between(motion[kept], se2.between(robot[a[kept]], robot[b[kept]]))
    along = np.hypot(residual[:, 0], residual[:, 1])
    turn = np.abs(residual[:, 2])
    print(
        f"  the relations' residuals: median {1000 * np.median(along):.1f} mm, "
        f"{math.degrees(np.median(turn)):.3f} deg; RMS {1000 * np.sqrt(np.mean(along**2)):.1f}"
        f" mm, {math.degrees(np.sqrt(np.mean(turn**2))):.3f} deg"
    )
    # a Gaussian's median: 1.177 sigma for a 2D distance, 0.674 sigma for an absolute value
    sigma_m = 1.5 * float(np.median(along)) / 1.177
    sigma_rad = 1.5 * float(np.median(turn)) / 0.674
    rng = np.random.default_rng(0)
    for label_text, resampled in (
        (f"noise of {1000 * sigma_m:.1f} mm, {math.degrees(sigma_rad):.3f} deg", False),
        ("the residuals resampled x1.5", True),
    ):
        moved, apart = [], []
        for _ in range(args.draws):
            z = motion.copy()
            if resampled:
                pick = rng.integers(0, len(residual), len(z))
                z += 1.5 * rng.choice([-1.0, 1.0], (len(z), 3)) * residual[pick]
            else:
                z[:, :2] += rng.normal(0.0, sigma_m, (len(z), 2))
                z[:, 2] += rng.normal(0.0, sigma_rad, len(z))
            drawn = laser(solve(z))
            moved.append(trajectory_error(drawn, pinned).rms_m)
            apart.append(trajectory_error(gmapping, drawn).rms_m)
        print(
            f"  relations perturbed by {label_text}, {args.draws} draws: the trajectory moves "
            f"{np.mean(moved):.4f} m RMS (max {np.max(moved):.4f}); GMapping's poses from it "
            f"{np.min(apart):.4f}-{np.max(apart):.4f} m"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
