"""How a scan match becomes a measurement in the pose graph: its information and
covariance, the window it is searched in, the field a finished map is matched against."""

from __future__ import annotations

import math

import numpy as np

from baromap.arrays import FloatArray
from baromap.mapping import se2
from baromap.mapping.pose_graph import Edge
from baromap.mapping.scan_matcher import LikelihoodField, MatchResult, SearchWindow
from baromap.mapping.scans import voxel_filter
from baromap.mapping.slam.settings import (
    CAR_FAR_AGREE_M,
    CAR_FAR_AGREE_RAD,
    COARSE_ABOVE_CELLS,
    COARSE_STEP_CELLS,
    FINISHED_MAP_FIELD_SCALE,
    LOOP_ROBUST_C,
    LOOP_SIGMA_M,
    LOOP_SIGMA_RAD,
    MATCH_COV_SCALE,
    MATCH_SIGMA_M,
    MATCH_SIGMA_RAD,
    MAX_ANGLE_STEP_RAD,
    MIN_ANGLE_STEP_RAD,
    UNMEASURED_INFORMATION,
)


def diagonal_information(sigma_xy: float, sigma_theta: float) -> FloatArray:
    return np.diag([1 / sigma_xy**2, 1 / sigma_xy**2, 1 / sigma_theta**2])


def finished_map_field(world: FloatArray, resolution: float) -> LikelihoodField:
    """The field a keyframe or scan is refined against once the graph holds the map (see
    FINISHED_MAP_FIELD_SCALE), of the map's points thinned to one per half front-end cell:
    passes through one place repeat their points."""
    fine = resolution * FINISHED_MAP_FIELD_SCALE
    return LikelihoodField.from_points(voxel_filter(world, resolution / 2), fine, fine)


def match_information(information: FloatArray, sigma_xy: float, sigma_theta: float) -> FloatArray:
    """Edge information from a match: inflated GN covariance plus a floor, inverted (in the
    frame the match was made in; :func:`rotate_information` takes it into the edge's frame).

    ``(H^-1 s + F)^-1`` is computed as ``(I + H F / s)^-1 H / s``, which needs no inverse of
    ``H``: a scan with a handful of points along one wall (a laser that sees little in a hall)
    has an information matrix of rank one, whose inverse is ``inf`` or garbage, where a double
    inversion raises. A direction the scan did not measure gets no information here.
    """
    h = np.asarray(information, dtype=np.float64) / MATCH_COV_SCALE
    floor = np.diag([sigma_xy**2, sigma_xy**2, sigma_theta**2])
    out = np.asarray(np.linalg.solve(np.eye(3) + h @ floor, h), dtype=np.float64)
    symmetric: FloatArray = (out + out.T) / 2
    return symmetric


def spread_information(information: FloatArray, spread: FloatArray) -> FloatArray:
    """Information of a measurement whose covariance is widened by ``spread spread^T``: it
    says nothing more precise than the spread along that direction, and as much as before
    across it. Sherman-Morrison, ``H - H d (H d)^T / (1 + d^T H d)``, so a singular ``H`` (a
    direction the scan did not measure) needs no inverse."""
    h = np.asarray(information, dtype=np.float64)
    hd = h @ spread
    out: FloatArray = h - np.outer(hd, hd) / (1.0 + float(spread @ hd))
    symmetric: FloatArray = (out + out.T) / 2
    return symmetric


def edge_covariance(information: FloatArray) -> FloatArray:
    """An edge's covariance from its information, finite where the edge measured nothing.

    :func:`match_information` leaves a direction a scan did not measure without information;
    such a direction (information under ``UNMEASURED_INFORMATION``) is given that much, a
    standard deviation of 1 km, instead of an inverse that raises. An edge that measured every
    direction is inverted as it is.
    """
    info = np.asarray(information, dtype=np.float64)
    if float(np.linalg.eigvalsh(info)[0]) < UNMEASURED_INFORMATION:
        info = info + UNMEASURED_INFORMATION * np.eye(3)
    cov: FloatArray = np.asarray(np.linalg.inv(info), dtype=np.float64)
    return cov


def place_on_ridge(
    guess: FloatArray, guess_info: FloatArray, best: FloatArray, spread: FloatArray
) -> FloatArray:
    """The pose on the ridge from ``best`` to ``best + spread`` that odometry's ``guess``
    (weighed by its information) likes best. The ridge was seen between its two ends only:
    a pose beyond them is where the scan fits worse, so the choice stops at the ends."""
    miss = guess - best
    miss[2] = float(se2.wrap(miss[2]))
    along = float(spread @ guess_info @ spread)
    t = float(np.clip(spread @ guess_info @ miss / along, 0.0, 1.0)) if along > 0 else 0.0
    out: FloatArray = best + t * spread
    out[2] = float(se2.wrap(out[2]))
    return out


def rotate_information(info: FloatArray, theta: float) -> FloatArray:
    """Information in the frame of the matched pose (heading ``theta`` in the frame the match
    was made in), where the pose graph expresses an edge's translational error."""
    c, s = math.cos(theta), math.sin(theta)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out: FloatArray = rot.T @ info @ rot
    return out


def lattice_angle_step(typical_range_m: float, resolution: float) -> float:
    """Lattice rotation step that moves a typical point of the scan by about one cell."""
    return min(MAX_ANGLE_STEP_RAD, max(MIN_ANGLE_STEP_RAD, resolution / typical_range_m))


def search_window(
    linear: float, angular: float, angle_step: float, resolution: float
) -> SearchWindow:
    coarse = COARSE_STEP_CELLS if linear > COARSE_ABOVE_CELLS * resolution else 1
    return SearchWindow(linear, angular, angle_step, coarse_step_cells=coarse)


def same_shift(a: FloatArray, b: FloatArray) -> bool:
    """Two rigid corrections of the chain that agree (CAR_FAR_AGREE)."""
    d = se2.between(a, b)
    return bool(
        math.hypot(d[0], d[1]) <= CAR_FAR_AGREE_M and abs(se2.wrap(d[2])) <= CAR_FAR_AGREE_RAD
    )


def match_edge(
    anchor: int,
    k: int,
    result: MatchResult,
    *,
    kind: str,
    spread: FloatArray | None = None,
) -> Edge:
    """Edge anchor -> k from a match of keyframe k made in the anchor's frame.

    Front-end and car edges are trusted (plain least squares); loop closures get the
    robust kernel and their own floor sigmas, and can be outvoted.
    """
    loop = kind in ("loop", "car")
    info = match_information(
        result.information,
        LOOP_SIGMA_M if loop else MATCH_SIGMA_M,
        LOOP_SIGMA_RAD if loop else MATCH_SIGMA_RAD,
    )
    if spread is not None:
        info = spread_information(info, spread)
    return Edge(
        anchor,
        k,
        result.pose.copy(),
        rotate_information(info, result.pose[2]),
        kind,
        robust_c=LOOP_ROBUST_C if loop else None,
    )
