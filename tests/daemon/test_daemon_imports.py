"""The daemon starts without what it never uses: the recording reader, YAML, batch detection,
the live view's own process.

Each costs CPU at every start (``python -X importtime -c "import baromapd.main"``); the packages
that hold them load them on first use, so their names must still work from outside.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

NOT_AT_START = (
    "baromap.recording.reader",
    "mcap",
    "mcap_protobuf",
    "yaml",
    "baromap.floors.detection",
    # the live view's server, front and map run in a process of their own
    "baromapd.liveview_child",
    "websockets",
    "scipy",
)


def test_the_daemon_imports_no_reader_yaml_or_batch_detection() -> None:
    code = (
        "import sys, baromapd.main; "
        f"print(','.join(m for m in {NOT_AT_START!r} if m in sys.modules))"
    )
    loaded = subprocess.run(
        [sys.executable, "-c", code], check=True, capture_output=True, text=True
    ).stdout.strip()
    assert loaded == ""


def test_lazy_names_still_resolve() -> None:
    import baromap.floors
    import baromap.recording
    from baromap.floors import detection
    from baromap.recording import reader

    assert baromap.recording.read_messages is reader.read_messages
    assert baromap.floors.detect_floors is detection.detect_floors
    with pytest.raises(AttributeError):
        _ = baromap.recording.no_such_name  # type: ignore[attr-defined]
    with pytest.raises(AttributeError):
        _ = baromap.floors.no_such_name  # type: ignore[attr-defined]


def test_the_import_package_is_baromapd_not_daemon(tmp_path: Path) -> None:
    """python-daemon installs a top-level ``daemon``; ours must not shadow it (or be it)."""
    probe = (
        "import importlib.util, baromapd; "
        "spec = importlib.util.find_spec('daemon'); "
        "print(baromapd.__file__); "
        "where = [] if spec is None else [spec.origin, *(spec.submodule_search_locations or [])]; "
        "print(*(w for w in where if w))"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe], check=True, capture_output=True, text=True, cwd=tmp_path
    ).stdout.splitlines()
    repo = Path(__file__).resolve().parents[2]
    assert Path(out[0]).resolve().is_relative_to(repo / "daemon" / "baromapd")
    assert not any(word and Path(word).resolve().is_relative_to(repo) for word in out[1].split())
