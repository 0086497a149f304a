"""The live view's library side: what baromapd serves to Foxglove while the robot drives.

- :mod:`~baromap.liveview.floor_map`: the live map of the current floor (scan matching on that
  floor, no loop closure), following the floor detector.
- :mod:`~baromap.liveview.channels`: the recording's channels, message for message, and the
  live map's, logged to a Foxglove SDK context.

The process, the SDK's server and the front that takes the viewers are the daemon's
(``daemon/baromapd/liveview*.py``).
"""
