"""The operating system's name of the calling thread, set to its Python name.

Python (before 3.14) leaves every thread named after the interpreter, so ``top -H``, ``ps -L``,
``/proc/<pid>/task/*/stat`` and the bench cannot tell the laser's reader from the recorder or
from the Zenoh runtime. Linux keeps 15 bytes of it (``prctl(PR_SET_NAME)``); threads a thread
starts (the Zenoh runtime's) inherit it. Elsewhere this does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys
import threading
from typing import Final

_PR_SET_NAME: Final = 15
_NAME_BYTES: Final = 15


def name_os_thread(name: str | None = None) -> None:
    """Give the calling thread ``name`` (default: its Python name) in the OS, best effort."""
    if not sys.platform.startswith("linux"):
        return
    text = (name or threading.current_thread().name).encode("utf-8", "replace")[:_NAME_BYTES]
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
        libc.prctl(_PR_SET_NAME, ctypes.c_char_p(text), 0, 0, 0)
    except (OSError, AttributeError):
        return
