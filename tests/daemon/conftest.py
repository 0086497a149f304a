"""Fixtures of the daemon's tests (the rig itself is in ``daemon_rig``)."""

from daemon_rig import rig, twins

__all__ = ["rig", "twins"]
