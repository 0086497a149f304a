"""docs/zenoh.md, "Applying corrections": its consumer code and its table are what the detector
really does. The code block is run on the run the section describes, its table is compared
with the events that run published."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

from baromap import jsonmsg
from baromap.evaluation.floor_traces import TRACE_EPOCH_NS, Stay, trace
from baromap.floors import FloorDetectorConfig, apply_corrections
from baromap.floors.online import OnlineFloorDetector
from baromap.floors.replay import replay
from baromap.messages import FloorEventKind

DOC = Path(__file__).resolve().parent.parent.parent / "docs" / "zenoh.md"
STOREY_M = 3.2


def _section() -> str:
    text = DOC.read_text()
    start = text.index("## Applying corrections")
    return text[start : text.index("\n## ", start + 1)]


def _described_run() -> OnlineFloorDetector:
    """Two storeys up and back, then up again with a 5 s pause one storey up, visits after 3 s."""
    tr = trace(
        [
            Stay(0.0, 60),
            Stay(2 * STOREY_M, 60, drive_m=3.0),
            Stay(0.0, 60, drive_m=3.0),
            Stay(STOREY_M, 5.0),
            Stay(2 * STOREY_M + 0.4, 60, drive_m=3.0),
        ]
    )
    config = FloorDetectorConfig(min_visit_s=3.0)
    detector, _, _ = replay(tr.t_ns, tr.pressure_pa, tr.temperature_c, config, odometry=None)
    return detector


def test_the_documented_consumer_holds_what_apply_corrections_gives() -> None:
    code = re.search(r"corrections example: begin -->\s*```python\n(.*?)```", _section(), re.S)
    assert code is not None
    detector = _described_run()
    assert any(e.kind is FloorEventKind.CORRECTION for e in detector.events)
    namespace: dict[str, Any] = {}
    exec(compile(code.group(1), str(DOC), "exec"), namespace)
    for event in detector.events:
        namespace["on_floor_event"](jsonmsg.dumps(event))
    expected = [json.loads(jsonmsg.dumps(e)) for e in apply_corrections(detector.events)]
    assert namespace["transitions"] == expected
    # a correction of an event never seen is refused, not guessed around
    fresh: dict[str, Any] = {}
    exec(compile(code.group(1), str(DOC), "exec"), fresh)
    correction = next(e for e in detector.events if e.kind is FloorEventKind.CORRECTION)
    with pytest.raises(KeyError):
        fresh["on_floor_event"](jsonmsg.dumps(correction))


def test_the_documented_table_is_what_that_run_published() -> None:
    detector = _described_run()
    rows = [
        [cell.strip().strip("`") for cell in line.strip("|").split("|")]
        for line in _section().splitlines()
        if re.match(r"\| \d+ \|", line)
    ]
    assert len(rows) == len(detector.events)

    def secs(t_ns: int) -> str:
        return f"{(t_ns - TRACE_EPOCH_NS) / 1e9:.1f}"

    for row, e in zip(rows, detector.events, strict=True):
        assert row[0] == str(e.event_id)
        assert row[1] == e.kind.value
        assert row[2] == ("null" if e.replaces is None else str(e.replaces))
        assert row[3].replace("`", "") == f"{e.from_id} -> {e.to_id}"
        assert row[4].replace("`", "") == f"{e.from_name} -> {e.to_name}"
        assert row[5] == f"{e.height_m:.2f}"
        assert row[6] == f"{secs(e.t_start_ns)} .. {secs(e.t_end_ns)}"
        assert row[7] == secs(e.t_ns)
    assert detector.state().floors_known == 2
