"""``baromap export ros2|rmf``: baromap's outputs for ROS 2 and Open-RMF."""

from __future__ import annotations

import argparse
from typing import Any


def register(subparsers: Any) -> None:
    export = subparsers.add_parser(
        "export", help="convert a run or its maps for other ecosystems (ROS 2, Open-RMF)"
    )
    kinds = export.add_subparsers(dest="format", metavar="FORMAT", required=True)
    ros2 = kinds.add_parser(
        "ros2",
        help="write a recording as a rosbag2 (MCAP storage, ROS 2 Jazzy message types)",
        description="Write a recording as a rosbag2 directory: LaserScan, Odometry, /tf and "
        "/tf_static, FluidPressure and Temperature, diagnostics, floor events as "
        "std_msgs/String JSON. With --maps, each floor map of a build-maps directory is added "
        "as nav_msgs/OccupancyGrid on /floor_<k>/map (latched), and the map -> odom transforms "
        "of its maps.mcap on /tf.",
    )
    ros2.add_argument(
        "recording",
        nargs="+",
        help="baromap recording (.mcap); a run baromapd rotated into several files: all of "
        "them, or their directory (one bag)",
    )
    ros2.add_argument(
        "--across-runs",
        action="store_true",
        help="the files are runs of one exploration (baromapd restarted in between)",
    )
    ros2.add_argument("-o", "--output", required=True, help="bag directory to create")
    ros2.add_argument(
        "--maps", default=None, metavar="OUT", help="a build-maps output directory of this run"
    )
    ros2.set_defaults(run=run_ros2)
    rmf = kinds.add_parser(
        "rmf",
        help="write build-maps' building as an Open-RMF building map (traffic-editor format)",
        description="Write an Open-RMF .building.yaml from a build-maps directory: one level "
        "per floor at its barometric elevation, each with its map as drawing (pixel-exact PNG "
        "written next to the output) and a measurement giving its scale, fiducials that align "
        "the levels, and a lift where the robot rode between floors (from trajectory.tum).",
    )
    rmf.add_argument("building", help="OUT/building.yaml written by build-maps")
    rmf.add_argument("-o", "--output", required=True, help="site file to write (.building.yaml)")
    rmf.add_argument("--name", default=None, help="building name (default: the output's stem)")
    rmf.set_defaults(run=run_rmf)


def run_ros2(args: argparse.Namespace) -> int:
    from baromap.export.ros2 import export_ros2

    result = export_ros2(
        args.recording, args.output, maps_dir=args.maps, across_runs=args.across_runs
    )
    total = sum(result.counts.values())
    print(f"wrote {result.path}: {total} messages on {len(result.counts)} topics")
    for topic, count in sorted(result.counts.items()):
        print(f"  {topic:28s} {count:8d}")
    for topic, count in sorted(result.skipped.items()):
        print(f"  skipped {topic} ({count} messages): no ROS 2 counterpart")
    return 0


def run_rmf(args: argparse.Namespace) -> int:
    from baromap.export.rmf import export_rmf

    site = export_rmf(args.building, args.output, name=args.name)
    print(f"wrote {site.path}: {len(site.levels)} levels, lift {site.lift or 'none'}")
    for level in site.levels:
        print(f"  {level}")
    for note in site.notes:
        print(f"  note: {note}")
    return 0
