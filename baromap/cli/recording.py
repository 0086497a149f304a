"""``baromap import ...`` (outside data into recordings), ``baromap info`` (what a run holds) and
``baromap recover`` (a cut file made whole)."""

from __future__ import annotations

import argparse
from typing import Any

#: ``info``'s exit status for a file that was cut (read as far as it goes, but not whole).
EXIT_INCOMPLETE = 3


def register(subparsers: Any) -> None:
    info = subparsers.add_parser(
        "info",
        help="summarise a recording: topics, schemas, counts, rates, metadata",
        description="Summarise a recording from its MCAP summary section. A file that was not "
        "closed cleanly (power cut, killed recorder) has none: then it is read as far as its "
        "chunks are whole, the output says INCOMPLETE and why, and the exit status is "
        f"{EXIT_INCOMPLETE} (0: a whole file; 1: not readable at all).",
    )
    info.add_argument("recording", help="MCAP file")
    info.set_defaults(run=run_info)

    recover = subparsers.add_parser(
        "recover",
        help="rewrite a recording cut by SIGKILL or a power cut so every MCAP reader opens it",
        description="Copy every whole record of a cut recording (messages, metadata, "
        "attachments) into a new file with a summary, and say how many messages were kept "
        "and where the cut was. The cut file is left as it is.",
    )
    recover.add_argument("recording", help="the cut MCAP file")
    recover.add_argument("-o", "--output", required=True, help="the recovered file to write")
    recover.set_defaults(run=run_recover)

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
    carmen.add_argument(
        "--odometry-from",
        choices=("odom", "laser"),
        default="odom",
        help="where the log's own odometry is: its ODOM lines (default), or the robot pose "
        "its laser lines print, which in a raw log is the wheels' own",
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

    counts = import_carmen(args.log, args.output, args.synth_odometry, args.odometry_from)
    print(
        f"wrote {args.output}: {counts['scans']} scans, {counts['odometry']} odometry poses"
        + (f", skipped {counts['skipped']}" if counts["skipped"] else "")
        + (
            f", readings from {counts['range_limit_m']:.3f} m on are no return"
            if counts["range_limit_m"] is not None
            else ""
        )
    )
    return 0


def run_import_csv(args: argparse.Namespace) -> int:
    from baromap.recording.csv_pressure import import_csv

    count = import_csv(args.csv, args.output, args.reference)
    print(f"wrote {args.output}: {count} pressure samples")
    return 0


def run_info(args: argparse.Namespace) -> int:
    from baromap.recording.summary import summarize

    summary = summarize(args.recording)
    print(f"{args.recording}" + ("" if summary.complete else "  INCOMPLETE"))
    if not summary.complete:
        print(f"  not closed cleanly: {summary.stop}; what follows is what could be recovered")
    if summary.profile:
        print(f"  profile {summary.profile}")
    start, end = summary.start_ns, summary.end_ns
    if start is not None and end is not None:
        print(f"  duration {(end - start) / 1e9:.1f} s, {summary.message_count} messages")
    for topic in summary.topics:
        print(
            f"  {topic.topic:24s} {topic.count:8d} msgs  {topic.rate_hz:7.2f} Hz  "
            f"{topic.schema} ({topic.encoding})"
        )
    for name, data in sorted(summary.metadata.items()):
        print(f"  metadata {name}:")
        for key, value in sorted(data.items()):
            shown = value if len(value) <= 72 else value[:69] + "..."
            print(f"    {key} = {shown}")
    return 0 if summary.complete else EXIT_INCOMPLETE


def run_recover(args: argparse.Namespace) -> int:
    import datetime as dt

    from baromap.recording.recover import recover

    result = recover(args.recording, args.output)
    topics = ", ".join(f"{topic} {n}" for topic, n in sorted(result.topics.items()))
    print(
        f"wrote {result.target}: kept {result.messages} messages ({topics or 'none'}), "
        f"{result.metadata} metadata records, {result.attachments} attachments"
    )
    if result.cut_at is None:
        print(f"{result.source} was not cut (it was closed cleanly): copied whole")
    else:
        print(
            f"{result.source} was cut at byte {result.cut_at} of {result.size} "
            f"({result.size - result.cut_at} bytes dropped): {result.reason}"
        )
    if result.last_log_time is not None:
        last = dt.datetime.fromtimestamp(result.last_log_time / 1e9, tz=dt.UTC)
        print(f"last message kept: {last:%Y-%m-%dT%H:%M:%S.%f}Z")
    return 0
