"""Sans-I/O codecs for the robot's three devices.

A decoder is fed bytes and returns decoded messages and :class:`BadFrame` records; it holds
only a bounded buffer, never touches a port, never raises on bad bytes, and resynchronises on
the next frame. Encoders raise :class:`baromap.errors.EncodeError` when asked for something the
wire format cannot carry (a programming error, not line noise).
"""

from baromap.protocols.framing import BadFrame, DecoderStats

__all__ = ["BadFrame", "DecoderStats"]
