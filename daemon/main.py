"""Entry point of ``baromapd``.

The daemon is not written yet: its parts (codecs, simulated devices, floor detection,
recording) are being built first. Until then the command says so and exits non-zero rather
than pretending to record.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="baromapd", description="baromap acquisition daemon")
    parser.add_argument("--config", help="configuration file")
    parser.add_argument("--check-config", metavar="FILE", help="validate a configuration and exit")
    parser.parse_args(argv)
    print(
        "baromapd: not implemented yet; record simulated runs with 'baromap sim record'",
        file=sys.stderr,
    )
    return 3


if __name__ == "__main__":
    raise SystemExit(main())
