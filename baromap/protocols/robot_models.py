"""Conversion factors of the Pioneer bases, from ARIA's robot parameter files.

A P2OS robot reports positions in its own encoder units; only the host knows how many
millimetres one unit is, and a wrong parameter set scales the whole map silently. So the model
is chosen explicitly in configuration and looked up here, never guessed from the robot's name.

Values are those of AriaCoda's ``params/p3at.p``, ``params/p2at.p`` and ``params/p3dx.p``. The
files round AngleConvFactor to 0.00153 with the comment "2PI/4096"; the firmware's heading unit
really is 1/4096 of a turn, so the exact value is used (the rounded one is 0.26 % short, about
one degree per full turn).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Final

from baromap.errors import ConfigError

#: Radians per heading unit: P2OS firmware counts 4096 units per turn.
ANGLE_CONV_FACTOR: Final = math.tau / 4096


@dataclass(frozen=True, slots=True)
class RobotModel:
    """One robot type's conversion factors (ARIA parameter names in the comments)."""

    name: str
    dist_conv_factor: float  # DistConvFactor: mm per position unit
    angle_conv_factor: float  # AngleConvFactor: rad per heading unit
    vel_conv_factor: float  # VelConvFactor: mm/s per velocity unit
    diff_conv_factor: float  # DiffConvFactor: rad/s per mm/s of (right - left) / 2
    range_conv_factor: float  # RangeConvFactor: mm per sonar unit
    max_velocity_mmps: float  # MaxVelocity
    max_rot_velocity_degps: float  # MaxRVelocity
    sonar_count: int  # SonarNum


P3AT: Final = RobotModel(
    name="p3at",
    dist_conv_factor=0.465,
    angle_conv_factor=ANGLE_CONV_FACTOR,
    vel_conv_factor=1.0,
    diff_conv_factor=0.0034,
    range_conv_factor=1.0,
    max_velocity_mmps=1200.0,
    max_rot_velocity_degps=300.0,
    sonar_count=16,
)

P2AT: Final = RobotModel(
    name="p2at",
    dist_conv_factor=1.32,
    angle_conv_factor=ANGLE_CONV_FACTOR,
    vel_conv_factor=1.0,
    diff_conv_factor=0.0034,
    range_conv_factor=0.268,
    max_velocity_mmps=1200.0,
    max_rot_velocity_degps=300.0,
    sonar_count=16,
)

P3DX: Final = RobotModel(
    name="p3dx",
    dist_conv_factor=0.485,
    angle_conv_factor=ANGLE_CONV_FACTOR,
    vel_conv_factor=1.0,
    diff_conv_factor=0.0056,
    range_conv_factor=1.0,
    max_velocity_mmps=2200.0,
    max_rot_velocity_degps=500.0,
    sonar_count=16,
)

MODELS: Final = MappingProxyType({m.name: m for m in (P3AT, P2AT, P3DX)})


def robot_model(name: str) -> RobotModel:
    """The model called ``name`` ("p3at", "P3-AT", "p3_at" all work), else ConfigError."""
    key = name.strip().lower().replace("-", "").replace("_", "")
    try:
        return MODELS[key]
    except KeyError:
        known = ", ".join(sorted(MODELS))
        raise ConfigError(f"unknown robot model {name!r}; known: {known}") from None
