"""What a UART set to one speed makes of bytes sent at another: the garbage of a baud mismatch.

A pty carries bytes, not bits, so a twin has to produce the mismatch itself or a host's baud
search finds the device at any speed. This module replays the line bit by bit: the sender
puts each byte on the line as a start bit (0), eight data bits LSB first and a stop bit (1),
back to back, the line idle (1) before and after; the receiver waits for a falling edge,
checks the start bit in its middle, samples eight data bits and the stop bit in their middles
at its own bit time, and looks for the next start after the stop bit. A byte whose stop bit
reads 0 (a framing error) arrives as NUL, as Linux delivers it on a raw tty (neither IGNPAR nor
PARMRK set). The result is what a real line gives: fewer, wrong bytes when the receiver is
slower, more when it is faster, now and then a byte that happens to be right.
"""

from __future__ import annotations

import bisect
import math
from typing import Final

#: What a byte with a framing error reads as.
FRAMING_ERROR_BYTE: Final = 0x00
_BITS_PER_BYTE: Final = 10


def _line(data: bytes) -> bytearray:
    """Line levels, one per bit time of the sender."""
    levels = bytearray()
    for byte in data:
        levels.append(0)
        levels.extend((byte >> i) & 1 for i in range(8))
        levels.append(1)
    return levels


def misread(data: bytes, tx_baud: int, rx_baud: int) -> bytes:
    """The bytes a receiver at ``rx_baud`` reads from ``data`` sent at ``tx_baud``."""
    if tx_baud == rx_baud or not data:
        return bytes(data)
    levels = _line(data)
    n = len(levels)
    falls = [k for k in range(n) if levels[k] == 0 and (k == 0 or levels[k - 1] == 1)]
    tx_bit = 1.0 / tx_baud
    rx_bit = 1.0 / rx_baud

    def level(t: float) -> int:
        k = int(t / tx_bit)
        return levels[k] if k < n else 1

    out = bytearray()
    t = 0.0
    while True:
        i = bisect.bisect_left(falls, math.ceil(t / tx_bit - 1e-9))
        if i == len(falls):
            break
        start = falls[i] * tx_bit
        if level(start + 0.5 * rx_bit) != 0:  # a glitch, not a start bit
            t = start + 0.5 * rx_bit
            continue
        value = 0
        for bit in range(8):
            value |= level(start + (1.5 + bit) * rx_bit) << bit
        stop_ok = level(start + 9.5 * rx_bit) == 1
        out.append(value if stop_ok else FRAMING_ERROR_BYTE)
        t = start + 9.5 * rx_bit
    return bytes(out)


def line_seconds(size: int, baud: int) -> float:
    """Time ``size`` bytes take on an 8N1 line."""
    return size * _BITS_PER_BYTE / baud
