"""One run of ``baromap demo`` as a user runs it (a process of its own), and its outputs.

While it runs, a third-party viewer joins its live view: ``tests/liveview/js/view.js``
(``@foxglove/ws-protocol``'s FoxgloveClient under Node), started when the demo prints the
ws:// address, and ending when the daemon stops. What it saw is ``viewer.json`` beside the
demo's outputs; without Node (or its packages: ``make test`` installs them) it is not run, and
``viewer_skipped`` says why.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from baromap.cli.demo_mission import Mission
from baromap.sim.scenario import Scenario, make_scenario

REPO = Path(__file__).resolve().parent.parent.parent
#: Far above the demo's two minutes: a loaded CI machine may take several times as long.
DEMO_TIMEOUT_S = 1200
VIEWER_JS = REPO / "tests" / "liveview" / "js"
#: The line the demo prints when the daemon's live view serves.
VIEW_LINE = re.compile(r"live view on (ws://\S+)")


@dataclass(frozen=True, slots=True)
class DemoRun:
    out: Path
    exit_code: int
    stdout: str
    stderr: str
    wall_s: float
    viewer_skipped: str | None = None

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

    @property
    def viewer(self) -> Path:
        """What the live view's third-party viewer saw (``view.js``'s JSON)."""
        return self.out / "viewer.json"

    def watch_lines(self) -> list[str]:
        """What ``baromap watch`` printed, as the demo showed it."""
        return [
            line.split(" | ", 1)[1] for line in self.lines if line.strip().startswith("watch |")
        ]


def viewer_missing() -> str | None:
    """Why the Node viewer cannot run here, or None."""
    if shutil.which("node") is None:
        return "node not found (Debian: apt-get install nodejs npm; then make test)"
    if not (VIEWER_JS / "node_modules" / "@foxglove" / "ws-protocol").is_dir():
        return f"the viewer's packages are not installed (make viewer-client, in {REPO})"
    return None


def run_demo(out: Path) -> DemoRun:
    """The demo, with the Node viewer joining its live view as soon as it is announced."""
    started = time.monotonic()
    missing = viewer_missing()
    proc = subprocess.Popen(
        [sys.executable, "-m", "baromap.cli.main", "demo", "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=out.parent,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    err: list[str] = []
    reader = threading.Thread(target=lambda: err.extend(proc.stderr or ()), daemon=True)
    reader.start()
    lines: list[str] = []
    viewer: subprocess.Popen[bytes] | None = None
    out.mkdir(parents=True, exist_ok=True)
    (out / "viewer.json").unlink(missing_ok=True)
    # a demo that hangs, silent or not, is killed at the deadline (its output then ends)
    watchdog = threading.Timer(DEMO_TIMEOUT_S, proc.kill)
    watchdog.start()
    try:
        for line in proc.stdout or ():
            lines.append(line)
            found = VIEW_LINE.search(line)
            if found and viewer is None and missing is None:
                with (out / "viewer.log").open("wb") as log:  # the child has its own copy
                    viewer = subprocess.Popen(
                        ["node", "view.js", found.group(1), str(out / "viewer.json")],
                        cwd=VIEWER_JS,
                        stdout=subprocess.DEVNULL,
                        stderr=log,
                    )
        proc.wait()
    finally:
        watchdog.cancel()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if viewer is not None:
            try:  # it ends when the daemon's server goes; a stuck one writes what it has
                viewer.wait(30)
            except subprocess.TimeoutExpired:
                viewer.terminate()
                viewer.wait(10)
    reader.join(10)
    if missing is None and viewer is None:
        missing = "the demo printed no live view address"
    return DemoRun(
        out,
        proc.returncode,
        "".join(lines),
        "".join(err),
        time.monotonic() - started,
        viewer_skipped=missing,
    )
