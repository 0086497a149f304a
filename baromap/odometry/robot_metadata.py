"""Which parameter set turned a recording's counters into metres, and how it was chosen.

A recording keeps the raw 15-bit counters in every :class:`~baromap.messages.Odometry`; to
turn them into metres again (re-integration, an import, a check of the live figures) a tool
needs the model the recorder used, and the subclass the robot reported. The recorder writes
them as one MCAP metadata record, :data:`ROBOT_METADATA`, with string values:

- ``model``: the parameter set used (a key of ``MODELS``, e.g. ``p3at-sh``);
- ``model_source``: ``reported`` (chosen from the SYNC2 subclass), ``configured`` (pinned and
  matching) or ``override`` (pinned against the reported subclass, deliberately);
- ``reported_name``, ``reported_class``, ``reported_subclass``: the SYNC2 echo's strings;
- ``dist_conv_factor``, ``angle_conv_factor``, ``vel_conv_factor``: the factors used (so a
  recording stays readable if the table changes).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Final

from baromap.errors import ConfigError, InputFormatError
from baromap.messages import Odometry
from baromap.odometry.integrator import BREAK_S, OdometryIntegrator
from baromap.protocols.p2os import StandardSip
from baromap.protocols.robot_models import RobotModel, find_model

#: Name of the metadata record.
ROBOT_METADATA: Final = "baromap.robot"
MODEL_SOURCES: Final = ("reported", "configured", "override")
#: Older recordings (the simulator's) name only the model, in their own record.
_LEGACY: Final = (("baromap.sim", "robot_model"),)


def robot_metadata(
    model: RobotModel, reported: tuple[str, str, str] | None, source: str
) -> dict[str, str]:
    """The :data:`ROBOT_METADATA` record for ``model``; ``reported`` is (name, class, subclass)."""
    if source not in MODEL_SOURCES:
        raise ConfigError(f"model source is one of {MODEL_SOURCES}, not {source!r}")
    name, robot_class, subclass = reported if reported is not None else ("", "", "")
    return {
        "model": model.name,
        "model_source": source,
        "reported_name": name,
        "reported_class": robot_class,
        "reported_subclass": subclass,
        "dist_conv_factor": repr(model.dist_conv_factor),
        "angle_conv_factor": repr(model.angle_conv_factor),
        "vel_conv_factor": repr(model.vel_conv_factor),
    }


def model_from_metadata(metadata: Mapping[str, Mapping[str, str]]) -> RobotModel | None:
    """The model a recording's counters were turned into metres with, or None if unrecorded.

    The factors written in the record win over the table's (the recording is the truth of
    what was done); an unknown model name or an unreadable factor is an InputFormatError.
    """
    record = metadata.get(ROBOT_METADATA)
    if record is None:
        for name, key in _LEGACY:
            legacy = metadata.get(name, {}).get(key)
            if legacy is not None:
                record = {"model": legacy}
                break
    if record is None or "model" not in record:
        return None
    model = find_model(record["model"])
    if model is None:
        raise InputFormatError(f"the recording's robot model {record['model']!r} is unknown")

    def factor(field: str, default: float) -> float:
        if field not in record:
            return default
        try:
            return float(record[field])
        except ValueError:
            raise InputFormatError(f"robot metadata {field}={record[field]!r}") from None

    return dataclasses.replace(
        model,
        dist_conv_factor=factor("dist_conv_factor", model.dist_conv_factor),
        angle_conv_factor=factor("angle_conv_factor", model.angle_conv_factor),
        vel_conv_factor=factor("vel_conv_factor", model.vel_conv_factor),
    )


def reintegrate(
    odometry: Sequence[Odometry], model: RobotModel, *, origin_at_start: bool = False
) -> list[Odometry]:
    """Poses rebuilt from the recorded raw counters with ``model`` (velocities as recorded).

    ``origin_at_start`` as in :class:`~baromap.odometry.integrator.OdometryIntegrator`; the
    counters of a robot that came back from zero after a gap (:data:`BREAK_S`) are joined at
    the last pose, as the daemon joined them.
    """
    integrator = OdometryIntegrator(model, origin_at_start=origin_at_start, break_s=BREAK_S)
    out = []
    for message in odometry:
        sip = StandardSip(
            moving=False,
            x=message.raw_x,
            y=message.raw_y,
            theta=message.raw_theta,
            left_vel=0,
            right_vel=0,
            battery_dv=0,
            stall_bumpers=0,
            control=0,
            flags=0,
            compass=0,
        )
        pose = integrator.update(sip, message.t_ns)
        out.append(
            dataclasses.replace(message, x_m=pose.x_m, y_m=pose.y_m, theta_rad=pose.theta_rad)
        )
    return out
