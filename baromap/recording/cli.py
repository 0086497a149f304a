"""``baromap import ...`` (outside data into recordings) and ``baromap info`` (what a run holds)."""

from __future__ import annotations

import argparse
import importlib
from typing import Any

#: Modules contributing an importer through ``register_import(import_subparsers)``.
IMPORTER_MODULES: tuple[str, ...] = (
    "baromap.recording.carmen",
    "baromap.recording.csv_pressure",
)


def register(subparsers: Any) -> None:
    info = subparsers.add_parser("info", help="summarise a recording: topics, counts, metadata")
    info.add_argument("recording", help="MCAP file")
    info.set_defaults(run=run_info)

    importer = subparsers.add_parser("import", help="bring outside data into a recording")
    kinds = importer.add_subparsers(dest="format", metavar="FORMAT", required=True)
    for name in IMPORTER_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue
        module.register_import(kinds)


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
