"""The shipped Foxglove layout is the one the code makes, and names only channels the live
view serves."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from baromap.liveview.channels import LIVE_MAP, LIVE_MAP_INFO, LIVE_PATH
from baromap.liveview.layout import live_layout_json
from baromap.recording import topics
from baromap.recording.writer import DEFAULT_TOPICS

LAYOUT = Path(__file__).resolve().parents[2] / "layouts" / "live-view.json"
SERVED = {
    *DEFAULT_TOPICS.values(),
    topics.TF,
    topics.TF_STATIC,
    LIVE_MAP,
    LIVE_PATH,
    LIVE_MAP_INFO,
}


def _topics(node: Any) -> set[str]:
    """Every topic a layout refers to: keys of 3D panels' ``topics``, and topic paths."""
    found: set[str] = set()
    if isinstance(node, dict):
        for key, value in node.items():
            if key == "topics" and isinstance(value, dict):
                found |= set(value)
            elif key in ("topicPath", "value") and isinstance(value, str):
                found.add(value.split(".")[0])
            else:
                found |= _topics(value)
    elif isinstance(node, list):
        for item in node:
            found |= _topics(item)
    return found


def test_the_shipped_layout_is_the_one_the_code_makes() -> None:
    assert LAYOUT.read_text(encoding="utf-8") == live_layout_json(), (
        "regenerate: python -c 'from baromap.liveview.layout import live_layout_json; "
        'open("layouts/live-view.json", "w").write(live_layout_json())\''
    )


def test_the_layout_shows_the_scan_map_path_pressure_floor_and_diagnostics() -> None:
    used = _topics(json.loads(LAYOUT.read_text(encoding="utf-8")))
    assert used == {
        topics.SCAN,
        LIVE_MAP,
        LIVE_PATH,
        topics.BARO,
        topics.FLOOR_STATE,
        LIVE_MAP_INFO,
        topics.DIAGNOSTICS,
    }
    assert used <= SERVED
