"""Fixtures of the daemon's tests (the rig itself is in ``daemon_rig``)."""

from daemon_rig import rig, tap_program, twins

__all__ = ["rig", "tap_program", "twins"]
