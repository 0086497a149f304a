"""Floor-aware graph SLAM over a whole run.

Keyframes: every ``keyframe_m`` metres or ``keyframe_deg`` of odometric motion, plus the first
and last scan of every floor visit (the robot in the elevator car, before and after a ride).

Front end: each keyframe is matched against the submap it is driving through (the last 20 to
40 keyframes of the visit fused into one likelihood field, :mod:`baromap.mapping.submaps`),
with odometry as a soft prior so a featureless corridor cannot make it slide. The search
window follows the motion since the last keyframe: what odometry can have got wrong over it,
so a sparse log's metre-long steps and 80-degree turns get a wide coarse-to-fine search and a
dense log's centimetre steps a narrow one. A match that a clearly different pose explains
almost as well (a door further along, the room turned) is ambiguous and refused: odometry
alone carries that step. After a turn of more than 90 degrees between keyframes (a sparse log
turning round), a poor match is tried again against the keyframes of the last 20 m: looking
back, the scan sees what the submap of the last metres, seen looking forward, hardly holds.
Both odometry and the match enter the pose graph, the match with the information of its own
fit (weak along a corridor, strong across it).

Odometry's systematic errors (distance read long by the tyres, turns by a skid-steer's slip,
heading creep per metre) are learnt from the front end's matches wherever they pin a step
down at both ends (:mod:`baromap.mapping.odometry_calibration`), and taken out of every later
odometric step and, at the end, of every odometry edge: along a featureless corridor, where
odometry alone decides, a 2 % scale error would otherwise stretch the map. What corrected
odometry still gets wrong per step is measured on the same matched steps, and the last solve
weighs every odometry edge by it rather than by the front end's deliberately wide sigmas; then
every kind of edge (odometry, matches, closures, the car) is scaled to how far it actually
scatters against that solve, and the graph solved again.

Loop closures: each keyframe looks for finished submaps of the *same floor* (the barometer's
verdict) that it sees from near where they were built, and matches against each with a
window as wide as the front end can have drifted since it was last tied to the map (the path
since the submap, or since the last closure, whichever is shorter); a submap of a sparse log,
a scan every few metres, holds too few scans to score a revisit, and the keyframes around the
revisited one stand in for it. Ambiguous matches and corrections larger than that drift are
refused, and accepted closures carry a Cauchy kernel, so the few wrong ones that pass cannot
bend the map. Against such a target of few scans a revisit scores low (what the revisiting
scan sees, they mostly never saw) and may come back after long stretches without a closure,
metres off: there a closure under the threshold, or from a window as wide as the drift
(searched by branch and bound), is taken only once another keyframe's closure implies the
same correction. Different floors never close against each other: stacked floors can look
identical, and only the barometer tells them apart.

Floors: the elevator car, the one place seen on every floor, joins them. The car travels with
the robot and stands in the same shaft on every floor, so every pair of car keyframes (the
closed car, before and after each ride, from any floor) is matched; together these keep all
floors in one frame. The graph is solved when a closure disagrees with it (a correction that
moves the map), not after every keyframe.

Scans that are not keyframes get the corrected pose of the keyframes around them: odometry
between the two, with the correction the graph made to that stretch spread along it.

The code: :func:`run_slam` feeds the keyframes one by one to parts that each keep their own
state and are handed what they use: the keyframes and what the odometry said
(``state.Keyframes``), the submaps (``state.Submaps``), the pose graph and its closures
(``state.Chain``), what the run learns about odometry (``state.OdometryLearning``), the front
end (``front_end``), loop closure (``loops``), the car (``car``), the search after an
unmeasured step (``relocation``) and the last solve (``final_solve``).
"""

from baromap.mapping.slam.measurement import (
    edge_covariance,
    match_information,
    place_on_ridge,
    spread_information,
)
from baromap.mapping.slam.run import SlamResult, run_slam, scan_poses, select_keyframes
from baromap.mapping.slam.settings import BETWEEN_FLOORS, MATCH_COV_SCALE, SlamConfig

__all__ = [
    "BETWEEN_FLOORS",
    "MATCH_COV_SCALE",
    "SlamConfig",
    "SlamResult",
    "edge_covariance",
    "match_information",
    "place_on_ridge",
    "run_slam",
    "scan_poses",
    "select_keyframes",
    "spread_information",
]
