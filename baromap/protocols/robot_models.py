"""Parameter sets of the Pioneer bases, and choosing one the way ARIA does.

A P2OS robot reports positions in its own encoder units; only the host knows how many
millimetres one unit is, and a wrong parameter set scales the whole map silently: an ARCOS
P3-AT (subclass ``p3at-sh``, DistConvFactor 1.0) read with the old P2OS ``p3at`` set (0.465)
records every distance at 46.5 % of the truth. ARIA and p2os_driver therefore pick the set from
the subclass the robot reports in its SYNC2 echo; :func:`select_model` does the same, and
refuses a configured model that contradicts the robot unless the mismatch is allowed on
purpose (a robot whose firmware reports the wrong subclass).

Values are those of ARIA's robot parameter files (AriaCoda ``params/<subclass>.p``), which
p2os_driver's ``robot_params.cpp`` repeats. The files round AngleConvFactor to 0.00153 with the
comment "2PI/4096"; the firmware's heading unit really is 1/4096 of a turn, so the exact value
is used (the rounded one is 0.26 % short, about one degree per full turn).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Final

from baromap.errors import ConfigError

#: Radians per heading unit: P2OS firmware counts 4096 units per turn.
ANGLE_CONV_FACTOR: Final = math.tau / 4096
#: The class every model here reports in the SYNC2 echo.
PIONEER_CLASS: Final = "Pioneer"


class ModelMismatchError(ConfigError):
    """The configured robot model is not the one the robot reports."""


@dataclass(frozen=True, slots=True)
class RobotModel:
    """One robot type's parameter set (ARIA parameter names in the comments).

    ``name`` is the subclass string the robot reports in its SYNC2 echo (ARIA's Subclass).
    """

    name: str
    dist_conv_factor: float  # DistConvFactor: mm per position unit
    diff_conv_factor: float  # DiffConvFactor: rad/s per mm/s of (right - left) / 2
    range_conv_factor: float  # RangeConvFactor: mm per sonar unit
    max_velocity_mmps: float  # MaxVelocity
    max_rot_velocity_degps: float  # MaxRVelocity
    sonar_count: int = 16  # SonarNum
    angle_conv_factor: float = ANGLE_CONV_FACTOR  # AngleConvFactor: rad per heading unit
    vel_conv_factor: float = 1.0  # VelConvFactor: mm/s per velocity unit
    robot_class: str = PIONEER_CLASS  # Class


# Columns: subclass, DistConvFactor, DiffConvFactor, RangeConvFactor, MaxVelocity, MaxRVelocity.
# Skid-steered four-wheel bases: 1200 mm/s, 300 deg/s, DiffConvFactor 0.0034.
P3AT_SH: Final = RobotModel("p3at-sh", 1.0, 0.0034, 1.0, 1200.0, 300.0)
P3AT: Final = RobotModel("p3at", 0.465, 0.0034, 1.0, 1200.0, 300.0)
P3ATIW_SH: Final = RobotModel("p3atiw-sh", 1.0, 0.0034, 1.0, 1200.0, 300.0)
P2AT: Final = RobotModel("p2at", 1.32, 0.0034, 0.268, 1200.0, 300.0)
P2AT8: Final = RobotModel("p2at8", 1.32, 0.0034, 1.0, 1200.0, 300.0)
# Two-wheel differential bases: 2200 mm/s, 500 deg/s, DiffConvFactor 0.0056.
P3DX_SH: Final = RobotModel("p3dx-sh", 1.0, 0.0056, 1.0, 2200.0, 500.0)
P3DX: Final = RobotModel("p3dx", 0.485, 0.0056, 1.0, 2200.0, 500.0)
P2DX: Final = RobotModel("p2dx", 0.84, 0.0056, 0.268, 2200.0, 500.0)

#: Subclass -> parameter set.
MODELS: Final = MappingProxyType(
    {m.name: m for m in (P3AT_SH, P3AT, P3ATIW_SH, P2AT, P2AT8, P3DX_SH, P3DX, P2DX)}
)
#: What a robot of today's ARCOS generation reports (and the simulated robot's default).
DEFAULT_MODEL: Final = P3AT_SH


def _key(name: str) -> str:
    return name.strip().lower().replace("-", "").replace("_", "")


_BY_KEY: Final = MappingProxyType({_key(name): model for name, model in MODELS.items()})


def find_model(name: str) -> RobotModel | None:
    """The model called ``name`` or None; case, ``-`` and ``_`` do not matter (P3-AT-SH)."""
    return _BY_KEY.get(_key(name))


def robot_model(name: str) -> RobotModel:
    """The model called ``name`` ("p3at-sh", "P3-AT", "p3_at" all work), else ConfigError."""
    model = find_model(name)
    if model is None:
        known = ", ".join(sorted(MODELS))
        raise ConfigError(f"unknown robot model {name!r}; known: {known}")
    return model


def select_model(
    reported_subclass: str, configured: str | None = None, *, allow_mismatch: bool = False
) -> RobotModel:
    """The parameter set to use for a robot that reported ``reported_subclass`` in SYNC2.

    With nothing configured the reported subclass decides (ARIA's rule); a subclass with no
    known parameter set is a :class:`ConfigError` (pin a model to run such a robot). A
    configured model that differs from the reported subclass raises
    :class:`ModelMismatchError` naming both, unless ``allow_mismatch`` says the configuration
    deliberately overrides what the robot reports.
    """
    reported = find_model(reported_subclass)
    if configured is None:
        if reported is None:
            known = ", ".join(sorted(MODELS))
            raise ConfigError(
                f"the robot reports subclass {reported_subclass!r}, which has no known "
                f"parameter set (known: {known}); configure the robot model to use one"
            )
        return reported
    chosen = robot_model(configured)
    if chosen is not reported and not allow_mismatch:
        raise ModelMismatchError(
            f"configured robot model {chosen.name!r} does not match the subclass "
            f"{reported_subclass!r} the robot reports; fix the configuration, or allow the "
            "mismatch if the robot's firmware reports the wrong subclass"
        )
    return chosen
