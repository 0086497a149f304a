"""Floor detection from barometric pressure: which floor, when it changed, how high.

- :mod:`~baromap.floors.online`: the causal, streaming detector the daemon drives (pressure,
  odometry, a reference station in; :class:`~baromap.messages.FloorEvent` out).
- :mod:`~baromap.floors.paper`: the baseline of Ozkil et al. (batch segmentation).
- :func:`detect_floors`: arrays in, :class:`FloorDetection` out, with either method.
- :mod:`~baromap.floors.height`: pressure differences to metres (hypsometric equation).
- :mod:`~baromap.floors.building_model`: floor names from an earlier run's ``building.yaml``.

The batch detection's names are imported on first use (PEP 562 ``__getattr__``): the daemon
runs only the online detector, and imports this package at every start.
"""

from typing import TYPE_CHECKING, Any

from baromap.floors.building_model import BuildingModel, load_building_model
from baromap.floors.config import FloorDetectorConfig
from baromap.floors.events import apply_corrections, decided_at
from baromap.floors.online import OnlineFloorDetector

if TYPE_CHECKING:
    from baromap.floors.detection import (
        Floor,
        FloorDetection,
        Segment,
        Transition,
        detect_floors,
    )

_FROM_DETECTION = frozenset({"Floor", "FloorDetection", "Segment", "Transition", "detect_floors"})


def __getattr__(name: str) -> Any:
    if name in _FROM_DETECTION:
        from baromap.floors import detection

        return getattr(detection, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "BuildingModel",
    "Floor",
    "FloorDetection",
    "FloorDetectorConfig",
    "OnlineFloorDetector",
    "Segment",
    "Transition",
    "apply_corrections",
    "decided_at",
    "detect_floors",
    "load_building_model",
]
