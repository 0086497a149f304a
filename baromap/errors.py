"""Exceptions of baromap.

Bad bytes on a live serial line are *not* exceptions: decoders count them and resynchronise.
Exceptions are for things a person must fix: a wrong configuration, an unreadable input file,
a programming error such as asking an encoder for a value the wire format cannot carry.
Everything is rooted in :class:`BaromapError` so entry points can catch one type.
"""


class BaromapError(Exception):
    """Root of every error baromap raises on purpose."""


class ConfigError(BaromapError):
    """A configuration value or command-line argument is invalid."""


class EncodeError(BaromapError, ValueError):
    """An encoder was asked for something its wire format cannot represent."""


class InputFormatError(BaromapError):
    """An input file (recording, log, CSV) is not in the expected format."""


class RecordingError(BaromapError):
    """An MCAP recording cannot be written or read."""


class DeviceError(BaromapError):
    """A device could not be opened or did not complete its handshake."""
