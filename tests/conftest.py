"""Suite-wide fixtures: hardware ports, a guard against leaked threads and fds, and the split
between the fast inner loop (``make check``) and the whole suite (``make test``).

The hardware options themselves are declared by the ``pytest_baromap`` plugin (repository root).
"""

from __future__ import annotations

import os
import resource
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import structlog
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


#: Folders whose tests start real processes, pseudo-terminals, simulators or networks: slow by
#: nature, so ``make check`` (``-m "not slow"``) leaves them to ``make test``. A test elsewhere
#: that takes more than a few seconds of CPU carries ``@pytest.mark.slow`` itself.
INTEGRATION_DIRS = ("daemon", "e2e", "firmware", "hardware", "live", "liveview")


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """With ``-m "not slow"`` the integration folders are not even imported (their modules
    load the daemon, the twins and Zenoh: seconds of the inner loop's minute)."""
    if config.getoption("markexpr") != "not slow":
        return None
    tests_dir = Path(__file__).resolve().parent
    if collection_path.parent == tests_dir and collection_path.name in INTEGRATION_DIRS:
        return True
    return None


# Before pytest-xdist's own hook, which reads the groups marked here into the node ids it
# schedules by: after it, the groups are marked too late and every test is scheduled alone.
@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    tests_dir = Path(__file__).resolve().parent
    for item in items:
        relative = item.path.resolve().relative_to(tests_dir)
        if len(relative.parts) > 1 and relative.parts[0] in INTEGRATION_DIRS:
            item.add_marker(pytest.mark.slow)
        group = _shared_fixture_group(item, tests_dir)
        if group:
            item.add_marker(pytest.mark.xdist_group(group))


def _shared_fixture_group(item: pytest.Item, tests_dir: Path) -> str | None:
    """The pytest-xdist group that keeps a test with the others sharing its costly fixtures.

    A fixture of the suite's own made once per session or package (the demo's run, the
    firmware's build) puts every test using it on one worker: the other worker goes on with
    the rest instead of waiting on the same lock or building the same thing again. One made
    once per module keeps only that module's tests together.
    """
    fixture_info = getattr(item, "_fixtureinfo", None)
    if fixture_info is None:
        return None
    module_scoped = False
    for definitions in fixture_info.name2fixturedefs.values():
        for definition in definitions:
            if not definition.baseid:  # a plugin's, not the suite's
                continue
            if definition.scope in ("session", "package"):
                return f"shared:{definition.baseid.split('::')[0]}"
            module_scoped = module_scoped or definition.scope == "module"
    return str(item.path.resolve().relative_to(tests_dir)) if module_scoped else None


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


@pytest.fixture(autouse=True)
def default_logging() -> Iterator[None]:
    """Each test starts from structlog's defaults (every level reaches ``capture_logs``).

    An entry point called by an earlier test on the same worker configures an INFO filter; a
    test reading debug events would then pass or fail by the order tests ran in.
    """
    structlog.reset_defaults()
    yield
    structlog.reset_defaults()


#: Where each test's cost is appended when set: ``BAROMAP_TEST_COST=cost.tsv make test`` (then
#: ``sort -t$'\t' -k2 -rn cost.tsv | head``): test, CPU s, wall s, the worker and the time it
#: started (Unix s), which show where a worker waited. CPU seconds are the worker's and its
#: children's, so they hold on a loaded machine, where wall times do not. The pytest runs a
#: test starts (tests/hardware/test_hil_on_twins.py) inherit the variable and append their
#: tests too.
COST_FILE = os.environ.get("BAROMAP_TEST_COST")


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[object]:
    if not COST_FILE:
        return (yield)

    def cpu() -> float:
        own, kids = (
            resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
        )
        return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime

    cpu0, wall0, started = cpu(), time.monotonic(), time.time()
    result = yield
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    with open(COST_FILE, "a") as out:
        out.write(
            f"{item.nodeid}\t{cpu() - cpu0:.2f}\t{time.monotonic() - wall0:.2f}\t{worker}"
            f"\t{started:.1f}\n"
        )
    return result
