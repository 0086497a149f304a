"""Floor detection from barometric pressure: which floor, when it changed, how high.

- :mod:`~baromap.floors.online`: the causal, streaming detector the daemon drives.
- :mod:`~baromap.floors.paper`: the baseline of Ozkil et al. (batch segmentation).
- :func:`detect_floors`: arrays in, :class:`FloorDetection` out, with either method.
- :mod:`~baromap.floors.height`: pressure differences to metres (hypsometric equation).
"""

from baromap.floors.config import FloorDetectorConfig
from baromap.floors.detection import Floor, FloorDetection, Segment, Transition, detect_floors
from baromap.floors.online import OnlineFloorDetector

__all__ = [
    "Floor",
    "FloorDetection",
    "FloorDetectorConfig",
    "OnlineFloorDetector",
    "Segment",
    "Transition",
    "detect_floors",
]
