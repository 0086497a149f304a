"""Simulated devices on pseudo-terminals, each speaking its real wire protocol."""

from baromap.sim.twins.baro import BaroTwin
from baromap.sim.twins.base import SimClock, Twin
from baromap.sim.twins.lms200 import Lms200Twin
from baromap.sim.twins.p2os import P2osTwin
from baromap.sim.twins.runner import SimDevices

__all__ = ["BaroTwin", "Lms200Twin", "P2osTwin", "SimClock", "SimDevices", "Twin"]
