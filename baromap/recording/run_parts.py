"""The files of one run, in order.

baromapd rotates a run's recording by size and by the hour (``[recording] rotate_size_mb``,
``rotate_minutes``): a run of two hours is two files or more, ``RUN_000.mcap``,
``RUN_001.mcap``, ... Each starts with the ``baromap`` header, which names the run (``run``)
and the file's place in it (``part``). Whatever reads a run reads all of its parts, in that
order. Files of different runs are refused unless asked for (``across_runs``): a daemon
restarted during one exploration starts a new run, and its runs belong together, but two
runs of different days do not, and a directory of the daemon's holds them all.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from pathlib import Path

import structlog

from baromap.errors import ConfigError
from baromap.recording import topics
from baromap.recording.reader import read_metadata
from baromap.recording.summary import summarize

log = structlog.get_logger(__name__)

#: Runs further apart than this are said in the log when taken as one exploration.
FAR_APART_NS = 30 * 60 * 1_000_000_000

#: What names a run's recording: one file, a directory holding its files, or its files.
Recording = str | Path | Sequence[str | Path]


def run_parts(recording: Recording, *, across_runs: bool = False) -> tuple[Path, ...]:
    """The files ``recording`` names, in the order they were recorded. A directory stands
    for the ``.mcap`` files in it.

    The files of one run are ordered by the ``part`` their headers name (as given where a
    file has none); a part missing between two others is said in the log (its stretch of
    the run is a silence of every device). With ``across_runs``, files of several runs of
    one robot are taken too, ordered by their first message; they must not overlap in time.

    Raises :class:`ConfigError` for no file, the same part twice, files of different runs
    (without ``across_runs``), of different robots, or overlapping in time."""
    given = [recording] if isinstance(recording, str | Path) else list(recording)
    files: list[Path] = []
    for item in given:
        path = Path(item)
        files += sorted(path.glob("*.mcap")) if path.is_dir() else [path]
    if not files:
        raise ConfigError(f"no recording in {', '.join(str(g) for g in given) or 'nothing'}")
    if len(files) == 1:
        return (files[0],)
    headers = [read_metadata(f).get(topics.METADATA_NAME, {}) for f in files]
    robots = {h.get("robot") for h in headers}
    if len(robots) > 1:
        named = _listing(files, headers, "robot")
        raise ConfigError(f"these files are of different robots: {named}")
    runs = {h.get("run") for h in headers}
    if len(runs) > 1:
        if not across_runs:
            raise ConfigError(
                f"these files are of different runs: {_listing(files, headers, 'run')} "
                "(runs of one exploration, the daemon restarted in between: --across-runs)"
            )
        return _in_time_order(files)
    parts = [h.get("part") for h in headers]
    if any(p is None or not p.isdigit() for p in parts):
        return tuple(files)  # not rotated by baromapd: the order given
    numbers = [int(p) for p in parts if p is not None]
    if len(set(numbers)) != len(numbers):
        raise ConfigError(f"a part of run {runs.pop()} is given twice: {[str(f) for f in files]}")
    order = sorted(range(len(files)), key=numbers.__getitem__)
    missing = sorted(set(range(min(numbers), max(numbers) + 1)) - set(numbers))
    if missing:
        log.warning("parts of the run are missing", run=runs.pop(), missing=missing)
    return tuple(files[i] for i in order)


def _listing(files: list[Path], headers: list[dict[str, str]], key: str) -> str:
    return ", ".join(
        f"{f.name} ({h.get(key, 'none named')})" for f, h in zip(files, headers, strict=True)
    )


def _in_time_order(files: list[Path]) -> tuple[Path, ...]:
    """Files of several runs by their first message, refusing any two that overlap."""
    spans = []
    for f in files:
        summary = summarize(f)
        if summary.start_ns is None or summary.end_ns is None:
            raise ConfigError(f"{f} holds no message")
        spans.append((summary.start_ns, summary.end_ns, f))
    spans.sort(key=lambda s: s[0])
    for (_, end, a), (start, _, b) in itertools.pairwise(spans):
        if start < end:
            raise ConfigError(f"{a.name} and {b.name} overlap in time: not one robot's runs")
        if start - end > FAR_APART_NS:
            # a restart takes seconds to minutes; hours apart is more likely another day
            log.warning(
                "runs far apart: are they one exploration?",
                before=a.name,
                after=b.name,
                apart_min=round((start - end) / 60e9, 1),
            )
    return tuple(f for _, _, f in spans)
