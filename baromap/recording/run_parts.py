"""The files of one run, in order.

baromapd rotates a run's recording by size and by the hour (``[recording] rotate_size_mb``,
``rotate_minutes``): a run of two hours is two files or more, ``RUN_000.mcap``,
``RUN_001.mcap``, ... Each starts with the ``baromap`` header, which names the run (``run``)
and the file's place in it (``part``). Whatever reads a run reads all of its parts, in that
order; files of different runs are refused, since their frames and clocks have nothing in
common.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import structlog

from baromap.errors import ConfigError
from baromap.recording import topics
from baromap.recording.reader import read_metadata

log = structlog.get_logger(__name__)

#: What names a run's recording: one file, a directory holding its files, or its files.
Recording = str | Path | Sequence[str | Path]


def run_parts(recording: Recording) -> tuple[Path, ...]:
    """The files of the run ``recording`` names, in the order of their ``part`` (as given
    where a file has none). A directory stands for the ``.mcap`` files in it.

    Raises :class:`ConfigError` for no file, or for files of different runs or the same part
    twice; a part missing between two others is said in the log (its stretch of the run is
    a silence of every device)."""
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
    runs = {h.get("run") for h in headers}
    if len(runs) > 1:
        named = ", ".join(
            f"{f.name} ({h.get('run', 'no run named')})"
            for f, h in zip(files, headers, strict=True)
        )
        raise ConfigError(f"these files are of different runs: {named}")
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
