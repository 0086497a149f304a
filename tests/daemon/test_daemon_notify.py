"""The sd_notify client: datagrams to $NOTIFY_SOCKET, the watchdog interval from the env."""

from __future__ import annotations

import os
import socket
from pathlib import Path

from baromapd.notify import Notifier


def test_notifications_reach_the_socket(tmp_path: Path) -> None:
    address = str(tmp_path / "n.sock")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind(address)
        sock.settimeout(1)
        env = {
            "NOTIFY_SOCKET": address,
            "WATCHDOG_USEC": "4000000",
            "WATCHDOG_PID": str(os.getpid()),
        }
        with Notifier(env) as notifier:
            assert notifier.watchdog_s == 4.0
            assert notifier.ready("laser up")
            assert notifier.watchdog()
            assert notifier.stopping("bye")
        got = [sock.recv(1024).decode() for _ in range(3)]
    assert got == ["READY=1\nSTATUS=laser up", "WATCHDOG=1", "STOPPING=1\nSTATUS=bye"]


def test_without_systemd_nothing_is_sent() -> None:
    with Notifier({}) as notifier:
        assert not notifier.enabled
        assert notifier.watchdog_s is None
        assert not notifier.ready("x")
    other_pid = Notifier({"NOTIFY_SOCKET": "@x", "WATCHDOG_USEC": "1000", "WATCHDOG_PID": "1"})
    assert other_pid.watchdog_s is None  # the watchdog is meant for another process
    other_pid.close()
