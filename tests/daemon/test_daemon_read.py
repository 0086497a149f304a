"""A session's reads on a real pty: every byte handed on once, in order, in chunks that stay
what they were when later reads reuse the session's read buffer."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator

import pytest

from baromapd.clock import HostClock
from baromapd.config import Retry
from baromapd.session import READ_CHUNK, DeviceSession


class _Raw(DeviceSession):
    """A session with nothing on top: the reads alone."""

    def handshake(self) -> None:
        pass

    def handle(self, data: bytes, read_ns: int) -> None:
        pass


@pytest.fixture
def session_and_line() -> Iterator[tuple[DeviceSession, int]]:
    master, slave = os.openpty()
    session = _Raw(
        "raw",
        port=os.ttyname(slave),
        baud=500_000,
        retry=Retry(),
        clock=HostClock(),
        publish=lambda message, read_ns: None,
        resolve=lambda spec: spec,
    )
    session._open()
    yield session, master
    session._close()
    os.close(slave)
    os.close(master)


def _read_all(session: DeviceSession, size: int) -> list[bytes]:
    chunks: list[bytes] = []
    deadline = time.monotonic() + 5.0
    while sum(map(len, chunks)) < size and time.monotonic() < deadline:
        data, _ = session.read()
        if data:
            chunks.append(data)
    return chunks


def test_reads_hand_on_every_byte_in_chunks_later_reads_leave_alone(
    session_and_line: tuple[DeviceSession, int],
) -> None:
    session, master = session_and_line
    sent = bytes(range(256)) * 3 + b"\x02\x80tail"
    chunks: list[bytes] = []
    for piece in (sent[:100], sent[100:500], sent[500:]):
        os.write(master, piece)
        chunks += _read_all(session, len(piece))
    assert b"".join(chunks) == sent  # kept chunks were not overwritten by the reads after them
    assert all(isinstance(c, bytes) and c for c in chunks)
    assert session.health(0).counters["bytes_in"] == len(sent)


def test_more_than_one_read_buffer_comes_in_full_and_in_order(
    session_and_line: tuple[DeviceSession, int],
) -> None:
    session, master = session_and_line
    sent = os.urandom(READ_CHUNK + 5000)
    chunks: list[bytes] = []
    for start in range(0, len(sent), 2048):  # a pty holds a few KiB: write as the line would
        piece = sent[start : start + 2048]
        os.write(master, piece)
        chunks += _read_all(session, len(piece))
    assert b"".join(chunks) == sent
