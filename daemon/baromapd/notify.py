"""systemd's notification protocol: READY=1, STATUS=..., WATCHDOG=1, STOPPING=1.

The protocol is one datagram of ``KEY=VALUE`` lines to the ``AF_UNIX`` socket named in
``$NOTIFY_SOCKET`` (a leading ``@`` means the abstract namespace), as ``sd_notify(3)``
specifies. It is written here rather than taken from a package: ``systemd-python`` needs
libsystemd's headers and a C build, and the pure-Python ``sdnotify`` (last released 2017)
swallows every error with a bare ``except`` and never closes its socket.

The watchdog interval comes from ``$WATCHDOG_USEC``; the daemon pings at half of it, and only
while its main loop sees every part making progress (see ``baromapd.app``).
"""

from __future__ import annotations

import os
import socket
from collections.abc import Mapping
from types import TracebackType

import structlog

log = structlog.get_logger(__name__)


class Notifier:
    """Sends notifications when started by systemd (``$NOTIFY_SOCKET`` set); else does nothing."""

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        self._address = "\0" + address[1:] if address.startswith("@") else address
        self._socket: socket.socket | None = None
        if self._address:
            self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
        usec = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        self.watchdog_s: float | None = None
        if usec.isdigit() and int(usec) > 0 and (not pid or pid == str(os.getpid())):
            self.watchdog_s = int(usec) / 1e6
        self.failures = 0

    @property
    def enabled(self) -> bool:
        return self._socket is not None

    def notify(self, **fields: str | int) -> bool:
        """Send ``KEY=value`` lines (keys upper-cased); False if not sent."""
        if self._socket is None:
            return False
        message = "\n".join(f"{key.upper()}={value}" for key, value in fields.items())
        try:
            self._socket.sendto(message.encode(), self._address)
        except OSError as exc:
            self.failures += 1
            log.warning("sd_notify failed", error=str(exc), address=self._address.lstrip("\0"))
            return False
        return True

    def ready(self, status: str) -> bool:
        return self.notify(ready=1, status=status)

    def status(self, status: str) -> bool:
        return self.notify(status=status)

    def watchdog(self) -> bool:
        return self.notify(watchdog=1)

    def stopping(self, status: str) -> bool:
        return self.notify(stopping=1, status=status)

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    def __enter__(self) -> Notifier:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
