"""The demo, run once for the whole test session, as a user runs it (``baromap demo``).

Every test of this package reads the same run: the demo takes two minutes, so it is run once
and shared, also between pytest-xdist workers (a lock file in the session's base temporary
directory, which the workers share: the first worker runs it, the others wait and read).
"""

from __future__ import annotations

import fcntl
import json
import os

import pytest
from demo_run import DemoRun, run_demo


@pytest.fixture(scope="session")
def demo(tmp_path_factory: pytest.TempPathFactory) -> DemoRun:
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):  # each worker's base sits in the session's
        base = base.parent
    shared = base / "baromap-e2e"
    shared.mkdir(exist_ok=True)
    done = shared / "demo.json"
    with (shared / "lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not done.exists():
                run = run_demo(shared / "demo")
                keys = ("exit_code", "stdout", "stderr", "wall_s", "viewer_skipped")
                record = {k: getattr(run, k) for k in keys}
                done.write_text(json.dumps(record))
            record = json.loads(done.read_text())
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    return DemoRun(out=shared / "demo", **record)
