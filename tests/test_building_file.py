"""building.yaml: one typed schema for the file build-maps writes and everything that reads it."""

from __future__ import annotations

from pathlib import Path

import pytest

from baromap.building import (
    Building,
    BuildingFloor,
    BuildingRide,
    LoopClosures,
    read_building,
    write_building,
)
from baromap.errors import InputFormatError
from baromap.floors import load_building_model
from baromap.floors.names import counted_name, names_by_height


def _written(tmp_path: Path) -> Path:
    building = Building(
        source="run.mcap",
        frame="one frame for all floors",
        resolution_m=0.05,
        segmentation="barometer (online)",
        floors=[
            BuildingFloor(index=0, name="0", live_name="-1", elevation_m=0.0, visits=1),
            BuildingFloor(
                index=1, name="1", elevation_m=5.59, visits=2, map="floor_1.yaml", image="f.pgm"
            ),
        ],
        rides=[BuildingRide(10, 20, 1, 0)],
        loop_closures=LoopClosures(within_floors=3, cross_floor=0, elevator_car=1),
        untied=[],
        keyframes=10,
        scans=100,
    )
    path = tmp_path / "building.yaml"
    write_building(path, building)
    return path


def test_what_is_written_reads_back_the_same(tmp_path: Path) -> None:
    path = _written(tmp_path)
    building = read_building(path)
    assert building == Building(**{f: getattr(building, f) for f in building.__struct_fields__})
    assert [f.label(k) for k, f in enumerate(building.floors)] == ["0", "1"]
    assert building.floors[0].live_name == "-1" and building.floors[1].live_name is None
    assert [(index, name) for index, name, _ in building.floor_maps()] == [(1, "floor_1.yaml")]
    text = path.read_text()
    assert "parts" not in text and "mean_pressure_pa" not in text  # absent, not null
    assert "untied: []" in text
    assert text.index("source") < text.index("floors") < text.index("rides")


def test_a_file_written_by_hand_needs_only_elevations(tmp_path: Path) -> None:
    path = tmp_path / "plans.yaml"
    path.write_text(
        "floors:\n- {elevation_m: 0}\n- {elevation_m: 4.2, name: M}\n- {elevation_m: 8}\n"
    )
    model = load_building_model(path)
    assert [(f.name, f.elevation_m) for f in model.floors] == [("0", 0.0), ("M", 4.2), ("2", 8.0)]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("floors:\n- {elevation_m: high}\n", "$.floors[0].elevation_m"),
        ("floors:\n- {index: 0}\n", "elevation_m"),
        ("floors: []\n", "no floors"),
        ("rides: []\n", "floors"),
        ("- just\n- a list\n", "Expected `object`"),
        ("floors: [\n", "not YAML"),
    ],
)
def test_a_file_that_does_not_fit_is_refused_naming_what(
    tmp_path: Path, text: str, message: str
) -> None:
    path = tmp_path / "building.yaml"
    path.write_text(text)
    with pytest.raises(InputFormatError) as error:
        read_building(path)
    assert str(path) in str(error.value) and message in str(error.value)
    with pytest.raises(InputFormatError):
        read_building(tmp_path / "missing.yaml")


def test_floors_are_named_in_order_of_height_from_the_start_floor() -> None:
    assert names_by_height(3, 1, "1") == ["0", "1", "2"]
    assert names_by_height(4, 0, "5") == ["5", "6", "7", "8"]
    assert names_by_height(3, 1, "G") == ["G-1", "G", "G+1"]
    assert counted_name("-1", -2) == "-3"


def test_the_demos_summary_shows_each_floors_name_and_live_name(tmp_path: Path) -> None:
    from baromap.cli.demo_summary import summary_lines

    building = read_building(_written(tmp_path))
    lines = summary_lines(
        out=tmp_path,
        recording=tmp_path / "run.mcap",
        building=building,
        events=[],
        t0_ns=0,
        post_run_transitions=0,
        truth=None,
        files=[],
    )
    floors = [line for line in lines if line.startswith("  floor ")]
    assert len(floors) == 2
    assert "name   0  live name  -1" in floors[0]  # named by height, the live name beside it
    assert "name   1  live name   1" in floors[1]  # the same where they agree


def test_floors_get_the_names_the_daemon_published_not_the_replays() -> None:
    """A floor of the replay is named as the live account named the robot's floor during its
    stays: the daemon's configured names, a correction applied, a lost stream none."""
    from baromap.floors.detection import Segment
    from baromap.mapping.live_names import live_floor_names
    from baromap.messages import FloorEvent, FloorEventKind

    def event(event_id: int, t: int, to: str, replaces: int | None = None) -> FloorEvent:
        kind = FloorEventKind.TRANSITION if replaces is None else FloorEventKind.CORRECTION
        return FloorEvent(
            t + 1, event_id, kind, replaces, t - 5, t, 0, 1, "1", to, 6.0, -70.0, 6.0, 1e5
        )

    # the replay's floor 1 is the start (named "1" live), floor 2 its upper neighbour, which
    # the live account first took for "3" and corrected to "2"; floor 0 below
    segments = [Segment(0, 90, 1), Segment(110, 190, 2), Segment(210, 290, 0), Segment(310, 400, 1)]
    events = [
        event(1, 100, "3"),
        event(2, 150, "2", replaces=1),
        FloorEvent(
            201,
            3,
            FloorEventKind.TRANSITION,
            None,
            195,
            200,
            1,
            2,
            "2",
            "0",
            -5.5,
            65.0,
            -11.5,
            1e5,
        ),
        FloorEvent(
            301, 4, FloorEventKind.TRANSITION, None, 295, 300, 2, 0, "0", "1", 0.0, -65.0, 5.5, 1e5
        ),
    ]
    assert live_floor_names(events, segments) == {1: "1", 2: "2", 0: "0"}
    assert live_floor_names([], segments) == {}
    assert live_floor_names(events[1:], segments) == {}  # a correction of an event never seen
