"""Live floor state over Zenoh: keys, payloads, settings, what to publish when, and watching.

The threads and the session that publish live in the daemon (``daemon/baromapd/live.py``); here are
the parts both sides share and everything that can be tested without a network:

- :mod:`~baromap.live.keys`: the key expressions of docs/design.md, in one module.
- :mod:`~baromap.live.payloads`: JSON payloads, the same as a recording's JSON channels.
- :mod:`~baromap.live.settings`: the ``[zenoh]`` and ``[reference]`` configuration tables.
- :mod:`~baromap.live.schedule`: which messages are published, and when (sans-I/O).
- :mod:`~baromap.live.reference`: a reference station's pressure, for the floor detector.
- :mod:`~baromap.live.watch`: following robots' floors, liveliness and state (``baromap watch``).
"""

from baromap.live.keys import Channel, NodeKeys
from baromap.live.session import LiveError
from baromap.live.settings import LiveSettings, ReferenceSettings, ZenohMode

__all__ = ["Channel", "LiveError", "LiveSettings", "NodeKeys", "ReferenceSettings", "ZenohMode"]
