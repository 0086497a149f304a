"""A device silent for a while: how the post-run maps cope with what the daemon's reconnects
leave in a recording.

The daemon closes a device that stops, marks it down and opens it again (docs/daemon.md), so
a recording can hold a stretch without scans while the robot drives on, or scans without
odometry. :func:`silenced` writes a copy of a simulated recording with topics left out for a
while; :func:`score_silence` maps it and scores it against the simulator's truth, over every
scan and over the scans the odometry spoke for (the others are not mapped: see
:func:`baromap.mapping.slam.run_slam`'s ``blind``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory

from baromap.arrays import FloatArray
from baromap.evaluation.mapping import evaluate_recording, truth_at
from baromap.evaluation.recording_cuts import start_copy
from baromap.evaluation.trajectory import fit_rigid
from baromap.mapping import se2
from baromap.mapping.build import build_maps
from baromap.messages import NS_PER_S
from baromap.recording import read_messages, topics

#: What a base's odometry does after a silence (:class:`Silence`'s ``counters``).
COUNTERS = ("kept", "zeroed", "joined")


@dataclass(frozen=True, slots=True)
class Silence:
    """No ``topic`` message from ``start_s`` to ``end_s`` after the recording's first message
    (the device unplugged, power-cycled).

    ``counters`` (``/odom`` only), the odometry after the silence: ``kept`` as it was (the
    base kept counting); ``zeroed``, from zero in a frame of its own (a power-cycled base
    under a recorder that does not join its tracks); ``joined``, that frame joined at the
    last pose before the silence (what baromapd records of a power-cycled base). ``/tf`` is
    copied as it was: the mapping reads ``/odom``."""

    topic: str
    start_s: float
    end_s: float
    counters: str = "kept"

    def __post_init__(self) -> None:
        if self.counters not in COUNTERS:
            raise ValueError(f"counters must be one of {COUNTERS}, not {self.counters!r}")
        if self.counters != "kept" and self.topic != topics.ODOM:
            raise ValueError(f"only {topics.ODOM} has counters, not {self.topic}")


class _Counters:
    """One silence's odometry frame after it, as the poses reach it (through the silences
    before it in the list, as if each were written into a copy of the one before)."""

    def __init__(self, silence: Silence) -> None:
        self.silence = silence
        self._last: FloatArray | None = None  # the last pose before the silence
        self._origin: FloatArray | None = None
        self._anchor = np.zeros(3)

    def moves(self, at_s: float) -> bool:
        return at_s >= self.silence.start_s

    def apply(self, at_s: float, pose: FloatArray) -> FloatArray:
        if at_s < self.silence.start_s:
            self._last = pose
            return pose
        if self._origin is None:
            self._origin = pose
            if self.silence.counters == "joined" and self._last is not None:
                self._anchor = self._last
        return se2.compose(self._anchor, se2.between(self._origin, pose))


def without(
    src: Path, dst: Path, topic: str, start_s: float, end_s: float, *, counters: str = "kept"
) -> int:
    """A copy of ``src`` with one :class:`Silence`; returns how many messages it left out."""
    (dropped,) = silenced(src, dst, [Silence(topic, start_s, end_s, counters)])
    return dropped


def silenced(src: Path, dst: Path, silences: Sequence[Silence]) -> list[int]:
    """A copy of ``src`` with every silence of ``silences``, in one pass (a pass over a long
    recording is seconds); returns how many messages each left out. The copy is the one
    :func:`without` would leave applied once per silence, in the list's order, each to the
    copy before. Everything else (schemas, channels, metadata, the other messages) is copied
    as it was."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    dropped = [0] * len(silences)
    stages = [_Counters(s) for s in silences if s.counters != "kept"]
    with src.open("rb") as f, dst.open("wb") as g:
        reader = make_reader(f)
        writer = Writer(g)
        channels = start_copy(reader, writer, src)
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        factory = ProtobufDecoderFactory()
        decoders: dict[int, Any] = {}  # one per channel
        first = None
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            first = message.log_time if first is None else first
            at = (message.log_time - first) / NS_PER_S
            data = message.data
            cut = next(
                (
                    k
                    for k, s in enumerate(silences)
                    if s.topic == channel.topic and s.start_s <= at < s.end_s
                ),
                None,
            )
            if cut is not None:
                dropped[cut] += 1
                continue
            if stages and channel.topic == topics.ODOM:
                if channel.id not in decoders:
                    decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
                decode = decoders[channel.id]
                if decode is None:
                    raise ValueError(f"{src}: cannot decode {topics.ODOM}")
                odometry = decode(data)
                for stage in stages:
                    moved = stage.moves(at)
                    pose = stage.apply(at, _pose(odometry))
                    if moved:  # written, and read back by the next, as a copy would be
                        data = _with_pose(odometry, pose)
                        odometry = decode(data)
            writer.add_message(
                channels[channel.id], message.log_time, data, message.publish_time,
                message.sequence,
            )  # fmt: skip
        writer.finish()  # type: ignore[no-untyped-call]
    return dropped


def _pose(odometry: Any) -> FloatArray:
    """x, y, yaw of a ``foxglove.Odometry``."""
    position, q = odometry.pose.position, odometry.pose.orientation
    return np.array([position.x, position.y, 2.0 * math.atan2(q.z, q.w)])


def _with_pose(odometry: Any, pose: FloatArray) -> bytes:
    """The ``foxglove.Odometry`` at another planar pose, encoded."""
    position, q = odometry.pose.position, odometry.pose.orientation
    position.x, position.y = float(pose[0]), float(pose[1])
    q.x, q.y, q.z, q.w = 0.0, 0.0, math.sin(pose[2] / 2.0), math.cos(pose[2] / 2.0)
    return bytes(odometry.SerializeToString())


@dataclass(frozen=True, slots=True)
class SilenceScore:
    """A silenced recording mapped, against the truth, under one rigid transform each."""

    rms_m: float  # every scan on a floor (evaluate_recording's figure)
    max_m: float
    kept_rms_m: float  # the scans the odometry spoke for
    kept_max_m: float
    blind_scans: int
    worst_walls: float  # the lowest floor's share of walls within 10 cm, building transform
    worst_lobby_m: float
    stats: dict[str, float]


def score_silence(recording: Path, out: Path) -> SilenceScore:
    """Map a (silenced) simulated recording into ``out`` and score it."""
    result = build_maps(recording, out)
    report = evaluate_recording(result, recording)
    truth = [r.message for r in read_messages(recording, ["/truth/pose"])]
    true_pose, _ = truth_at(
        np.array([m.t_ns for m in truth], dtype=np.int64),
        np.array([(m.x_m, m.y_m, m.theta_rad) for m in truth], dtype=np.float64),
        np.array([m.floor for m in truth], dtype=np.int64),
        result.run.scans.t_ns,
    )
    blind = result.run.blind
    kept = (result.segmentation.scan_floor >= 0) & ~blind
    est = result.slam.scan_poses
    aligned = se2.compose(fit_rigid(est[kept, :2], true_pose[kept, :2])[None, :], est)
    errors = np.hypot(*(aligned[kept, :2] - true_pose[kept, :2]).T)
    return SilenceScore(
        rms_m=report.trajectory_rms_m,
        max_m=report.trajectory_max_m,
        kept_rms_m=float(np.sqrt(np.mean(errors**2))),
        kept_max_m=float(errors.max()),
        blind_scans=int(blind.sum()),
        worst_walls=min(f.building_occupied_precision for f in report.floors),
        worst_lobby_m=max(f.lobby_error_m for f in report.floors),
        stats=dict(result.slam.stats),
    )
