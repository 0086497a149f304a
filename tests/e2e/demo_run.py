"""One run of ``baromap demo`` as a user runs it (a process of its own), and its outputs."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from baromap.cli.demo_mission import Mission
from baromap.sim.scenario import Scenario, make_scenario

REPO = Path(__file__).resolve().parent.parent.parent
#: Far above the demo's two minutes: a loaded CI machine may take several times as long.
DEMO_TIMEOUT_S = 1200


@dataclass(frozen=True, slots=True)
class DemoRun:
    out: Path
    exit_code: int
    stdout: str
    stderr: str
    wall_s: float

    @property
    def lines(self) -> list[str]:
        return self.stdout.splitlines()

    @property
    def mission(self) -> Mission:
        record = json.loads((self.out / "mission.json").read_text())
        record["route"] = tuple(record["route"])
        return Mission(**record)

    def scenario(self) -> Scenario:
        m = self.mission
        return make_scenario(m.seed, floors=m.floors, minutes=m.minutes, route=m.route)

    @property
    def recording(self) -> Path:
        (path,) = sorted((self.out / "recording").glob("*.mcap"))
        return path

    @property
    def maps(self) -> Path:
        return self.out / "maps"

    def watch_lines(self) -> list[str]:
        """What ``baromap watch`` printed, as the demo showed it."""
        return [
            line.split(" | ", 1)[1] for line in self.lines if line.strip().startswith("watch |")
        ]


def run_demo(out: Path) -> DemoRun:
    started = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "baromap.cli.main", "demo", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=DEMO_TIMEOUT_S,
        cwd=out.parent,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        check=False,
    )
    return DemoRun(out, proc.returncode, proc.stdout, proc.stderr, time.monotonic() - started)
