"""Copies of a recording cut the way the daemon cuts a run, for the tests and benches that
check what reads a run copes with: rotated into parts, or split by a restart of the daemon.

A copy keeps every schema, channel and metadata record; only the header names the run and
the part, as baromapd writes them (``daemon/baromapd/recorder.py``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from baromap.recording import topics


def start_copy(reader: Any, writer: Any, src: Path) -> dict[int, int]:
    """Start ``writer`` as ``reader``'s file started, with its schemas and channels; returns
    the writer's channel id for each of the reader's."""
    header = reader.get_header()
    summary = reader.get_summary()
    if summary is None:
        raise ValueError(f"{src} has no summary section to copy channels from")
    writer.start(profile=header.profile, library=header.library)
    schemas = {
        sid: writer.register_schema(s.name, s.encoding, s.data)
        for sid, s in summary.schemas.items()
    }
    return {
        cid: writer.register_channel(
            c.topic, c.message_encoding, schemas.get(c.schema_id, 0), c.metadata
        )
        for cid, c in summary.channels.items()
    }


def split_like_baromapd(
    src: Path, out_dir: Path, at_s: float, runs: tuple[str, str] = ("run", "run")
) -> list[Path]:
    """``src`` cut in two at ``at_s`` after its first message: two parts of one run, as
    baromapd rotates a run (``runs`` the same), or two runs, as a restarted daemon leaves
    them. Each header names its run and part and says the odometry's tracks were joined,
    as baromapd's does. Returns the two files, ``RUN_PART.mcap`` in ``out_dir``."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for part in (0, 1):
        number = part if runs[0] == runs[1] else 0
        path = out_dir / f"{runs[part]}_{number:03d}.mcap"
        with src.open("rb") as f, path.open("wb") as g:
            reader = make_reader(f)
            writer = Writer(g)
            channels = start_copy(reader, writer, src)
            for record in reader.iter_metadata():
                data = dict(record.metadata)
                if record.name == topics.METADATA_NAME:
                    data.update(run=runs[part], part=str(number))
                    data[topics.ODOMETRY_TRACKS_KEY] = topics.ODOMETRY_TRACKS_JOINED
                writer.add_metadata(record.name, data)
            first = None
            for _, channel, message in reader.iter_messages(log_time_order=True):
                first = message.log_time if first is None else first
                if (message.log_time - first >= at_s * 1e9) == bool(part):
                    writer.add_message(
                        channels[channel.id], message.log_time, message.data,
                        message.publish_time, message.sequence,
                    )  # fmt: skip
            writer.finish()  # type: ignore[no-untyped-call]
        paths.append(path)
    return paths
