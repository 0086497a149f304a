"""Exports, checked with the other ecosystems' readers: rosbags' AnyReader for the ROS 2 bag,
the mcap packages for the transform tree, and the exact schema and alignment arithmetic of
rmf_building_map_tools' building loader for the Open-RMF site (that package is a ROS package,
not on PyPI: the checks below follow what its ``Building``/``Level``/``Lift`` classes read)."""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from baromap import messages as m
from baromap.cli.main import main as cli
from baromap.errors import ConfigError
from baromap.mapping.export import read_pgm, write_pgm
from baromap.recording import LaserMount, RecordingWriter, read_messages, read_metadata
from baromap.recording import topics as t
from baromap.sim.record import record_run

#: Seconds to minutes of CPU each: `make test` runs them, `make check` does not.
pytestmark = pytest.mark.slow

T0 = 1_763_700_000_000_000_000
MOUNT = LaserMount(0.12, -0.03, 0.02)


@pytest.fixture(scope="module")
def sim_out(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A short simulated three-floor run and its build-maps directory."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    fig, ax = plt.subplots()  # load matplotlib's fonts before the fd leak guard looks
    ax.set_title("warm-up \u2192")
    fig.savefig(tmp_path_factory.mktemp("fonts") / "warm.png")
    plt.close(fig)
    base = tmp_path_factory.mktemp("sim")
    run = base / "run.mcap"
    record_run(run, seed=1, floors=3, minutes=5.0, progress=False)
    out = base / "out"
    assert cli(["--log-level", "WARNING", "build-maps", str(run), "-o", str(out)]) == 0
    return run, out


# -- ROS 2 ---------------------------------------------------------------------------------


def scan(t_ns: int) -> m.LaserScan:
    ranges = np.linspace(0.5, 7.5, 181).astype(np.float32)
    flags = np.zeros(181, dtype=np.uint16)
    ranges[10], flags[10] = np.nan, m.BeamFlag.OVER_RANGE
    ranges[20], flags[20] = np.nan, m.BeamFlag.DAZZLE
    return m.LaserScan(t_ns, -math.pi / 2, math.radians(1), 8.19, ranges, flags)


def every_message_type(path: Path) -> Counter[str]:
    sent: Counter[str] = Counter()
    with RecordingWriter(path, robot="r", laser_mount=MOUNT) as writer:
        for i in range(30):
            t_ns = T0 + i * 100_000_000
            batch: list[tuple[m.Message, str | None]] = [
                (m.PressureSample(t_ns, 100000.0 + i, 21.5 if i % 2 else None, i, i), None),
                (m.PressureSample(t_ns, 100100.0, 20.0), t.REFERENCE_PRESSURE),
                (scan(t_ns), None),
                (m.Odometry(t_ns, 0.1 * i, 0.0, 0.01 * i, 0.3, 0.1, i, 0, 0), None),
                (m.TruthPose(t_ns, 1.0, 2.0, 0.3, 0, 0.0), None),
                (m.TruthFloor(t_ns, None if i == 5 else 0, 0.0), None),
            ]
            if i % 10 == 0:
                batch += [
                    (
                        m.FloorEvent(
                            t_ns=t_ns,
                            event_id=i // 10 + 1,
                            kind=m.FloorEventKind.TRANSITION,
                            replaces=None,
                            t_start_ns=t_ns - 5,
                            t_end_ns=t_ns - 1,
                            from_id=0,
                            to_id=1,
                            from_name="lobby",
                            to_name="1",
                            height_m=3.3,
                            delta_pa=-40.0,
                            delta_m=3.3,
                            level_pa=99960.0,
                        ),
                        None,
                    ),
                    (
                        m.FloorState(
                            t_ns=t_ns,
                            phase=m.FloorPhase.SETTLED,
                            floor_id=1,
                            name="1",
                            height_m=math.nan,
                            level_m=3.3,
                            level_pa=99960.0,
                            since_ns=t_ns,
                            floors_known=2,
                        ),
                        None,
                    ),
                    (
                        m.DeviceHealth(t_ns, "baro", m.DeviceState.UP, "/dev/x", "", {"crc": 2}),
                        None,
                    ),
                ]
            for message, topic in batch:
                writer.write(message, topic=topic)
        sent.update(writer.counts)
    return sent


def fake_maps_dir(directory: Path) -> None:
    """A build-maps directory as build-maps writes it, plus maps.mcap's map -> odom."""
    import foxglove
    from foxglove.channels import FrameTransformChannel
    from foxglove.messages import FrameTransform, Quaternion, Timestamp, Vector3

    directory.mkdir()
    image = np.full((4, 6), 205, dtype=np.uint8)  # unknown
    image[0, 0] = 0  # top-left pixel occupied
    image[3, 5] = 254  # bottom-right pixel free
    write_pgm(directory / "floor_0.pgm", image)
    meta = {
        "image": "floor_0.pgm",
        "resolution": 0.05,
        "origin": [-1.0, -2.0, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
        "mode": "trinary",
    }
    (directory / "floor_0.yaml").write_text(yaml.safe_dump(meta))
    building = {"floors": [{"index": 0, "elevation_m": 0.0, "map": "floor_0.yaml"}]}
    (directory / "building.yaml").write_text(yaml.safe_dump(building))
    context = foxglove.Context()
    with foxglove.open_mcap(str(directory / "maps.mcap"), context=context):
        channel = FrameTransformChannel("/tf", context=context)
        channel.log(
            FrameTransform(
                timestamp=Timestamp(sec=T0 // 10**9, nsec=0),
                parent_frame_id="map",
                child_frame_id="odom",
                translation=Vector3(x=0.5, y=0.0, z=0.0),
                rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
            ),
            log_time=T0,
        )


def test_ros2_bag_reads_with_rosbags(tmp_path: Path) -> None:
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    run = tmp_path / "run.mcap"
    sent = every_message_type(run)
    fake_maps_dir(tmp_path / "maps")
    bag = tmp_path / "bag"
    assert cli(["export", "ros2", str(run), "-o", str(bag), "--maps", str(tmp_path / "maps")]) == 0

    got: Counter[str] = Counter()
    by_topic: dict[str, list[Any]] = {}
    with AnyReader([bag]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for connection, _, raw in reader.messages():
            msg = reader.deserialize(raw, connection.msgtype)  # every message, every type
            got[connection.topic] += 1
            by_topic.setdefault(connection.topic, []).append(msg)
    with (bag / "bag.mcap").open("rb") as f:
        assert make_reader(f).get_header().profile == "ros2"

    assert types[t.SCAN] == "sensor_msgs/msg/LaserScan"
    assert types[t.ODOM] == "nav_msgs/msg/Odometry"
    assert types[t.TF] == types[t.TF_STATIC] == "tf2_msgs/msg/TFMessage"
    assert types[t.BARO] == "sensor_msgs/msg/FluidPressure"
    assert types["/baro/temperature"] == "sensor_msgs/msg/Temperature"
    assert types[t.FLOOR_EVENT] == types[t.FLOOR_STATE] == "std_msgs/msg/String"
    assert types[t.DIAGNOSTICS] == "diagnostic_msgs/msg/DiagnosticArray"
    assert types["/floor_0/map"] == "nav_msgs/msg/OccupancyGrid"
    for topic in (t.SCAN, t.ODOM, t.BARO, t.REFERENCE_PRESSURE, t.FLOOR_EVENT, t.DIAGNOSTICS):
        assert got[topic] == sent[topic], topic
    assert got["/baro/temperature"] == 15  # only the samples that carried one
    assert got[t.TF] == sent[t.ODOM] + 1  # odom -> base_link each, map -> odom once

    first = by_topic[t.SCAN][0]
    assert first.header.frame_id == "laser"
    assert math.isinf(first.ranges[10]) and math.isnan(first.ranges[20])
    assert first.ranges[0] == pytest.approx(0.5)
    odom = by_topic[t.ODOM][3]
    assert (odom.header.frame_id, odom.child_frame_id) == ("odom", "base_link")
    assert odom.twist.twist.linear.x == pytest.approx(0.3)
    state = yaml.safe_load(by_topic[t.FLOOR_STATE][0].data)  # JSON: null, never NaN
    assert state["height_m"] is None and state["floor_id"] == 1
    assert by_topic[t.DIAGNOSTICS][0].status[0].values[0].key == "crc"
    grid = by_topic["/floor_0/map"][0]
    assert (grid.info.width, grid.info.height) == (6, 4)
    assert grid.info.origin.position.x == pytest.approx(-1.0)
    cells = grid.data.reshape(4, 6)  # rows from the bottom
    assert cells[3, 0] == 100 and cells[0, 5] == 0 and cells[1, 1] == -1
    edges = {
        (tf.header.frame_id, tf.child_frame_id)
        for topic in (t.TF, t.TF_STATIC)
        for msg in by_topic[topic]
        for tf in msg.transforms
    }
    assert edges == {("base_link", "laser"), ("odom", "base_link"), ("map", "odom")}
    static = by_topic[t.TF_STATIC][0].transforms[0].transform
    assert static.translation.x == pytest.approx(MOUNT.x_m)


def test_ros2_export_of_a_rotated_run_is_one_bag(tmp_path: Path) -> None:
    """A run baromapd rotated into two files exports to one bag holding what the run's one
    file gives, whichever order the parts are named in."""
    from baromap.evaluation.recording_cuts import split_like_baromapd
    from baromap.export.ros2 import export_ros2
    from baromap.recording.summary import summarize

    run = tmp_path / "run.mcap"
    every_message_type(run)
    summary = summarize(run)
    assert summary.start_ns is not None and summary.end_ns is not None
    half_s = (summary.end_ns - summary.start_ns) / 2e9
    parts = split_like_baromapd(run, tmp_path / "parts", half_s)
    assert all(summarize(p).message_count > 0 for p in parts)
    whole = export_ros2(run, tmp_path / "whole")
    rotated = export_ros2(parts[::-1], tmp_path / "rotated")
    assert sum(whole.counts.values()) > 20
    assert rotated.counts == whole.counts


def test_ros2_export_refuses_to_overwrite(tmp_path: Path) -> None:
    from baromap.export.ros2 import export_ros2

    run = tmp_path / "run.mcap"
    with RecordingWriter(run, robot="r") as writer:
        writer.write(m.PressureSample(T0, 1.0))
    (tmp_path / "bag").mkdir()
    with pytest.raises(ConfigError):
        export_ros2(run, tmp_path / "bag")


# -- transform tree ------------------------------------------------------------------------


def frame_edges(path: Path) -> set[tuple[str, str]]:
    """(parent, child) of every FrameTransform in a file, decoded by the mcap packages alone."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    edges = set()
    factory = DecoderFactory()
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if schema is not None and schema.name == "foxglove.FrameTransform":
                decode = factory.decoder_for(channel.message_encoding, schema)
                assert decode is not None
                msg = decode(message.data)
                edges.add((msg.parent_frame_id, msg.child_frame_id))
    return edges


def connects(edges: set[tuple[str, str]], child: str, root: str) -> bool:
    parent_of = {c: p for p, c in edges}
    seen = set()
    while child != root and child in parent_of and child not in seen:
        seen.add(child)
        child = parent_of[child]
    return child == root


def test_run_and_maps_transform_tree_joins_laser_to_map(sim_out: tuple[Path, Path]) -> None:
    run, out = sim_out
    run_edges = frame_edges(run)
    assert {("base_link", "laser"), ("odom", "base_link")} <= run_edges
    assert connects(run_edges, "laser", "odom")
    assert LaserMount.from_metadata(read_metadata(run)) is not None
    map_edges = frame_edges(out / "maps.mcap")
    assert ("map", "odom") in map_edges
    assert connects(run_edges | map_edges, "laser", "map")


# -- Open-RMF ------------------------------------------------------------------------------


def rmf_loader_view(site_path: Path) -> dict[str, Any]:
    """What rmf_building_map_tools' loader reads from a reference_image building, checked
    field by field, with each level's pixel -> metre transform as the loader derives it:
    the reference level's scale from its measurements, the others from the fiducials they
    share with it (rotation from bearings, scale from distances, translation from means)."""
    site = yaml.safe_load(site_path.read_text())
    name = site.get("building_name", site.get("name"))
    assert isinstance(name, str) and name
    assert site.get("coordinate_system", "reference_image") == "reference_image"
    levels = site["levels"]
    assert isinstance(levels, dict) and levels
    ref_name = site.get("reference_level_name", next(iter(levels)))

    def flip(p: list[float]) -> np.ndarray:  # reference_image: y down in the file
        return np.array([float(p[0]), -float(p[1])])

    parsed = {}
    for level_name, level in levels.items():
        assert (site_path.parent / level["drawing"]["filename"]).is_file()
        float(level["elevation"])
        fiducials = {}
        for fid in level.get("fiducials", []):
            assert len(fid) == 3 and isinstance(fid[2], str)
            fiducials[fid[2]] = flip(fid)
        vertices = []
        for v in level.get("vertices", []):
            assert len(v) >= 4 and isinstance(v[3], str)
            float(v[2])
            assert all(len(p) == 2 for p in v[4].values()) if len(v) > 4 else True
            vertices.append(flip(v))
        scales = []
        for start, end, params in level.get("measurements", []):
            kind, distance = params["distance"]
            assert kind == 3  # a double
            scales.append(distance / np.linalg.norm(vertices[int(start)] - vertices[int(end)]))
        for key in ("lanes", "walls", "doors"):
            for edge in level.get(key, []):
                int(edge[0]), int(edge[1])
                assert isinstance(edge[2], dict)
        parsed[level_name] = {"fiducials": fiducials, "scales": scales, "level": level}

    ref = parsed[ref_name]
    assert ref["scales"], "the reference level needs a measurement for its scale"
    ref_scale = float(np.mean(ref["scales"]))
    transforms = {ref_name: (0.0, ref_scale, np.zeros(2))}
    for level_name, info in parsed.items():
        if level_name == ref_name:
            continue
        common = [n for n in ref["fiducials"] if n in info["fiducials"]]
        assert len(common) >= 2, f"{level_name} shares {len(common)} fiducials with {ref_name}"
        a = np.array([ref["fiducials"][n] for n in common])
        b = np.array([info["fiducials"][n] for n in common])
        pairs = [(i, j) for i in range(len(common)) for j in range(i + 1, len(common))]
        d_bearing = [
            math.atan2(*(b[j] - b[i])[::-1]) - math.atan2(*(a[j] - a[i])[::-1]) for i, j in pairs
        ]
        rotation = -math.atan2(sum(map(math.sin, d_bearing)), sum(map(math.cos, d_bearing)))
        rel = np.mean([np.linalg.norm(b[j] - b[i]) / np.linalg.norm(a[j] - a[i]) for i, j in pairs])
        c, s = math.cos(rotation), math.sin(rotation)
        rot = np.array([[c, -s], [s, c]])
        moved = [rot @ (bb / rel) - aa for aa, bb in zip(a, b, strict=True)]
        shift = -ref_scale * np.mean(moved, axis=0)
        transforms[level_name] = (rotation, ref_scale / rel, shift)

    def to_metres(level_name: str, pixel: list[float]) -> np.ndarray:
        rotation, scale, shift = transforms[level_name]
        c, s = math.cos(rotation), math.sin(rotation)
        return np.array([[c, -s], [s, c]]) @ flip(pixel) * scale + shift

    lifts = site.get("lifts") or {}
    for lift in lifts.values():
        for key in ("depth", "width", "yaw", "x", "y"):
            float(lift[key])
        for key in ("highest_floor", "lowest_floor", "initial_floor_name", "reference_floor_name"):
            if key in lift:
                assert lift[key] in levels
        doors = lift.get("doors", {})
        for door in doors.values():
            assert door["door_type"]
            for key in ("x", "y", "motion_axis_orientation", "width"):
                float(door[key])
        for level_name, door_names in lift.get("level_doors", {}).items():
            assert level_name in levels and set(door_names) <= set(doors)
    return {"site": site, "ref": ref_name, "to_metres": to_metres, "ref_scale": ref_scale}


def test_rmf_site_loads_with_one_level_per_floor_and_one_lift(
    sim_out: tuple[Path, Path], tmp_path: Path
) -> None:
    from matplotlib import image as mpimg

    from baromap.export.rmf import ride_segments
    from baromap.mapping.export import read_tum

    run, out = sim_out
    site_path = tmp_path / "site" / "demo.building.yaml"
    assert cli(["export", "rmf", str(out / "building.yaml"), "-o", str(site_path)]) == 0
    view = rmf_loader_view(site_path)
    site = view["site"]
    building = yaml.safe_load((out / "building.yaml").read_text())
    floors = [f for f in building["floors"] if f.get("map")]
    assert len(site["levels"]) == len(floors) == 3
    assert len(site["lifts"]) == 1
    for floor in floors:
        level = site["levels"][f"floor_{floor['index']}"]
        assert level["elevation"] == pytest.approx(floor["elevation_m"], abs=1e-3)
        drawing = mpimg.imread(site_path.parent / level["drawing"]["filename"])
        pgm = read_pgm(out / f"floor_{floor['index']}.pgm")
        assert drawing.shape[:2] == pgm.shape  # pixel for pixel
        assert np.allclose(drawing[..., 0] * 255, pgm, atol=1)
    assert view["ref_scale"] == pytest.approx(building["resolution_m"])

    # every level puts the same world point at the same place: the floors stay aligned
    meta = {f["index"]: yaml.safe_load((out / f["map"]).read_text()) for f in floors}
    world = np.array([3.0, -2.0])
    placed = []
    for index, info in meta.items():
        ox, oy = info["origin"][:2]
        height = read_pgm(out / info["image"]).shape[0]
        pixel = [(world[0] - ox) / 0.05, height - (world[1] - oy) / 0.05]
        placed.append(view["to_metres"](f"floor_{index}", pixel))
    assert np.ptp(np.array(placed), axis=0) == pytest.approx([0.0, 0.0], abs=1e-6)

    # the lift stands where the robot rode, and serves the floors it rode between
    lift = next(iter(site["lifts"].values()))
    _, xyz, _ = read_tum(out / "trajectory.tum")
    elevations = np.array([f["elevation_m"] for f in floors])
    rides = ride_segments(xyz[:, 2], elevations)
    assert rides
    ride_xy = np.median(np.concatenate([xyz[a:b, :2] for a, b in rides]), axis=0)
    ref = meta[min(meta)]
    ref_height = read_pgm(out / ref["image"]).shape[0]
    ref_pixel = [
        (ride_xy[0] - ref["origin"][0]) / 0.05,
        ref_height - (ride_xy[1] - ref["origin"][1]) / 0.05,
    ]
    lift_metres = view["to_metres"](view["ref"], [lift["x"], lift["y"]])
    assert np.linalg.norm(lift_metres - view["to_metres"](view["ref"], ref_pixel)) < 1.0
    assert set(lift["level_doors"]) == set(site["levels"])

    # and at the simulator's elevator, seen from the map frame (the robot's start pose)
    sim = read_metadata(run)["baromap.sim"]
    ex, ey = yaml.safe_load(sim["elevator_xy"])
    start = next(iter(read_messages(run, [t.TRUTH_POSE]))).message
    cos, sin = math.cos(start.theta_rad), math.sin(start.theta_rad)
    dx, dy = ex - start.x_m, ey - start.y_m
    elevator_in_map = np.array([cos * dx + sin * dy, -sin * dx + cos * dy])
    assert np.linalg.norm(ride_xy - elevator_in_map) < 1.5
