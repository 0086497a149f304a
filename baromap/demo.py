"""``baromap demo``: the main job on the embedded default (no hardware).

The finished demo runs simulated devices on pseudo-terminals, the real daemon recording them,
live floor events over Zenoh, then per-floor maps. Until every stage exists, the demo runs the
stages that do and names the ones that do not, so nobody mistakes it for the finished product.
"""

from __future__ import annotations

import argparse
from typing import Any


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("demo", help="run the main job on simulated hardware")
    parser.add_argument("--out", default="out/demo", help="output directory (default out/demo)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    print("baromap demo: no stage of the pipeline exists yet; nothing to run.")
    return 0
