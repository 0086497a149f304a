"""Zenoh key expressions of baromap, all in one place (docs/design.md names them).

A robot publishes under ``baromap/<robot>/``, a reference station under
``baromap/reference/<station>/``. Ids become one chunk of a key expression, so they are held
to a small alphabet here: a ``/`` would add a level, ``*``, ``$``, ``?`` and ``#`` mean
something to Zenoh, and ``reference`` as a robot id would put a robot among the stations.
"""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass

from baromap.errors import ConfigError

ROOT = "baromap"
STATIONS = "reference"
ID_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


class Channel(enum.StrEnum):
    """What a node publishes; the value is the key's tail under the node's prefix."""

    EVENT = "floor/event"
    RIDE = "floor/ride"
    STATE = "floor/state"
    PRESSURE = "pressure"
    HEALTH = "health"
    ALIVE = "alive"


#: Channels a reference station has (a barometer only: no floors of its own).
STATION_CHANNELS = frozenset({Channel.PRESSURE, Channel.HEALTH, Channel.ALIVE})


def check_id(value: object, what: str) -> str:
    """``value`` as a robot or station id, or ConfigError naming ``what``."""
    if not isinstance(value, str) or not ID_PATTERN.fullmatch(value):
        raise ConfigError(
            f"{what}: {value!r} is not an id (1-64 of letters, digits, '_', '.', '-', "
            "starting with a letter or digit)"
        )
    return value


@dataclass(frozen=True, slots=True)
class NodeKeys:
    """The keys of one publishing node (a robot or a reference station)."""

    node: str
    station: bool = False

    @classmethod
    def robot(cls, robot_id: str) -> NodeKeys:
        check_id(robot_id, "robot id")
        if robot_id == STATIONS:
            raise ConfigError(f"robot id: {STATIONS!r} is reserved for reference stations")
        return cls(robot_id)

    @classmethod
    def reference(cls, station_id: str) -> NodeKeys:
        return cls(check_id(station_id, "station id"), station=True)

    @property
    def prefix(self) -> str:
        return f"{ROOT}/{STATIONS}/{self.node}" if self.station else f"{ROOT}/{self.node}"

    def key(self, channel: Channel) -> str:
        if self.station and channel not in STATION_CHANNELS:
            raise ConfigError(f"a reference station has no {channel.value!r} channel")
        return f"{self.prefix}/{channel.value}"


def robot_selector(channel: Channel, robot: str | None = None) -> str:
    """Key expression of ``channel`` for one robot, or for every robot when ``robot`` is None."""
    if robot is None:
        return f"{ROOT}/*/{channel.value}"
    return NodeKeys.robot(robot).key(channel)


def robot_of(key: str) -> str | None:
    """The robot a robot key belongs to (None for a station's key or a foreign key)."""
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != ROOT or parts[1] == STATIONS:
        return None
    return parts[1]
