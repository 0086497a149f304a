"""``baromap build-maps RUN.mcap -o OUT``: per-floor maps and the building model of a run."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "build-maps",
        help="per-floor occupancy maps, trajectory and building model from a recorded run",
    )
    parser.add_argument(
        "recording",
        nargs="+",
        help="run recording (.mcap); a run baromapd rotated into several files: all of them, "
        "or the directory that holds them (ordered by the part each file names)",
    )
    parser.add_argument("-o", "--output", required=True, help="output directory")
    parser.add_argument(
        "--resolution", type=float, default=0.05, help="map cell size in metres (default 0.05)"
    )
    parser.add_argument(
        "--method",
        choices=("paper", "online"),
        default="online",
        help="floor detection replayed over the recorded pressure to cut the run "
        "(default: online, whose heights resist weather drift; paper: the baseline)",
    )
    parser.add_argument(
        "--runs",
        type=int,
        default=1,
        metavar="K",
        help="map the run K times, runs 2.. with the odometry moved by a micrometre, and keep "
        "the one whose revisits agree best with the scans (default 1: a recording at the "
        "laser's rate gives the SLAM many scans for each choice; a sparse log gains from 3)",
    )
    parser.add_argument(
        "--across-runs",
        action="store_true",
        help="the files are runs of one exploration of one robot (baromapd restarted in "
        "between): map them as one, in time order",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from baromap.mapping.build import build_maps, summary_lines

    out = Path(args.output)
    result = build_maps(
        args.recording,
        out,
        resolution=args.resolution,
        method=args.method,
        progress=not args.no_progress,
        runs=args.runs,
        across_runs=args.across_runs,
    )
    for line in summary_lines(result, out):
        print(line)
    return 0
