"""Zenoh payloads: the JSON of :mod:`baromap.jsonmsg`, one message type per channel.

A floor event on the wire is byte for byte what a recording's ``/floor/event`` channel holds,
so a subscriber and a replay read the same thing, and the ``schema`` field every object
carries lets a reader refuse a newer format instead of misreading it.
"""

from __future__ import annotations

from typing import Any

from baromap import jsonmsg
from baromap.errors import InputFormatError
from baromap.live.keys import Channel
from baromap.messages import DeviceHealth, FloorEvent, FloorState, PressureSample, RideEvent

#: The message type each channel carries (``alive`` carries no payload).
CHANNEL_TYPES: dict[Channel, type] = {
    Channel.EVENT: FloorEvent,
    Channel.RIDE: RideEvent,
    Channel.STATE: FloorState,
    Channel.PRESSURE: PressureSample,
    Channel.HEALTH: DeviceHealth,
}
#: The channel of each published message type.
CHANNEL_OF: dict[type, Channel] = {cls: channel for channel, cls in CHANNEL_TYPES.items()}

MEDIA_TYPE = "application/json"


def schema_of(channel: Channel) -> str:
    """The schema name a channel's samples declare in their Zenoh encoding."""
    return jsonmsg.schema_name(CHANNEL_TYPES[channel])


def encode(message: Any) -> bytes:
    if type(message) not in CHANNEL_OF:
        raise TypeError(f"{type(message).__name__} is not published over Zenoh")
    return jsonmsg.dumps(message)


def decode(channel: Channel, payload: bytes) -> Any:
    """The message a sample of ``channel`` carries; InputFormatError if it is not one."""
    cls = CHANNEL_TYPES.get(channel)
    if cls is None:
        raise InputFormatError(f"channel {channel.value!r} carries no message")
    try:
        return jsonmsg.loads(cls, payload)
    except (ValueError, TypeError) as exc:  # an enum value or a field this reader cannot take
        raise InputFormatError(f"{cls.__name__}: {exc}") from exc
