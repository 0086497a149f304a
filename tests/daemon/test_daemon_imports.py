"""The daemon starts without what it never uses: the recording reader, YAML, batch detection.

Each costs CPU at every start (``python -X importtime -c "import daemon.main"``); the packages
that hold them load them on first use, so their names must still work from outside.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

NOT_AT_START = (
    "baromap.recording.reader",
    "mcap",
    "mcap_protobuf",
    "yaml",
    "baromap.floors.detection",
)


def test_the_daemon_imports_no_reader_yaml_or_batch_detection() -> None:
    code = (
        f"import sys, daemon.main; print(','.join(m for m in {NOT_AT_START!r} if m in sys.modules))"
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
