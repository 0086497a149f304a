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


class RecordingWriteError(RecordingError):
    """Writing, flushing or closing a recording failed: the file is left as far as it got.

    ``os_error`` is what the operating system refused (``ENOSPC`` for a full disk, ``EIO``),
    when the failure came from it; the MCAP library's own error only says "I/O error".
    """

    def __init__(self, message: str, os_error: OSError | None = None) -> None:
        super().__init__(message)
        self.os_error = os_error


class DeviceError(BaromapError):
    """A device could not be opened or did not complete its handshake."""
