"""A device silent for a while: how the post-run maps cope with what the daemon's reconnects
leave in a recording.

The daemon closes a device that stops, marks it down and opens it again (docs/daemon.md), so
a recording can hold a stretch without scans while the robot drives on, or scans without
odometry. :func:`without` writes a copy of a simulated recording with one topic left out for a
while; :func:`score_silence` maps it and scores it against the simulator's truth, over every
scan and over the scans the odometry spoke for (the others are not mapped: see
:func:`baromap.mapping.slam.run_slam`'s ``blind``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from baromap.evaluation.mapping import evaluate_recording, truth_at
from baromap.evaluation.trajectory import fit_rigid
from baromap.mapping import se2
from baromap.mapping.build import build_maps
from baromap.messages import NS_PER_S
from baromap.recording import read_messages


def without(src: Path, dst: Path, topic: str, start_s: float, end_s: float) -> int:
    """A copy of ``src`` with no ``topic`` message from ``start_s`` to ``end_s`` after its
    first message (the device unplugged, power-cycled); returns how many were left out.
    Everything else (schemas, channels, metadata, the other messages) is copied as it was."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    dropped = 0
    with src.open("rb") as f, dst.open("wb") as g:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
        if summary is None:
            raise ValueError(f"{src} has no summary section to copy channels from")
        writer = Writer(g)
        writer.start(profile=header.profile, library=header.library)
        schemas = {
            sid: writer.register_schema(s.name, s.encoding, s.data)
            for sid, s in summary.schemas.items()
        }
        channels = {
            cid: writer.register_channel(
                c.topic, c.message_encoding, schemas.get(c.schema_id, 0), c.metadata
            )
            for cid, c in summary.channels.items()
        }
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        first = None
        for _, channel, message in reader.iter_messages(log_time_order=True):
            first = message.log_time if first is None else first
            at = (message.log_time - first) / NS_PER_S
            if channel.topic == topic and start_s <= at < end_s:
                dropped += 1
                continue
            writer.add_message(
                channels[channel.id],
                message.log_time,
                message.data,
                message.publish_time,
                message.sequence,
            )
        writer.finish()  # type: ignore[no-untyped-call]
    return dropped


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
