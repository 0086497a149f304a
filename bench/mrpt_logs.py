"""Another SLAM on the same inputs as bench/mapping.py: MRPT's icp-slam or rbpf-slam on the
public laser logs.

    .venv/bin/python bench/mrpt_logs.py [--method icp|rbpf] [--logs fr079,acapulco]
                                        [--seeds 0,1,2] [--max-range M] [--keep DIR]
                                        [--save-poses DIR] [--gate-odometry]
                                        [ICP settings, see --help]

Issue 14's ATE bar is measured against GMapping's corrected poses, which are an estimate
themselves. Whether the bar is reachable at all is a question about the reference as much as
about baromap: a second, independent SLAM fed exactly the same scans and the same synthesised
odometry (``synthesize_odometry(reference, seed)``, as ``baromap.evaluation.laser_logs`` does)
and scored with the same code (``trajectory_error``, ``relation_errors``) tells how close a good
SLAM that is not GMapping lands. MRPT 2.5.8 (``apt-get install mrpt-apps``):

- ``icp-slam`` matches every scan by ICP against one growing point map (the settings of MRPT's
  ``icp-slam_demo_classic.ini``, localising at every scan), with no pose graph and no loop
  closure: revisits are matched against the points laid down on the first visit;
- ``rbpf-slam``, a Rao-Blackwellised particle filter with grid maps and the optimal proposal
  (GMapping's family; MRPT's ``gridmapping_optimal_sampling.ini``), fed keyframes every 0.5 m
  or 25 deg as baromap takes them, the scans between placed as baromap places them before
  its last registration (``slam.scan_poses``). It needs the actions/sensory-frames rawlog
  format: ``bench/mrpt_to_sf.cpp``, built here with g++ against ``libmrpt-obs-dev``.

The input goes through MRPT's own converter: a CARMEN log whose ``FLASER`` lines carry the
log's ranges and the synthesised odometry as both the laser and the robot pose, then
``carmen2rawlog``. MRPT 2.5.8's converter stamps every observation with the same time (its
CARMEN parser ignores the log's times), and icp-slam's odometry extrapolation then drops every
odometry step as a zero time difference; the rawlog's timestamps are rewritten in place to the
log's own times (each object's 8-byte stamp, all equal after conversion, found by its value).
``--gate-odometry`` feeds the odometry ``bench/gate.py`` makes for the case named as the log
(``baromap.evaluation.log_variants``, its default error model) instead, so MRPT's figure sits
beside the gate's row for that case and seed; ``--logs`` takes every log of
``baromap.evaluation.laser_logs.LOGS``, the three published with broken stamps
(``belgioioso``, ``corridor``, ``campus``) timed by their scan order as the importer times them.
Beams beyond ``--max-range`` (default 20 m; baromap's ``SlamConfig.max_range_m`` is 30 m, so
compare like with like when changing either) are no return: Acapulco's scanner reports no
return as 50-51.2 m, which ICP otherwise takes for walls.
Not part of the package: it needs MRPT's binaries and writes files.
"""

from __future__ import annotations

import argparse
import gzip
import math
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
LASER = Path(os.environ.get("BAROMAP_SHARED_DATA", REPO.parent / "shared" / "data")) / "laser"

#: 100 ns ticks between 1601-01-01 (MRPT's TTimeStamp epoch) and the Unix epoch
FILETIME_UNIX_TICKS = 11_644_473_600 * 10**7

ICP_INI = """\
[ICP]
maxIterations = 80
minAbsStep_trans = 1e-6
minAbsStep_rot = 1e-6
thresholdDist = {icp_m}
thresholdAng_DEG = {icp_deg}
ALFA = 0.8
smallestThresholdDist = 0.05
onlyClosestCorrespondences = true
onlyUniqueRobust = true
ICP_algorithm = icpClassic
corresponding_points_decimation = {decimation}

[MappingApplication]
rawlog_file = {rawlog}
rawlog_offset = 0
logOutput_dir = {out}
LOG_FREQUENCY = 1000000
SAVE_3D_SCENE = 0
SAVE_POSE_LOG = 0
CAMERA_3DSCENE_FOLLOWS_ROBOT = 0
SHOW_PROGRESS_3D_REAL_TIME = 0
SHOW_LASER_SCANS_3D = false
localizationLinDistance = {loc_m}
localizationAngDistance = {loc_deg}
insertionLinDistance = {ins_m}
insertionAngDistance = {ins_deg}
minICPgoodnessToAccept = {goodness}
matchAgainstTheGrid = 0
occupancyGrid_count = 0
gasGrid_count = 0
landmarksMap_count = 0
beaconMap_count = 0
pointsMap_count = 1
likelihoodMapSelection = -1

[MappingApplication_pointsMap_00_insertOpts]
minDistBetweenLaserPoints = 0.05
fuseWithExisting = false
isPlanarMap = 1
"""


def write_carmen(path: Path, scans: list[Any], odom: np.ndarray, max_range_m: float) -> None:
    """FLASER lines: the log's ranges, the synthesised odometry as laser and robot pose.

    Beams beyond ``max_range_m`` are no return to MRPT, as to baromap's SLAM (Acapulco's
    scanner marks no return with 50-51.2 m, 8 % of its beams, which ICP took for walls). MRPT's
    parser takes the beams' spacing from a PARAM line (without one it assumes half a
    degree, and a 181-beam scan at one degree comes out squeezed into 90 degrees)."""
    # MRPT spreads n beams over n times the resolution, centred: this puts them where they are
    n = len(scans[0].ranges_m)
    resolution = math.degrees(scans[0].angle_increment_rad) * (n - 1) / n
    with path.open("w") as f:
        f.write(f"PARAM laser_front_laser_resolution {resolution:g} nohost 0\n")
        f.write(f"PARAM robot_front_laser_max {max_range_m:g} nohost 0\n")
        for s, p in zip(scans, odom, strict=True):
            ranges = " ".join(f"{v:.3f}" for v in s.ranges_m)
            pose = f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f}"
            f.write(f"FLASER {len(s.ranges_m)} {ranges} {pose} {pose} 0 host 0\n")


def restamp(rawlog: Path, times_ns: np.ndarray) -> None:
    """Every object of ``rawlog`` (odometry, scan, odometry, scan...) gets its scan's time."""
    with gzip.open(rawlog) as f:
        raw = bytearray(f.read())
    now = (int(time.time()) * 10**7) + FILETIME_UNIX_TICKS
    month = 10**7 * 86400 * 30
    hits: list[int] = []
    for off in range(8):
        n = (len(raw) - off) // 8
        v = np.frombuffer(bytes(raw), dtype="<u8", count=n, offset=off).astype(np.int64)
        hits += [off + 8 * int(i) for i in np.nonzero(np.abs(v - now) < month)[0]]
    # the conversion's one stamp, repeated in every object; anything else is a coincidence
    stamp = Counter(bytes(raw[h : h + 8]) for h in hits).most_common(1)[0][0]
    hits = sorted(h for h in hits if bytes(raw[h : h + 8]) == stamp)
    if len(hits) != 2 * len(times_ns):
        raise RuntimeError(f"expected {2 * len(times_ns)} equal stamps, found {len(hits)}")
    base = int.from_bytes(stamp, "little")
    for i, h in enumerate(hits):
        ticks = base + int(times_ns[i // 2] - times_ns[0]) // 100
        raw[h : h + 8] = ticks.to_bytes(8, "little")
    with gzip.open(rawlog, "wb") as f:
        f.write(bytes(raw))


RBPF_INI = """\
[MappingApplication]
rawlog_file = {rawlog}
rawlog_offset = 0
logOutput_dir = {out}
LOG_FREQUENCY = 1000000
GENERATE_LOG_JOINT_H = 0
GENERATE_LOG_INFO = 0
SAVE_MAP_IMAGES = 0
SAVE_3D_SCENE = 0
SAVE_POSE_LOG = 0
SAVE_ENOSE_READINGS = 0
CAMERA_3DSCENE_FOLLOWS_ROBOT = 0
SHOW_PROGRESS_IN_WINDOW = 0
insertionLinDistance = 0
insertionAngDistance_deg = 0
localizeLinDistance = 0
localizeAngDistance_deg = 0
verbosity_level = WARN
PF_algorithm = 3
adaptiveSampleSize = 0
resamplingMethod = 0
sampleSize = {particles}
BETA = 0.50
occupancyGrid_count = 1
gasGrid_count = 0
landmarksMap_count = 0
beaconMap_count = 0
pointsMap_count = 0
likelihoodMapSelection = -1
powFactor = 0.01
pfAuxFilterOptimal_MaximumSearchSamples = 400
pfOptimalProposal_mapSelection = 0

[MappingApplication_occupancyGrid_00_creationOpts]
resolution = 0.05
disableSaveAs3DObject = 1

[MappingApplication_occupancyGrid_00_insertOpts]
mapAltitude = 0
useMapAltitude = 0
maxDistanceInsertion = 35
maxOccupancyUpdateCertainty = 0.60
considerInvalidRangesAsFreeSpace = 1
minLaserScanNoiseStd = 0.001
wideningBeamsWithDistance = 0

[MappingApplication_occupancyGrid_00_likelihoodOpts]
likelihoodMethod = 4
LF_decimation = 5
LF_stdHit = 0.20
LF_maxCorrsDistance = 0.30
LF_zHit = 0.999
LF_zRandom = 0.001
LF_maxRange = 30
LF_alternateAverageMethod = 0
enableLikelihoodCache = 1
"""


def converter(work: Path) -> Path:
    """bench/mrpt_to_sf.cpp built against MRPT's headers (libmrpt-obs-dev)."""
    exe = work / "mrpt_to_sf"
    if not exe.exists():
        includes = [f"-I{d}" for d in sorted(Path("/usr/include/mrpt").glob("*/include"))]
        libs = "obs io serialization poses system core rtti math containers bayes img random config"
        subprocess.run(
            ["g++", "-O1", "-std=c++17", str(REPO / "bench" / "mrpt_to_sf.cpp"), "-o", str(exe)]
            + ["-I/usr/include/mrpt", *includes, "-I/usr/include/eigen3"]
            + [f"-lmrpt-{lib}" for lib in libs.split()],
            check=True,
        )
    return exe


def run_mrpt(work: Path, name: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    from baromap.evaluation.laser_logs import LOGS
    from baromap.evaluation.trajectory import trajectory_error
    from baromap.mapping import se2
    from baromap.mapping.relations import read_relations, relation_errors
    from baromap.mapping.slam import scan_poses
    from baromap.odometry.synthesis import synthesize_odometry
    from baromap.recording.carmen import read_carmen

    spec = LOGS[name]
    carmen = read_carmen(LASER / spec.log_file)
    times = carmen.scan_times_ns()
    reference = carmen.reference_poses()
    if args.perfect_odometry:
        odom = reference.copy()
    elif args.gate_odometry:
        from baromap.evaluation.log_variants import ODOMETRY, degrade

        odom = degrade(reference, seed, ODOMETRY["default"])
    else:
        odom = synthesize_odometry(reference, seed)
    tag = f"{name}{seed}"
    log = work / f"{tag}.log"
    rawlog = work / f"{tag}.rawlog"
    out = work / f"out_{args.method}_{tag}"
    # from the origin: MRPT's map starts there
    write_carmen(log, carmen.scans, se2.between(odom[0], odom), args.max_range)
    subprocess.run(
        ["carmen2rawlog", "-q", "-w", "-i", str(log), "-o", str(rawlog)],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    restamp(rawlog, times)
    ini = work / f"{args.method}_{tag}.ini"
    if args.method == "icp":
        ini.write_text(
            ICP_INI.format(
                decimation=args.decimation,
                rawlog=rawlog,
                out=out,
                loc_m=args.localize_m,
                loc_deg=args.localize_deg,
                ins_m=args.insert_m,
                ins_deg=args.insert_deg,
                icp_m=args.icp_m,
                icp_deg=args.icp_deg,
                goodness=args.min_goodness,
            )
        )
        command = ["icp-slam", str(ini)]
    else:
        # the Gaussian motion model sized to the synthesis's error model: 5 % of distance
        # plus 2 % noise, 2 deg/m creep plus 0.5 deg/m noise, 2 % of a turn (a2, the
        # distance error per degree turned, and the floors, MRPT's defaults)
        sf = work / f"{tag}_sf.rawlog"
        motion = ["0.06", "0.0573", f"{math.radians(2.5):.5f}", "0.05", "0.01", "0.00349"]
        # keyframes as baromap's SLAM takes them (SlamConfig: 0.5 m or 25 deg)
        frames = ["0.5", f"{math.radians(25.0):.5f}"]
        made = subprocess.run(
            [str(converter(work)), str(rawlog), str(sf), *motion, *frames],
            check=True,
            capture_output=True,
            text=True,
        )
        kept = np.array([int(v) for v in made.stdout.split()], dtype=np.int64)
        ini.write_text(RBPF_INI.format(rawlog=sf, out=out, particles=args.particles))
        command = ["rbpf-slam", str(ini)]
    start = time.perf_counter()
    cpu0 = os.times()
    with (work / f"{args.method}_{tag}.out").open("w") as sink:
        subprocess.run(command, check=True, stdout=sink, stderr=subprocess.STDOUT)
    cpu1 = os.times()
    wall = time.perf_counter() - start
    cpu = (cpu1.children_user - cpu0.children_user) + (cpu1.children_system - cpu0.children_system)
    if args.method == "icp":
        path = np.loadtxt(out / "log_estimated_path.txt")
        if len(path) != 2 * len(times):
            raise RuntimeError(f"{len(path)} path steps for {len(times)} scans")
        # objects alternate odometry, scan: the pose after each scan's step is the scan's
        poses = path[1::2, 1:4]
    else:
        # the most likely particle's whole path (what GMapping's corrected poses are), one
        # pose per keyframe after a first one at the origin; the scans between keyframes
        # follow odometry, bent to end on the next keyframe, as baromap's own are before
        # their last registration
        path = np.loadtxt(out / "most_likely_path.txt")
        if len(path) != len(kept) + 1:
            raise RuntimeError(f"{len(path)} path poses for {len(kept)} keyframes")
        poses = scan_poses(odom, kept, path[1:, :3])
    result = {
        "ate": trajectory_error(poses, reference),
        "odometry_ate": trajectory_error(odom, reference),
        "wall": wall,
        "cpu": cpu,
        "poses": poses,
    }
    if spec.relations_file is not None:
        relations = read_relations(LASER / spec.relations_file)
        result["rel"] = relation_errors(times, poses, relations)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", default="fr079,acapulco")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--method", default="icp", choices=("icp", "rbpf"))
    parser.add_argument("--particles", type=int, default=25, help="rbpf-slam's")
    parser.add_argument("--max-range", type=float, default=20.0, help="beyond: no return")
    parser.add_argument("--decimation", type=int, default=5, help="ICP's point decimation")
    parser.add_argument("--localize-m", type=float, default=0.0)
    parser.add_argument("--localize-deg", type=float, default=0.0)
    parser.add_argument("--insert-m", type=float, default=1.2)
    parser.add_argument("--insert-deg", type=float, default=45.0)
    parser.add_argument("--icp-m", type=float, default=0.3, help="ICP's first pairing distance")
    parser.add_argument("--icp-deg", type=float, default=5.0, help="its growth with range")
    parser.add_argument("--min-goodness", type=float, default=0.4, help="ICP matches accepted")
    parser.add_argument("--perfect-odometry", action="store_true", help="a check: no error")
    parser.add_argument(
        "--gate-odometry",
        action="store_true",
        help="the odometry of bench/gate.py's case LOG at the same seed, not the synthesis's",
    )
    parser.add_argument("--keep", type=Path, default=None, help="keep inputs and outputs here")
    parser.add_argument("--save-poses", type=Path, default=None, help="NAME_SEED.npy per run")
    args = parser.parse_args()
    import logging

    import structlog

    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.WARNING))
    work = args.keep or Path(tempfile.mkdtemp(prefix="baromap-mrpt-"))
    work.mkdir(parents=True, exist_ok=True)
    for name in args.logs.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            r = run_mrpt(work, name, seed, args)
            ate = r["ate"]
            text = f"{name} seed {seed}: {args.method}-slam ATE {ate.rms_m:.3f} m"
            text += f" (max {ate.max_m:.3f})"
            text += f", odometry alone {r['odometry_ate'].rms_m:.3f} m"
            if "rel" in r:
                text += f"; relations {r['rel'].trans_mean:.4f} m, {r['rel'].rot_mean:.3f} deg"
            one, five, _ = os.getloadavg()
            text += f"; {r['wall']:.1f} s wall, {r['cpu']:.1f} s cpu"
            text += f", load {one:.1f} (5 min {five:.1f})"
            print(text, flush=True)
            if args.save_poses is not None:
                args.save_poses.mkdir(parents=True, exist_ok=True)
                np.save(args.save_poses / f"{name}_{seed}.npy", r["poses"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
