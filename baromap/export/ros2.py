"""``baromap export ros2``: a recording as a rosbag2 (MCAP storage, ``ros2`` profile, CDR).

Written with ``rosbags`` against the ROS 2 Jazzy message definitions, so ``ros2 bag play``,
rosbags' ``AnyReader``, Foxglove and RViz take it as any other bag. Topics:

========================= =============================== ====================================
recording                 bag topic                       ROS 2 type
========================= =============================== ====================================
``/scan``                 ``/scan``                       ``sensor_msgs/msg/LaserScan``
``/odom``                 ``/odom``, and ``/tf``          ``nav_msgs/msg/Odometry``,
                          (odom -> base_link)             ``tf2_msgs/msg/TFMessage``
laser mount (metadata)    ``/tf_static`` (once, latched)  ``tf2_msgs/msg/TFMessage``
``/baro``                 ``/baro``, ``/baro/temperature`` ``sensor_msgs/msg/FluidPressure``,
                                                          ``sensor_msgs/msg/Temperature``
``/reference/pressure``   same, ``.../temperature``       same
``/floor/event``,         same                            ``std_msgs/msg/String``: the JSON of
``/floor/ride``,
``/floor/state``                                          :mod:`baromap.jsonmsg` (``schema``
                                                          versioned), NaN as null
``/diagnostics``          ``/diagnostics``                ``diagnostic_msgs/msg/DiagnosticArray``
``/truth/pose``           ``/truth/pose``                 ``geometry_msgs/msg/PoseStamped``
                                                          (frame ``truth_world``)
``/truth/floor``          ``/truth/floor``                ``std_msgs/msg/String`` (JSON)
build-maps floor ``k``    ``/floor_<k>/map`` (latched)    ``nav_msgs/msg/OccupancyGrid``
maps.mcap transforms      ``/tf``                         ``tf2_msgs/msg/TFMessage``
========================= =============================== ====================================

Scan ranges follow REP 117: a beam flagged over-range is ``+inf``, any other error ``NaN``;
``intensities`` stay empty (the LMS200 measures none; baromap's per-beam flags have no ROS
field). The P2OS raw counters of ``/odom`` have no ROS field either and are not exported.
Maps are stamped at the start of the run and offered ``transient_local`` like map_server's,
their origin z at the floor's elevation (RViz and Foxglove stack them; Nav2 reads x, y only).
"""

from __future__ import annotations

import itertools
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import structlog

from baromap import jsonmsg, messages
from baromap.building import read_building
from baromap.errors import ConfigError, InputFormatError
from baromap.export.map_yaml import read_yaml_mapping
from baromap.mapping.export import read_pgm
from baromap.mapping.run_data import laser_offset_from_metadata
from baromap.recording import read_messages, read_metadata, topics
from baromap.recording.run_parts import Recording, run_parts

log = structlog.get_logger(__name__)

#: Messages exported as their JSON in a ``std_msgs/msg/String``.
_JSON_AS_STRING = (
    messages.FloorEvent,
    messages.RideEvent,
    messages.FloorState,
    messages.TruthFloor,
)

DISTRO_STORE = "ROS2_JAZZY"
BARO_FRAME = topics.BASE_FRAME  # the barometer rides on the base
REFERENCE_FRAME = "reference_station"
TRUTH_FRAME = "truth_world"

#: DeviceState -> diagnostic_msgs/DiagnosticStatus level (OK, WARN, ERROR, STALE).
DIAGNOSTIC_LEVEL = {
    messages.DeviceState.UP: 0,
    messages.DeviceState.DEGRADED: 1,
    messages.DeviceState.DOWN: 2,
    messages.DeviceState.STARTING: 3,
}


@dataclass(frozen=True, slots=True)
class Ros2Export:
    path: Path
    counts: dict[str, int]  # messages per bag topic
    skipped: dict[str, int]  # recording topics that have no ROS 2 counterpart


class _Bag:
    """The rosbags writer with baromap's message builders around it."""

    def __init__(self, path: Path) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore

        self.store = get_typestore(Stores[DISTRO_STORE])
        self.types = self.store.types
        self.writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        self.connections: dict[str, Any] = {}
        self.counts: Counter[str] = Counter()

    def __enter__(self) -> _Bag:
        self.writer.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.writer.close()

    def write(self, topic: str, msgtype: str, t_ns: int, msg: Any, latched: bool = False) -> None:
        connection = self.connections.get(topic)
        if connection is None:
            qos = [_latched_qos()] if latched else []
            connection = self.writer.add_connection(
                topic, msgtype, typestore=self.store, offered_qos_profiles=qos
            )
            self.connections[topic] = connection
        self.writer.write(connection, t_ns, self.store.serialize_cdr(msg, msgtype))
        self.counts[topic] += 1

    # builders -------------------------------------------------------------------------

    def header(self, t_ns: int, frame: str) -> Any:
        sec, nsec = divmod(t_ns, 1_000_000_000)
        return self.types["std_msgs/msg/Header"](
            stamp=self.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
            frame_id=frame,
        )

    def vector(self, x: float, y: float, z: float) -> Any:
        return self.types["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)

    def quaternion(self, yaw: float) -> Any:
        return self.types["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
        )

    def pose(self, x: float, y: float, z: float, yaw: float) -> Any:
        return self.types["geometry_msgs/msg/Pose"](
            position=self.types["geometry_msgs/msg/Point"](x=x, y=y, z=z),
            orientation=self.quaternion(yaw),
        )

    def transform(
        self, t_ns: int, frames: tuple[str, str], xyz: tuple[float, float, float], q: Any
    ) -> Any:
        """A TransformStamped of ``frames`` = (parent, child)."""
        parent, child = frames
        x, y, z = xyz
        return self.types["geometry_msgs/msg/TransformStamped"](
            header=self.header(t_ns, parent),
            child_frame_id=child,
            transform=self.types["geometry_msgs/msg/Transform"](
                translation=self.vector(x, y, z), rotation=q
            ),
        )

    def tf(self, transforms: list[Any]) -> Any:
        return self.types["tf2_msgs/msg/TFMessage"](transforms=transforms)

    def string(self, text: str) -> Any:
        return self.types["std_msgs/msg/String"](data=text)


def _latched_qos() -> Any:
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    never = QosTime(sec=0, nsec=0)
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=1,
        reliability=QosReliability.RELIABLE,
        durability=QosDurability.TRANSIENT_LOCAL,
        deadline=never,
        lifespan=never,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=never,
        avoid_ros_namespace_conventions=False,
    )


def _scan(bag: _Bag, scan: messages.LaserScan) -> Any:
    ranges = np.array(scan.ranges_m, dtype=np.float32)
    bad = ~scan.valid()
    over = (scan.flags & np.uint16(messages.BeamFlag.OVER_RANGE)) != 0
    ranges[bad] = np.nan
    ranges[over] = np.inf
    return bad, bag.types["sensor_msgs/msg/LaserScan"](
        header=bag.header(scan.t_ns, topics.LASER_FRAME),
        angle_min=scan.angle_min_rad,
        angle_max=scan.angle_max_rad,
        angle_increment=scan.angle_increment_rad,
        time_increment=0.0,
        scan_time=0.0,
        range_min=scan.range_min_m,
        range_max=scan.range_max_m if math.isfinite(scan.range_max_m) else 0.0,
        ranges=ranges,
        intensities=np.zeros(0, dtype=np.float32),
    )


def _odometry(bag: _Bag, odom: messages.Odometry) -> Any:
    t = bag.types
    zeros = np.zeros(36, dtype=np.float64)
    return t["nav_msgs/msg/Odometry"](
        header=bag.header(odom.t_ns, topics.ODOM_FRAME),
        child_frame_id=topics.BASE_FRAME,
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=bag.pose(odom.x_m, odom.y_m, 0.0, odom.theta_rad), covariance=zeros
        ),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](
                linear=bag.vector(odom.v_mps, 0.0, 0.0),
                angular=bag.vector(0.0, 0.0, odom.omega_radps),
            ),
            covariance=zeros.copy(),
        ),
    )


def _pressure(bag: _Bag, topic: str, sample: messages.PressureSample, frame: str) -> None:
    t = bag.types
    bag.write(
        topic,
        "sensor_msgs/msg/FluidPressure",
        sample.t_ns,
        t["sensor_msgs/msg/FluidPressure"](
            header=bag.header(sample.t_ns, frame), fluid_pressure=sample.pressure_pa, variance=0.0
        ),
    )
    if sample.temperature_c is not None:
        bag.write(
            temperature_topic(topic),
            "sensor_msgs/msg/Temperature",
            sample.t_ns,
            t["sensor_msgs/msg/Temperature"](
                header=bag.header(sample.t_ns, frame),
                temperature=sample.temperature_c,
                variance=0.0,
            ),
        )


def temperature_topic(pressure_topic: str) -> str:
    """``/baro`` -> ``/baro/temperature``; ``/reference/pressure`` -> ``/reference/temperature``."""
    if pressure_topic.endswith("/pressure"):
        return pressure_topic.removesuffix("/pressure") + "/temperature"
    return pressure_topic.rstrip("/") + "/temperature"


def _diagnostics(bag: _Bag, health: messages.DeviceHealth) -> Any:
    t = bag.types
    status = t["diagnostic_msgs/msg/DiagnosticStatus"](
        level=DIAGNOSTIC_LEVEL.get(health.state, 3),
        name=health.device,
        message=f"{health.state.value}: {health.detail}" if health.detail else health.state.value,
        hardware_id=health.port,
        values=[
            t["diagnostic_msgs/msg/KeyValue"](key=str(k), value=str(v))
            for k, v in sorted(health.counters.items())
        ],
    )
    return t["diagnostic_msgs/msg/DiagnosticArray"](
        header=bag.header(health.t_ns, ""), status=[status]
    )


def _truth_pose(bag: _Bag, pose: messages.TruthPose) -> Any:
    return bag.types["geometry_msgs/msg/PoseStamped"](
        header=bag.header(pose.t_ns, TRUTH_FRAME),
        pose=bag.pose(pose.x_m, pose.y_m, pose.z_m, pose.theta_rad),
    )


def _json(bag: _Bag, message: Any) -> Any:
    return bag.string(jsonmsg.dumps(message).decode())  # strict JSON: NaN goes out as null


def export_ros2(
    recording: Recording,
    out_dir: str | Path,
    *,
    maps_dir: str | Path | None = None,
    across_runs: bool = False,
) -> Ros2Export:
    """Write ``recording`` (and optionally a build-maps directory's maps) as a rosbag2: every
    file of the run in order (:func:`~baromap.recording.run_parts.run_parts`), one bag."""
    out = Path(out_dir)
    if out.exists():
        raise ConfigError(f"{out} exists: a rosbag2 goes into a new directory")
    parts = run_parts(recording, across_runs=across_runs)
    metadata = read_metadata(parts[0])
    mount = laser_offset_from_metadata(metadata)
    maps = _load_maps(Path(maps_dir)) if maps_dir is not None else []
    map_transforms = _map_transforms(Path(maps_dir)) if maps_dir is not None else []
    map_transforms.sort(key=lambda item: item[0])
    pending_maps = iter(map_transforms)
    next_map = next(pending_maps, None)
    skipped: Counter[str] = Counter()
    started = False
    bad_beams = 0
    by_message: dict[type, Callable[[_Bag, Any], Any]] = {
        messages.DeviceHealth: _diagnostics,
        messages.TruthPose: _truth_pose,
    }
    types = {
        messages.DeviceHealth: "diagnostic_msgs/msg/DiagnosticArray",
        messages.TruthPose: "geometry_msgs/msg/PoseStamped",
    }
    with _Bag(out) as bag:
        for rec in itertools.chain.from_iterable(read_messages(p) for p in parts):
            msg = rec.message
            if not started:
                started = True
                _write_start(bag, rec.log_time_ns, mount, maps)
            while next_map is not None and next_map[0] <= rec.log_time_ns:
                _write_map_transform(bag, *next_map)
                next_map = next(pending_maps, None)
            if isinstance(msg, messages.LaserScan):
                bad, ros = _scan(bag, msg)
                bad_beams += int(bad.sum())
                bag.write(rec.topic, "sensor_msgs/msg/LaserScan", msg.t_ns, ros)
            elif isinstance(msg, messages.Odometry):
                bag.write(rec.topic, "nav_msgs/msg/Odometry", msg.t_ns, _odometry(bag, msg))
                if rec.topic == topics.ODOM:
                    tf = bag.transform(
                        msg.t_ns,
                        (topics.ODOM_FRAME, topics.BASE_FRAME),
                        (msg.x_m, msg.y_m, 0.0),
                        bag.quaternion(msg.theta_rad),
                    )
                    bag.write(topics.TF, "tf2_msgs/msg/TFMessage", msg.t_ns, bag.tf([tf]))
            elif isinstance(msg, messages.PressureSample):
                frame = BARO_FRAME if rec.topic == topics.BARO else REFERENCE_FRAME
                _pressure(bag, rec.topic, msg, frame)
            elif isinstance(msg, _JSON_AS_STRING):
                bag.write(rec.topic, "std_msgs/msg/String", msg.t_ns, _json(bag, msg))
            elif type(msg) in by_message:
                bag.write(rec.topic, types[type(msg)], msg.t_ns, by_message[type(msg)](bag, msg))
            elif rec.topic in (topics.TF, topics.TF_STATIC):
                pass  # rebuilt above from /odom and the mount
            else:
                skipped[rec.topic] += 1
        if not started:
            raise InputFormatError(f"{', '.join(map(str, parts))}: no messages")
        while next_map is not None:
            _write_map_transform(bag, *next_map)
            next_map = next(pending_maps, None)
        counts = dict(bag.counts)
    log.info("ros2 bag written", path=str(out), topics=counts, skipped=dict(skipped))
    return Ros2Export(out, counts, dict(skipped))


def _write_map_transform(bag: _Bag, t_ns: int, tf: tuple[Any, ...]) -> None:
    q = bag.types["geometry_msgs/msg/Quaternion"](**tf[5])
    msg = bag.transform(t_ns, (tf[0], tf[1]), (tf[2], tf[3], tf[4]), q)
    bag.write(topics.TF, "tf2_msgs/msg/TFMessage", t_ns, bag.tf([msg]))


def _write_start(
    bag: _Bag, t_ns: int, mount: npt.NDArray[np.float64], maps: list[tuple[int, dict[str, Any]]]
) -> None:
    """What a player needs from the first instant: the laser mount and the maps, latched."""
    x, y, yaw = (float(v) for v in mount)
    static = bag.transform(
        t_ns, (topics.BASE_FRAME, topics.LASER_FRAME), (x, y, 0.0), bag.quaternion(yaw)
    )
    bag.write(topics.TF_STATIC, "tf2_msgs/msg/TFMessage", t_ns, bag.tf([static]), latched=True)
    for index, grid in maps:
        msg = bag.types["nav_msgs/msg/OccupancyGrid"](
            header=bag.header(t_ns, topics.MAP_FRAME),
            info=bag.types["nav_msgs/msg/MapMetaData"](
                map_load_time=bag.header(t_ns, "").stamp,
                resolution=grid["resolution"],
                width=grid["width"],
                height=grid["height"],
                origin=bag.pose(*grid["origin"]),
            ),
            data=grid["data"],
        )
        bag.write(f"/floor_{index}/map", "nav_msgs/msg/OccupancyGrid", t_ns, msg, latched=True)


def _load_maps(directory: Path) -> list[tuple[int, dict[str, Any]]]:
    """The floors of a build-maps directory as OccupancyGrid fields (map_server's reading)."""
    building = read_building(directory / "building.yaml")
    out = []
    for index, map_file, floor in building.floor_maps():
        meta = read_yaml_mapping(directory / map_file)
        elevation = floor.elevation_m
        try:
            resolution = float(meta["resolution"])
            ox, oy, oyaw = (float(v) for v in meta["origin"])
            occupied, free = float(meta["occupied_thresh"]), float(meta["free_thresh"])
            negate = int(meta.get("negate", 0))
            image_name = str(meta["image"])
        except (KeyError, TypeError, ValueError) as exc:
            raise InputFormatError(f"{directory}: map of floor {index}: {exc}") from exc
        image = read_pgm(directory / image_name)
        out.append(
            (
                index,
                {
                    "resolution": resolution,
                    "width": int(image.shape[1]),
                    "height": int(image.shape[0]),
                    "origin": (ox, oy, elevation, oyaw),
                    "data": occupancy_from_image(image, occupied, free, negate),
                },
            )
        )
    if not out:
        raise InputFormatError(f"{directory}/building.yaml lists no floor maps")
    return out


def occupancy_from_image(
    image: npt.NDArray[np.uint8], occupied_thresh: float, free_thresh: float, negate: int = 0
) -> npt.NDArray[np.int8]:
    """map_server's trinary reading of a map image, rows from the bottom (OccupancyGrid order)."""
    value = image.astype(np.float64) / 255.0
    occ = value if negate else 1.0 - value
    data = np.full(image.shape, -1, dtype=np.int8)
    data[occ > occupied_thresh] = 100
    data[occ < free_thresh] = 0
    flipped: npt.NDArray[np.int8] = np.ascontiguousarray(data[::-1]).ravel()
    return flipped


def _map_transforms(directory: Path) -> list[tuple[int, tuple[Any, ...]]]:
    """FrameTransforms that maps.mcap carries (the SLAM's map -> odom), if any."""
    maps = directory / "maps.mcap"
    if not maps.exists():
        return []
    out = []
    for rec in read_messages(maps):
        msg = rec.message
        if type(msg).__name__ != "FrameTransform":
            continue
        q = msg.rotation
        out.append(
            (
                rec.log_time_ns,
                (
                    msg.parent_frame_id,
                    msg.child_frame_id,
                    msg.translation.x,
                    msg.translation.y,
                    msg.translation.z,
                    {"x": q.x, "y": q.y, "z": q.z, "w": q.w},
                ),
            )
        )
    return out
