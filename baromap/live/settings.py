"""How a baromap node talks Zenoh: the ``[zenoh]`` and ``[reference]`` tables of a config.

The defaults keep a robot to itself until someone says otherwise: a Zenoh peer listening on
loopback only, with multicast scouting off, so nothing on the building's network can reach
the daemon (or be reached by it) by accident. A fleet is configured explicitly: client mode
towards zenohd routers, or peers listening on a chosen interface (see ``docs/zenoh.md``).

TLS certificates and access control are Zenoh's own configuration: ``config_file`` names a
Zenoh JSON5 file that is loaded first; the keys of this table are then applied over it, so a
file never silently moves what the table says (mode, endpoints, scouting).
"""

from __future__ import annotations

import enum
import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from baromap.errors import ConfigError
from baromap.live.keys import check_id

if TYPE_CHECKING:
    import zenoh

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"

#: Zenoh link protocols an endpoint may name (what zenohd's default build supports).
PROTOCOLS = frozenset(
    {"tcp", "udp", "tls", "quic", "ws", "unixsock-stream", "unixpipe", "serial", "vsock"}
)
#: Protocols whose address is host:port.
_HOST_PORT = frozenset({"tcp", "udp", "tls", "quic", "ws"})
_ZENOH_ORIGIN = re.compile(r"\s+at \S+\.rs:\d+\.?")


class ZenohMode(enum.StrEnum):
    """``peer``: talks to other peers and routers directly (the default, one machine or a
    small fleet on one network); ``client``: talks only through the routers it connects to."""

    PEER = "peer"
    CLIENT = "client"


def zenoh_message(exc: BaseException) -> str:
    """Zenoh's error text without the Rust source location it appends."""
    return _ZENOH_ORIGIN.sub("", str(exc)).strip()


def _check_endpoint(endpoint: object, key: str, *, listening: bool) -> str:
    if not isinstance(endpoint, str) or "/" not in endpoint:
        raise ConfigError(f"{key}: {endpoint!r} is not an endpoint like {DEFAULT_ENDPOINT!r}")
    protocol, address = endpoint.split("/", 1)
    address = re.split(r"[?#]", address, maxsplit=1)[0]
    if protocol not in PROTOCOLS:
        raise ConfigError(
            f"{key}: unknown protocol {protocol!r} in {endpoint!r} "
            f"(one of {', '.join(sorted(PROTOCOLS))})"
        )
    if protocol in _HOST_PORT:
        host, _, port = address.rpartition(":")
        lowest = 0 if listening else 1
        if not host or not port.isdigit() or not lowest <= int(port) <= 65535:
            raise ConfigError(f"{key}: {endpoint!r} needs a host and a port ({protocol}/HOST:PORT)")
    return endpoint


def _endpoints(value: object, key: str, *, listening: bool) -> tuple[str, ...]:
    if isinstance(value, str) or not isinstance(value, (list, tuple)):
        raise ConfigError(f"{key}: expected a list of endpoints, got {value!r}")
    return tuple(_check_endpoint(e, key, listening=listening) for e in value)


def _period(value: object, key: str, *, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{key}: expected a number of seconds, got {value!r}")
    if not (math.isfinite(value) and low <= value <= high):
        raise ConfigError(f"{key}: must be between {low:g} and {high:g} s, got {value!r}")
    return float(value)


@dataclass(frozen=True, slots=True)
class LiveSettings:
    """The ``[zenoh]`` table. Periods are of publishing; health is published each second."""

    enabled: bool = True
    mode: ZenohMode = ZenohMode.PEER
    #: Where a peer accepts connections. A client never listens (empty).
    listen: tuple[str, ...] = (DEFAULT_ENDPOINT,)
    #: Routers (client or peer) or peers (peer) to connect to.
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    #: A Zenoh JSON5 configuration loaded before the keys above (TLS, access control).
    config_file: Path | None = None
    #: Floor state is published on change and at least this often.
    state_period_s: float = 5.0
    #: Pressure is published as the mean of each period (decimated and smoothed).
    pressure_period_s: float = 0.2
    health_period_s: float = 1.0
    #: Messages waiting for the publisher; beyond this, new ones are dropped and counted.
    queue_size: int = 1024
    #: Longest wait between two attempts to open a session that failed to open.
    retry_max_s: float = 5.0
    #: Longest wait for the publisher to finish when it is stopped.
    stop_timeout_s: float = 15.0
    #: Section name errors are reported under (``zenoh.listen``).
    section: str = field(default="zenoh", compare=False)

    def __post_init__(self) -> None:
        s = self.section
        if not isinstance(self.enabled, bool):
            raise ConfigError(f"{s}.enabled: expected true or false, got {self.enabled!r}")
        try:
            object.__setattr__(self, "mode", ZenohMode(self.mode))
        except ValueError:
            raise ConfigError(f"{s}.mode: expected 'peer' or 'client', got {self.mode!r}") from None
        object.__setattr__(self, "listen", _endpoints(self.listen, f"{s}.listen", listening=True))
        object.__setattr__(
            self, "connect", _endpoints(self.connect, f"{s}.connect", listening=False)
        )
        if not isinstance(self.multicast_scouting, bool):
            raise ConfigError(
                f"{s}.multicast_scouting: expected true or false, got {self.multicast_scouting!r}"
            )
        if self.mode is ZenohMode.CLIENT and self.listen:
            raise ConfigError(f"{s}.listen: a client does not listen; use mode = 'peer'")
        if self.mode is ZenohMode.CLIENT and not (self.connect or self.multicast_scouting):
            raise ConfigError(
                f"{s}.connect: a client needs a router to connect to (or multicast scouting)"
            )
        if self.config_file is not None:
            path = Path(self.config_file)
            if not path.is_file():
                raise ConfigError(f"{s}.config_file: {str(path)!r} is not a readable file")
            object.__setattr__(self, "config_file", path)
        object.__setattr__(
            self,
            "state_period_s",
            _period(self.state_period_s, f"{s}.state_period_s", low=0.1, high=3600.0),
        )
        object.__setattr__(
            self,
            "pressure_period_s",
            _period(self.pressure_period_s, f"{s}.pressure_period_s", low=0.0, high=60.0),
        )
        object.__setattr__(
            self,
            "health_period_s",
            _period(self.health_period_s, f"{s}.health_period_s", low=0.1, high=3600.0),
        )
        object.__setattr__(
            self, "retry_max_s", _period(self.retry_max_s, f"{s}.retry_max_s", low=0.1, high=600)
        )
        object.__setattr__(
            self,
            "stop_timeout_s",
            _period(self.stop_timeout_s, f"{s}.stop_timeout_s", low=0.1, high=600),
        )
        size = self.queue_size
        if isinstance(size, bool) or not isinstance(size, int) or not 16 <= size <= 1_000_000:
            raise ConfigError(
                f"{s}.queue_size: expected an integer from 16 to 1000000, got {size!r}"
            )

    @classmethod
    def from_table(cls, table: Mapping[str, Any], *, section: str = "zenoh") -> LiveSettings:
        """Settings from a parsed TOML table; a client's ``listen`` defaults to none."""
        known = {f.name for f in fields(cls)} - {"section"}
        unknown = sorted(set(table) - known)
        if unknown:
            raise ConfigError(
                f"{section}.{unknown[0]}: unknown key (known: {', '.join(sorted(known))})"
            )
        values = dict(table)
        if values.get("mode") == ZenohMode.CLIENT and "listen" not in values:
            values["listen"] = ()
        if "config_file" in values:
            if not isinstance(values["config_file"], str):
                raise ConfigError(f"{section}.config_file: expected a path")
            values["config_file"] = Path(values["config_file"])
        return cls(**values, section=section)

    @classmethod
    def client(cls, connect: tuple[str, ...], config_file: Path | None = None) -> LiveSettings:
        """Settings of a tool that only looks (``baromap watch``): a client, listening nowhere."""
        return cls(mode=ZenohMode.CLIENT, listen=(), connect=connect, config_file=config_file)

    def zenoh_config(self) -> zenoh.Config:
        """The Zenoh configuration: ``config_file`` first, then this table's keys over it."""
        import zenoh

        s = self.section
        try:
            config = (
                zenoh.Config.from_file(self.config_file) if self.config_file else zenoh.Config()
            )
        except zenoh.ZError as exc:
            raise ConfigError(f"{s}.config_file: {zenoh_message(exc)}") from None
        for key, value, name in (
            ("mode", self.mode.value, "mode"),
            ("listen/endpoints", list(self.listen), "listen"),
            ("connect/endpoints", list(self.connect), "connect"),
            ("scouting/multicast/enabled", self.multicast_scouting, "multicast_scouting"),
            # Payloads are a few hundred bytes of JSON: a shared-memory segment per process
            # would buy nothing and leave a /dev/shm mapping behind each process.
            ("transport/shared_memory/enabled", False, "config_file"),
        ):
            try:
                config.insert_json5(key, json.dumps(value))
            except zenoh.ZError as exc:
                raise ConfigError(f"{s}.{name}: {zenoh_message(exc)}") from None
        return config


@dataclass(frozen=True, slots=True)
class ReferenceSettings:
    """The ``[reference]`` table of a robot: the station whose pressure change is weather."""

    station: str

    def __post_init__(self) -> None:
        check_id(self.station, "reference.station")

    @classmethod
    def from_table(cls, table: Mapping[str, Any]) -> ReferenceSettings:
        unknown = sorted(set(table) - {"station"})
        if unknown:
            raise ConfigError(f"reference.{unknown[0]}: unknown key (known: station)")
        if "station" not in table:
            raise ConfigError("reference.station: missing (the id of the reference station)")
        return cls(station=table["station"])
