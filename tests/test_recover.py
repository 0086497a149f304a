"""``baromap recover``: a cut recording made whole, as the official MCAP reader opens it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import Writer

from baromap import messages as m
from baromap.cli.main import main as baromap_main
from baromap.errors import InputFormatError, RecordingError
from baromap.recording import RecordingWriter, read_messages
from baromap.recording.recover import is_cut, recover

T0 = 1_700_000_000_000_000_000

#: A writer process killed between two flushes: 200 samples flushed, 40 more not.
_KILLED_WRITER = """
import os, sys
from baromap import messages as m
from baromap.recording import RecordingWriter
w = RecordingWriter(sys.argv[1], robot="r1", flush_interval_s=3600, fsync=False)
for i in range(200):
    w.write(m.PressureSample({t0} + i * 20_000_000, 100000.0 + i, 20.0, i))
w.write_metadata("baromap.device.barometer", {{"firmware_version": "1.2.3"}})
w.flush()
for i in range(200, 240):
    w.write(m.PressureSample({t0} + i * 20_000_000, 100000.0 + i, 20.0, i))
os.kill(os.getpid(), 9)
"""


@pytest.fixture
def killed(tmp_path: Path) -> Path:
    path = tmp_path / "cut.mcap"
    code = _KILLED_WRITER.format(t0=T0)
    proc = subprocess.run([sys.executable, "-c", code, str(path)], check=False)
    assert proc.returncode == -9
    return path


def _official(path: Path) -> tuple[int, int, list[str], list[str]]:
    """(summary's message count, messages iterated, metadata names, attachment names)."""
    with path.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        count = summary.statistics.message_count
        iterated = sum(1 for _ in reader.iter_messages())
        names = [record.name for record in reader.iter_metadata()]
        attached = [record.name for record in reader.iter_attachments()]
    return count, iterated, names, attached


def test_a_killed_writers_file_is_made_whole(killed: Path, tmp_path: Path) -> None:
    # what the issue found: the usual call refuses the unfinished chunk (its length unset)
    with killed.open("rb") as stream, pytest.raises(McapError):
        list(make_reader(stream).iter_messages())
    assert is_cut(killed)
    fixed = tmp_path / "fixed.mcap"
    result = recover(killed, fixed)
    assert result.messages == 200 and result.topics == {"/baro": 200}
    assert result.cut_at is not None and 0 < result.cut_at < result.size
    assert result.reason is not None and "length is unset" in result.reason
    assert result.last_log_time == T0 + 199 * 20_000_000
    assert _official(fixed) == (200, 200, ["baromap", "baromap.device.barometer"], [])
    assert not is_cut(fixed)
    seqs = [rec.message.seq for rec in read_messages(fixed)]
    assert seqs == list(range(200))
    assert killed.stat().st_size == result.size, "the cut file is left as it was"


def test_metadata_and_attachments_are_kept_up_to_the_cut(tmp_path: Path) -> None:
    whole = tmp_path / "whole.mcap"
    with whole.open("wb") as stream:
        writer = Writer(stream, chunk_size=200)
        writer.start("baromap", "test")
        schema = writer.register_schema("s", "jsonschema", b"{}")
        channel = writer.register_channel("/x", "json", schema)
        for i in range(20):
            writer.add_message(channel, T0 + i, b'{"i": %d}' % i, T0 + i, sequence=i)
        writer.add_metadata("site", {"floor": "2"})
        writer.add_attachment(T0, T0, "building.yaml", "text/yaml", b"floors: []\n")
        for i in range(20, 40):
            writer.add_message(channel, T0 + i, b'{"i": %d}' % i, T0 + i, sequence=i)
        writer.finish()  # type: ignore[no-untyped-call]
    data = whole.read_bytes()
    cut = tmp_path / "cut.mcap"
    # cut inside the summary: every record of the data section is whole
    cut.write_bytes(data[: len(data) - 100])
    result = recover(cut, tmp_path / "a.mcap")
    assert (result.messages, result.metadata, result.attachments) == (40, 1, 1)
    count, _, names, attached = _official(tmp_path / "a.mcap")
    assert (count, names, attached) == (40, ["site"], ["building.yaml"])
    with (tmp_path / "a.mcap").open("rb") as stream:
        sequences = [msg.sequence for _, _, msg in make_reader(stream).iter_messages()]
    assert sequences == list(range(40))
    # cut in the middle of the data: only the records before the cut
    cut.write_bytes(data[: len(data) // 2])
    result = recover(cut, tmp_path / "b.mcap")
    assert 0 < result.messages < 40
    assert result.cut_at is not None and result.cut_at <= len(data) // 2
    assert _official(tmp_path / "b.mcap")[:2] == (result.messages, result.messages)


def test_a_whole_file_is_copied_and_said_to_be_whole(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with RecordingWriter(path, robot="r1") as writer:
        writer.write(m.PressureSample(T0, 100000.0))
    result = recover(path, tmp_path / "copy.mcap")
    assert result.cut_at is None and result.messages == 1
    assert not is_cut(path)


def test_what_cannot_be_recovered_is_refused(tmp_path: Path) -> None:
    other = tmp_path / "notes.mcap"
    other.write_bytes(b"not an mcap file at all")
    with pytest.raises(InputFormatError):
        recover(other, tmp_path / "x.mcap")
    with pytest.raises(RecordingError):
        recover(other, other)
    assert not (tmp_path / "x.mcap").exists()
    assert not (tmp_path / "x.mcap.part").exists()


def test_the_command_says_what_it_kept_and_where_the_cut_was(
    killed: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fixed = tmp_path / "fixed.mcap"
    assert baromap_main(["recover", str(killed), "-o", str(fixed)]) == 0
    out = capsys.readouterr().out
    assert "kept 200 messages (/baro 200)" in out
    size = os.path.getsize(killed)
    assert "was cut at byte " in out and f"of {size}" in out
    assert "last message kept: 2023-11-14T22:13:23.980000Z" in out
