"""Opening a Zenoh session from :class:`~baromap.live.settings.LiveSettings`."""

from __future__ import annotations

from typing import TYPE_CHECKING

from baromap.errors import BaromapError
from baromap.live.settings import LiveSettings, zenoh_message

if TYPE_CHECKING:
    import zenoh


class LiveError(BaromapError):
    """Zenoh could not do what was asked (no router reachable, an endpoint already taken)."""


def open_session(settings: LiveSettings) -> zenoh.Session:
    """An open session; LiveError naming the endpoints if Zenoh refuses.

    A client with no reachable router fails at once (Zenoh tries each endpoint once); a peer
    opens even when nothing it should connect to is up, and keeps trying in the background.
    """
    import zenoh

    config = settings.zenoh_config()
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        where = ", ".join(settings.connect or settings.listen) or "multicast scouting"
        raise LiveError(
            f"cannot open a Zenoh {settings.mode.value} session ({where}): {zenoh_message(exc)}"
        ) from None


def close_session(session: zenoh.Session) -> None:
    """Close a session (undeclaring all it declared, liveliness tokens included)."""
    session.close()  # type: ignore[no-untyped-call]
