"""The daemon's configuration: one TOML file, checked whole before anything opens a port.

Each table of the file is a :class:`Table`, a msgspec Struct: its fields are the table's keys,
their types and ``Meta`` constraints are the checks, and ``doc(...)`` says what a
key does and is the hint printed with its problems. msgspec stops at the first error, so the
file is handed to it one key at a time and every problem is collected with its dotted key: one
``--check-config`` run names all of them. Unknown keys are errors (a typo in ``rate_hz`` must
not silently leave the default in force). A key that fails takes its default, so the checks
across keys and tables still run. The ``[zenoh]`` and ``[reference]`` tables are handed
unparsed to the live publisher, which owns their meaning.

Adding a table ``[name]``:

1. Write ``class NameConfig(Table, frozen=True)`` with one field per key: its type (a
   ``Literal`` for a choice, ``Annotated[int, Meta(ge=1)]`` for a range), its default unless
   the key is required, and ``doc(...)``.
2. Give :class:`DaemonConfig` a field ``name: NameConfig | None = None`` (the daemon runs
   without it) or ``name: NameConfig = msgspec.field(default_factory=NameConfig)``.
3. A check that spans keys of the table goes in ``NameConfig.problems``; one across tables
   goes in :func:`_across_tables`.
4. Show the keys in systemd/baromapd.toml and docs/daemon.md.
"""

from __future__ import annotations

import contextlib
import dataclasses
import ipaddress
import math
import os
import tempfile
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import (
    Annotated,
    Any,
    ClassVar,
    Final,
    Literal,
    TypeVar,
    get_args,
    get_origin,
    get_type_hints,
)

import msgspec
from msgspec import Meta

from baromap.discovery import USB_IDENTITY
from baromap.errors import BaromapError, ConfigError
from baromap.floors import FloorDetectorConfig, load_building_model
from baromap.protocols import lms200
from baromap.protocols.baro import MAX_RATE_HZ
from baromap.protocols.robot_models import MODELS, find_model
from baromapd.live import config_problems

Role = Literal["robot", "station"]
ROLES: Final = get_args(Role)
#: (angle, resolution in degrees) -> (angle, resolution in hundredths of a degree).
LMS_VARIANTS: Final = {(a, r / 100): (a, r) for a, r in lms200.VARIANTS}
#: The choices below are the protocol's and the writer's; a test holds them equal.
LmsBaud = Literal[9600, 19200, 38400, 500000]
P2osBaud = Literal[9600, 19200, 38400, 57600, 115200]
Oversampling = Literal[1, 2, 4, 8, 16]  # baro.OVERSAMPLING_VALUES
IirFilter = Literal[0, 2, 4, 8, 16]  # baro.IIR_FILTER_VALUES
Compression = Literal["zstd", "lz4", "none"]  # recording.writer.COMPRESSIONS
LogLevel = Literal["debug", "info", "warning", "error"]


def doc(text: str) -> Meta:
    """What a key does: the reference of the setting, and the hint printed with its problems."""
    return Meta(description=text)


Positive = Annotated[float, Meta(gt=0)]
PositiveInt = Annotated[int, Meta(gt=0)]
#: Marks a field whose keys sit in its parent's table rather than in a table of their own.
SAME_TABLE: Final = Meta(extra={"same_table": True})

PORT_HINT: Final = (
    "a device path like /dev/baromap-laser, a URL like loop://, or 0403:6001[:SERIAL]"
)
ROBOT_HINT: Final = (
    "letters, digits, '-', '_' and '.': it names files and Zenoh keys, e.g. robot = \"p3at-01\""
)
START_FLOOR_HINT: Final = 'the floor the robot starts on, e.g. start_floor = "0" or "lobby"'
BUILDING_HINT: Final = (
    "a building.yaml written by `baromap build-maps` (floors: index, elevation_m, name); "
    "a relative path is taken from the configuration file's directory"
)


@dataclass(frozen=True, slots=True)
class Problem:
    """One thing wrong with a configuration: where, what, and how to fix it."""

    key: str
    message: str
    hint: str = ""

    def __str__(self) -> str:
        text = f"{self.key}: {self.message}"
        return f"{text} ({self.hint})" if self.hint else text


class ConfigProblems(ConfigError):
    """A configuration with one or more problems; ``problems`` lists them all."""

    def __init__(self, source: str, problems: list[Problem]) -> None:
        self.problems = problems
        lines = "\n".join(f"  {p}" for p in problems)
        super().__init__(f"{source}: {len(problems)} problem(s)\n{lines}")


class Table(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A table of the file (how to add one: the module docstring)."""

    #: Fields the daemon fills in itself; the file cannot set them.
    not_in_file: ClassVar[frozenset[str]] = frozenset()

    def problems(self) -> Iterator[Problem]:
        """What is wrong across this table's keys (keys relative to the table)."""
        return iter(())


# ---------------------------------------------------------------------------------------------
# The tables
# ---------------------------------------------------------------------------------------------


class Retry(Table, frozen=True, rename={"initial_s": "retry_initial_s", "max_s": "retry_max_s"}):
    """How a failed device is retried: capped exponential backoff, and what counts as failed.

    Its keys sit in the device's table (``retry_initial_s = 0.5`` under ``[laser]``).
    """

    initial_s: Annotated[Positive, doc("reconnect backoff doubles from here")] = 0.5
    max_s: Annotated[Positive, doc("...up to here")] = 30.0
    silence_s: Annotated[Positive, doc("no good frame for this long: the device is silent")] = 2.0
    garbage_s: Annotated[Positive, doc("bytes, no good frame for this long: garbage")] = 2.0

    def problems(self) -> Iterator[Problem]:
        if self.max_s < self.initial_s:
            yield Problem("retry_max_s", f"{self.max_s} is below retry_initial_s {self.initial_s}")


def port_problem(value: str) -> str | None:
    """Why ``value`` cannot name a port (a path, a pyserial URL, or vid:pid[:serial])."""
    if not value.strip():
        return "must not be empty"
    if value.startswith("/") or "://" in value or USB_IDENTITY.match(value):
        return None
    return f"{value!r} is neither a path, a pyserial URL, nor a USB identity vid:pid[:serial]"


class _Device(Table, frozen=True):
    """What every device table has: where it is and how it is retried."""

    port: Annotated[str, doc(PORT_HINT)]
    usb_reset: Annotated[
        bool, doc("reset its USB adapter (pyusb) when it stops answering after a reconnect")
    ] = False

    def problems(self) -> Iterator[Problem]:
        message = port_problem(self.port)
        if message:
            yield Problem("port", message, PORT_HINT)


class Mount(Table, frozen=True):
    """Where the laser sits on the base (base_link frame)."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_deg: float = 0.0

    @property
    def yaw_rad(self) -> float:
        return math.radians(self.yaw_deg)


class LaserConfig(_Device, frozen=True):
    """``[laser]``: a SICK LMS200."""

    baud: Annotated[LmsBaud, doc("RS-232: 9600, 19200, 38400; RS-422: 500000")] = 38400
    angle_deg: Literal[100, 180] = 180
    resolution_deg: Annotated[float, doc("1.0, 0.5 or 0.25 (0.25 at 100 deg)")] = 1.0
    units: Annotated[lms200.Units, doc("mm: 8 m, cm: 80 m")] = "mm"
    mount: Annotated[Mount, doc("x_m, y_m, yaw_deg of the laser on the base")] = Mount()
    restore_9600: Annotated[bool, doc("leave it at 9600 baud on stop, where it powers up")] = True
    retry: Annotated[Retry, SAME_TABLE] = Retry(silence_s=1.0)

    @property
    def resolution_cdeg(self) -> int:
        return round(self.resolution_deg * 100)

    def problems(self) -> Iterator[Problem]:
        yield from super().problems()
        if self.resolution_deg not in (0.25, 0.5, 1.0):
            yield Problem("resolution_deg", f"{self.resolution_deg} is not one of [0.25, 0.5, 1.0]")
        elif (self.angle_deg, self.resolution_deg) not in LMS_VARIANTS:
            yield Problem(
                "resolution_deg",
                f"no LMS200 variant {self.angle_deg} deg at {self.resolution_deg} deg",
            )


MODEL_HINT: Final = f'"auto" takes the robot\'s SYNC2 subclass; models: {", ".join(sorted(MODELS))}'


class BaseConfig(_Device, frozen=True):
    """``[base]``: a Pioneer (P2OS / ARCOS)."""

    baud: P2osBaud = 9600
    model: Annotated[str, doc(MODEL_HINT)] = "auto"
    allow_model_mismatch: Annotated[bool, doc("a pinned model wins over the robot's")] = False
    enable_motors: Annotated[bool, doc("the daemon records; it never drives unless told")] = False
    retry: Annotated[Retry, SAME_TABLE] = Retry()

    def __post_init__(self) -> None:
        # "auto" or a model name, written as the robot reports it (case does not matter).
        msgspec.structs.force_setattr(self, "model", self.model.strip().lower())

    def problems(self) -> Iterator[Problem]:
        yield from super().problems()
        if self.model != "auto" and find_model(self.model) is None:
            yield Problem("model", f"no parameter set for robot model {self.model!r}", MODEL_HINT)


class BarometerConfig(_Device, frozen=True):
    """``[barometer]``: the barometer board (firmware/)."""

    baud: PositiveInt = 115200
    rate_hz: Annotated[int, Meta(ge=1, le=MAX_RATE_HZ), doc("samples per second")] = 50
    oversampling: Annotated[Oversampling, doc("pressure oversampling")] = 16
    temperature_oversampling: Oversampling = 2
    iir_filter: Annotated[IirFilter, doc("the sensor's IIR filter coefficient")] = 16
    retry: Annotated[Retry, SAME_TABLE] = Retry()


class RecordingConfig(Table, frozen=True):
    """``[recording]``: where and how runs are written."""

    directory: Path = Path("/var/lib/baromapd")
    rotate_size_mb: Annotated[Positive, doc("start a new file past this size")] = 1024.0
    rotate_minutes: Annotated[Positive, doc("...or this age")] = 60.0
    compression: Annotated[Compression, doc("zstd: smallest, lz4: cheapest on the CPU")] = "zstd"
    min_free_mb: Annotated[float, Meta(ge=0), doc("stop writing below this free disk")] = 200.0
    flush_interval_s: Annotated[float, Meta(gt=0, le=1), doc("what a power cut loses")] = 1.0
    queue_size: Annotated[PositiveInt, doc("messages waiting; beyond it, counted drops")] = 8192


ADDRESS_HINT: Final = (
    '"127.0.0.1" keeps the view on this machine; "0.0.0.0" (or one interface\'s address) '
    "opens it to the network"
)


class LiveViewConfig(Table, frozen=True):
    """``[live_view]``: the Foxglove WebSocket server a person watches the robot on."""

    enabled: Annotated[bool, doc("serve the recorded channels and a live map while running")] = True
    address: Annotated[str, doc(ADDRESS_HINT)] = "127.0.0.1"
    port: Annotated[int, Meta(ge=1, le=65535), doc("viewers connect to ws://address:port")] = 8765
    resolution_m: Annotated[
        float, Meta(ge=0.02, le=0.5), doc("the live map's cell, m (post-run maps: 0.05)")
    ] = 0.1

    def problems(self) -> Iterator[Problem]:
        try:
            ipaddress.ip_address(self.address)
        except ValueError:
            yield Problem("address", f"{self.address!r} is not an IP address", ADDRESS_HINT)


class DaemonConfig(Table, frozen=True):
    """The whole file: top-level keys, then one field per table."""

    robot: Annotated[str, Meta(pattern=r"^[A-Za-z0-9_.-]+$"), doc(ROBOT_HINT)]
    role: Annotated[Role, doc("a station records a barometer only")] = "robot"
    recording: RecordingConfig = msgspec.field(default_factory=RecordingConfig)
    laser: LaserConfig | None = None
    base: BaseConfig | None = None
    barometer: BarometerConfig | None = None
    floors: FloorDetectorConfig = msgspec.field(default_factory=FloorDetectorConfig)
    #: ``[zenoh]`` and ``[reference]`` as written, for the live publisher (None when absent).
    zenoh: dict[str, Any] | None = None
    reference: dict[str, Any] | None = None
    live_view: LiveViewConfig = msgspec.field(default_factory=LiveViewConfig)
    log_level: LogLevel = "info"
    #: The file's text, recorded in every recording's metadata.
    source_text: str = ""

    not_in_file: ClassVar[frozenset[str]] = frozenset({"source_text"})

    def devices(self) -> list[tuple[str, LaserConfig | BaseConfig | BarometerConfig]]:
        """(name, settings) of each configured device."""
        named = (("laser", self.laser), ("base", self.base), ("barometer", self.barometer))
        return [(name, device) for name, device in named if device is not None]


# ---------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------

#: A value that failed its check (its problem is already recorded).
_INVALID: Final = object()
_T = TypeVar("_T", bound=Table)


def _bare(annotation: Any) -> Any:
    """The type without Annotated and without ``| None``."""
    if get_origin(annotation) is Annotated:
        annotation = get_args(annotation)[0]
    args = [a for a in get_args(annotation) if a is not type(None)]
    if type(None) in get_args(annotation) and len(args) == 1:
        return _bare(args[0])
    return annotation


def _hint(annotation: Any) -> str:
    metadata = getattr(annotation, "__metadata__", ())
    return "; ".join(m.description for m in metadata if m.description)


def _message(exc: msgspec.ValidationError, value: Any, annotation: Any) -> str:
    """msgspec's message, with the value it refused when msgspec does not say it."""
    bare = _bare(annotation)
    if get_origin(bare) is Literal:
        return f"{value!r} is not one of {list(get_args(bare))}"
    message = str(exc)
    return message if ", got " in message else f"{message}, got {value!r}"


def _decode_other(kind: type, value: Any) -> Any:
    """What msgspec does not convert by itself: a path, written as a string."""
    if kind is Path and isinstance(value, str):
        return Path(value)
    raise TypeError(f"Expected `str` (a path), got `{type(value).__name__}`")


class _Reading:
    """Hands the file to msgspec key by key and remembers every problem."""

    def __init__(self, directory: Path | None) -> None:
        self.directory = directory
        self.problems: list[Problem] = []

    def problem(self, key: str, message: str, hint: str = "") -> None:
        self.problems.append(Problem(key, message, hint))

    def table(
        self, kind: type[_T], data: dict[str, Any], prefix: str, base: _T | None = None
    ) -> _T | None:
        """``kind`` read from ``data`` and checked across its keys; None when a required key is
        missing or wrong. Keys ``data`` lacks are ``base``'s (the defaults when None)."""
        values, complete = self.values(kind, data, prefix)
        if not complete:
            return None
        table = msgspec.structs.replace(base, **values) if base is not None else kind(**values)
        for p in table.problems():
            self.problem(prefix + p.key, p.message, p.hint)
        return table

    def values(
        self, kind: type[Table], data: dict[str, Any], prefix: str
    ) -> tuple[dict[str, Any], bool]:
        """The valid values of ``data`` by field name, and whether every required key is."""
        hints = get_type_hints(kind, include_extras=True)
        values: dict[str, Any] = {}
        known: list[str] = []
        complete = True
        for info in msgspec.structs.fields(kind):
            if info.name in kind.not_in_file:
                continue
            annotation = hints[info.name]
            if SAME_TABLE in getattr(annotation, "__metadata__", ()):
                inner = _bare(annotation)
                keys = [f.encode_name for f in msgspec.structs.fields(inner)]
                known += keys
                own = {k: data[k] for k in keys if k in data}
                value = self.table(inner, own, prefix, info.default) or _INVALID
            elif info.encode_name in data:
                known.append(info.encode_name)
                value = self.value(annotation, data[info.encode_name], prefix + info.encode_name)
            else:
                known.append(info.encode_name)
                if info.required:
                    self.problem(prefix + info.encode_name, "is required", _hint(annotation))
                    complete = False
                continue
            if value is _INVALID:
                complete = complete and not info.required
            else:
                values[info.name] = value
        for key in data:
            if key not in known:
                self.problem(prefix + key, "unknown key", f"known here: {', '.join(known)}")
        return values, complete

    def value(self, annotation: Any, raw: Any, key: str) -> Any:
        """``raw`` as ``annotation`` says, or _INVALID with its problem recorded."""
        hint = _hint(annotation)
        bare = _bare(annotation)
        is_table = bare is FloorDetectorConfig or get_origin(bare) is dict or _is_table(bare)
        if is_table and not isinstance(raw, dict):
            self.problem(key, f"must be a table, not {type(raw).__name__}", hint)
            return _INVALID
        if bare is FloorDetectorConfig:  # the library's own class, checked by the library
            return _floors(self, raw, key + ".")
        if _is_table(bare):
            return self.table(bare, raw, key + ".") or _INVALID
        try:
            value = msgspec.convert(raw, annotation, dec_hook=_decode_other)
        except msgspec.ValidationError as exc:
            self.problem(key, _message(exc, raw, annotation), hint)
            return _INVALID
        if isinstance(value, float) and not math.isfinite(value):
            self.problem(key, f"must be finite, not {value!r}", hint)
            return _INVALID
        return value


def _is_table(kind: Any) -> bool:
    return isinstance(kind, type) and issubclass(kind, Table)


def _floors(reading: _Reading, data: dict[str, Any], prefix: str) -> Any:
    """``[floors]``: the detector's own settings (the library checks them), with the building
    model given as the path of its file."""
    names = [f.name for f in dataclasses.fields(FloorDetectorConfig)]
    types = get_type_hints(FloorDetectorConfig)
    values: dict[str, Any] = {}
    for key, raw in data.items():
        if key not in names:
            reading.problem(prefix + key, "unknown key", f"known here: {', '.join(names)}")
        elif key == "building":
            values[key] = _building(reading, raw, prefix + key)
        elif key == "start_floor":
            name = reading.value(Annotated[str, doc(START_FLOOR_HINT)], raw, prefix + key)
            if isinstance(name, str) and not name.strip():
                reading.problem(prefix + key, "must not be empty", START_FLOOR_HINT)
            else:
                values[key] = name
        else:
            values[key] = reading.value(types[key], raw, prefix + key)
    try:
        return FloorDetectorConfig(**{k: v for k, v in values.items() if v is not _INVALID})
    except ConfigError as exc:
        # The detector names the setting first ("start_floor 'x' is not a floor of ...").
        first = str(exc).split(" ", 1)[0]
        key = prefix + first if first in names else prefix.rstrip(".")
        hint = {"start_floor": START_FLOOR_HINT, "building": BUILDING_HINT}.get(first, "")
        reading.problem(key, str(exc), hint)
        return FloorDetectorConfig()


def _building(reading: _Reading, raw: Any, key: str) -> Any:
    name = reading.value(Annotated[str, doc(BUILDING_HINT)], raw, key)
    if name is _INVALID:
        return _INVALID
    path = Path(name)
    if not path.is_absolute() and reading.directory is not None:
        path = reading.directory / path
    try:
        return load_building_model(path)
    except BaromapError as exc:
        reading.problem(key, str(exc), BUILDING_HINT)
        return _INVALID


DEVICES: Final = ("laser", "base", "barometer")


def _across_tables(reading: _Reading, values: dict[str, Any]) -> None:
    """Checks that need more than one table (``values``: what was read, by field name)."""
    robot, role = values.get("robot", ""), values.get("role", "robot")
    for key, message in config_problems(
        values.get("zenoh"), values.get("reference"), robot=robot, role=role
    ):
        reading.problem(key, message)
    devices = {name: values[name] for name in DEVICES if values.get(name) is not None}
    if role == "station" and devices.keys() & {"laser", "base"}:
        reading.problem("role", "a station records a barometer only", "remove [laser] and [base]")
    if not devices and not reading.problems:
        reading.problem("<file>", "no device configured", "add [laser], [base] and/or [barometer]")
    seen: dict[str, str] = {}
    for name, device in devices.items():
        if device.port in seen and "://" not in device.port:
            reading.problem(f"{name}.port", f"{device.port!r} is also {seen[device.port]}.port")
        seen.setdefault(device.port, name)


def parse_config(
    text: str, source: str = "<config>", directory: Path | None = None
) -> DaemonConfig:
    """The configuration in ``text``, or :class:`ConfigProblems` naming every problem.

    ``directory`` is where the file lives: relative paths in it (``floors.building``) are
    taken from there (the working directory when None).
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigProblems(source, [Problem("<file>", f"not valid TOML: {exc}")]) from exc
    reading = _Reading(directory)
    values, _ = reading.values(DaemonConfig, data, "")
    _across_tables(reading, values)
    if reading.problems:
        raise ConfigProblems(source, reading.problems)
    return DaemonConfig(**values, source_text=text)


def load_config(path: str | Path) -> DaemonConfig:
    """The configuration of the file at ``path``, checked against this machine too: its
    recording directory must exist or be creatable, and be writable (what ``--check-config``
    and the daemon's start need; :func:`parse_config` alone looks at the text only)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigProblems(str(path), [Problem("<file>", f"cannot read: {exc}")]) from exc
    config = parse_config(text, str(path), path.parent)
    unusable = directory_problem(config.recording.directory)
    if unusable is not None:
        problem = Problem("recording.directory", unusable, DIRECTORY_HINT)
        raise ConfigProblems(str(path), [problem])
    return config


DIRECTORY_HINT: Final = (
    "a writable directory, or one that can be created; the unit's is its StateDirectory"
)


def directory_problem(directory: Path) -> str | None:
    """Why recordings cannot be written into ``directory`` (None: they can).

    It is tried, not inferred from permission bits: a directory is made where it is missing
    and a file created in it (both removed again), so a read-only file system, a path under a
    file or under ``/proc``, and root's own limits are all found.
    """
    missing = []
    existing = directory
    while not existing.exists() and existing.parent != existing:
        missing.append(existing)
        existing = existing.parent
    if not existing.is_dir():
        return f"{existing} is not a directory"
    try:
        for made in reversed(missing):
            made.mkdir()
        fd, probe = tempfile.mkstemp(dir=directory, prefix=".baromapd-check-")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        what = "cannot be created" if missing else "is not writable"
        return f"{directory} {what}: {exc.strerror or exc}"
    finally:
        for made in missing:
            with contextlib.suppress(OSError):
                made.rmdir()
    return None
