"""Suite-wide fixtures: hardware ports and a guard against leaked threads and fds.

The hardware options themselves are declared by the ``pytest_baromap`` plugin (repository root).
"""

from __future__ import annotations

import os
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import settings

REPO = Path(__file__).resolve().parent.parent

# Hypothesis' per-example deadline is a timing assertion: on a loaded CI machine it fails
# tests whose behaviour is right. Speed is measured by the scripts in bench/, not here.
settings.register_profile("baromap", deadline=None)
settings.load_profile("baromap")


def find_shared_data() -> Path | None:
    """The evaluation data (docs/contributing.md), wherever this checkout was cloned to.

    Looked up in $BAROMAP_SHARED_DATA, next to this checkout, then next to the repository it
    was cloned from (a CI clone in a scratch directory still tests against the real data).
    """
    candidates = []
    if os.environ.get("BAROMAP_SHARED_DATA"):
        candidates.append(Path(os.environ["BAROMAP_SHARED_DATA"]))
    candidates.append(REPO.parent / "shared" / "data")
    origin = subprocess.run(
        ["git", "-C", str(REPO), "config", "--get", "remote.origin.url"],
        capture_output=True,
        text=True,
        check=False,
    ).stdout.strip()
    if origin.startswith(("/", "file://")):
        candidates.append(Path(origin.removeprefix("file://")).resolve().parent / "shared" / "data")
    return next((c for c in candidates if c.is_dir()), None)


SHARED_DATA = find_shared_data()


#: Files libraries keep open on purpose for the life of the process (caches, not leaks).
PROCESS_CACHES = ("/matplotlib/mpl-data/fonts/",)


def _open_fds() -> set[int]:
    fds = set()
    for name in os.listdir("/proc/self/fd"):
        fd = int(name)
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue  # the fd listdir itself used, already closed
        if any(cache in target for cache in PROCESS_CACHES):
            continue
        if (
            target.startswith("/dev/pts/")
            or target == "/dev/ptmx"
            or not target.startswith(("anon_inode:", "/proc/"))
        ):
            fds.add(fd)
    return fds


@pytest.fixture(autouse=True)
def no_leaks(request: pytest.FixtureRequest) -> Iterator[None]:
    """Fail a test that leaves threads running or file descriptors (ptys included) open.

    A short grace period lets threads that were told to stop finish joining.
    """
    if request.node.get_closest_marker("allow_leaks"):
        yield
        return
    threads_before = set(threading.enumerate())
    fds_before = _open_fds()
    yield
    deadline = time.monotonic() + 2.0
    while True:
        threads = [t for t in threading.enumerate() if t not in threads_before and t.is_alive()]
        fds = _open_fds() - fds_before
        if (not threads and not fds) or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    problems = []
    if threads:
        problems.append("threads still running: " + ", ".join(t.name for t in threads))
    if fds:
        targets = []
        for fd in sorted(fds):
            try:
                targets.append(f"{fd}->{os.readlink(f'/proc/self/fd/{fd}')}")
            except OSError:
                targets.append(str(fd))
        problems.append("fds left open: " + ", ".join(targets))
    if problems:
        pytest.fail("; ".join(problems), pytrace=False)


@pytest.fixture
def shared_data() -> Path:
    if SHARED_DATA is None:
        pytest.skip("shared data not found: set BAROMAP_SHARED_DATA to the shared/data folder")
    return SHARED_DATA
