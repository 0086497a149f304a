"""``baromap import ...`` (outside data into recordings) and ``baromap info`` (what a run holds)."""

from __future__ import annotations

import argparse
from typing import Any


def register(subparsers: Any) -> None:
    info = subparsers.add_parser("info", help="summarise a recording: topics, counts, metadata")
    info.add_argument("recording", help="MCAP file")
    info.set_defaults(run=run_info)

    importer = subparsers.add_parser("import", help="bring outside data into a recording")
    kinds = importer.add_subparsers(dest="format", metavar="FORMAT", required=True)
    carmen = kinds.add_parser(
        "carmen", help="import a CARMEN log (FLASER, ROBOTLASER1, ODOM) as a recording"
    )
    carmen.add_argument("log", help="CARMEN log, plain or .gz")
    carmen.add_argument("-o", "--output", required=True, help="recording to write (.mcap)")
    carmen.add_argument(
        "--synth-odometry",
        type=int,
        default=None,
        metavar="SEED",
        help="replace missing odometry by the reference poses degraded with a seeded error "
        "model (5 %% scale, 2 deg/m heading drift, random noise)",
    )
    carmen.set_defaults(run=run_import_carmen)
    csv = kinds.add_parser(
        "csv", help="import a time_s,pressure_pa[,temperature_c] CSV as a recording"
    )
    csv.add_argument("csv", help="CSV pressure log")
    csv.add_argument("-o", "--output", required=True, help="recording to write (.mcap)")
    csv.add_argument(
        "--reference", default=None, help="a reference station's CSV, for /reference/pressure"
    )
    csv.set_defaults(run=run_import_csv)


def run_import_carmen(args: argparse.Namespace) -> int:
    from baromap.recording.carmen_import import import_carmen

    counts = import_carmen(args.log, args.output, args.synth_odometry)
    print(
        f"wrote {args.output}: {counts['scans']} scans, {counts['odometry']} odometry poses"
        + (f", skipped {counts['skipped']}" if counts["skipped"] else "")
    )
    return 0


def run_import_csv(args: argparse.Namespace) -> int:
    from baromap.recording.csv_pressure import import_csv

    count = import_csv(args.csv, args.output, args.reference)
    print(f"wrote {args.output}: {count} pressure samples")
    return 0


def run_info(args: argparse.Namespace) -> int:
    from baromap.recording import read_messages, read_metadata

    counts: dict[str, int] = {}
    first: dict[str, int] = {}
    last: dict[str, int] = {}
    for rec in read_messages(args.recording):
        counts[rec.topic] = counts.get(rec.topic, 0) + 1
        first.setdefault(rec.topic, rec.log_time_ns)
        last[rec.topic] = rec.log_time_ns
    print(f"{args.recording}")
    if counts:
        t0, t1 = min(first.values()), max(last.values())
        print(f"  duration {(t1 - t0) / 1e9:.1f} s, {sum(counts.values())} messages")
    for topic in sorted(counts):
        span = (last[topic] - first[topic]) / 1e9
        rate = (counts[topic] - 1) / span if span > 0 else 0.0
        print(f"  {topic:24s} {counts[topic]:8d} msgs  {rate:7.2f} Hz")
    for name, data in sorted(read_metadata(args.recording).items()):
        print(f"  metadata {name}:")
        for key, value in sorted(data.items()):
            shown = value if len(value) <= 72 else value[:69] + "..."
            print(f"    {key} = {shown}")
    return 0
