"""The daemon's configuration: one TOML file, checked whole before anything opens a port.

Every problem is collected with its dotted key and a hint, so one ``--check-config`` run
names all of them instead of the first; unknown keys are errors (a typo in ``rate_hz`` must
not silently leave the default in force). The ``[zenoh]`` and ``[reference]`` tables are
handed unparsed to the live publisher, which owns their meaning.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Final, Literal

from baromap.discovery import USB_IDENTITY
from baromap.errors import BaromapError, ConfigError
from baromap.floors import FloorDetectorConfig, load_building_model
from baromap.protocols import baro, lms200
from baromap.protocols.robot_models import MODELS, find_model
from baromap.recording.writer import COMPRESSIONS
from baromapd.live import config_problems

Role = Literal["robot", "station"]
ROLES: Final = ("robot", "station")
LMS_VARIANTS: Final = {(a, r / 100): (a, r) for a, r in lms200.VARIANTS}


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


@dataclass(frozen=True, slots=True)
class Retry:
    """How a failed device is retried: capped exponential backoff, and what counts as failed."""

    initial_s: float = 0.5
    max_s: float = 30.0
    silence_s: float = 2.0  # no good frame for this long: the device is silent
    garbage_s: float = 2.0  # bytes but no good frame for this long: the line is garbage


@dataclass(frozen=True, slots=True)
class Mount:
    """Where the laser sits on the base (base_link frame), metres and radians."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0


@dataclass(frozen=True, slots=True)
class LaserConfig:
    port: str
    baud: int = 38400
    angle_deg: int = 180
    resolution_cdeg: int = 100
    units: lms200.Units = "mm"
    mount: Mount = field(default_factory=Mount)
    restore_9600: bool = True
    retry: Retry = field(default_factory=Retry)


@dataclass(frozen=True, slots=True)
class BaseConfig:
    port: str
    baud: int = 9600
    model: str = "auto"
    allow_model_mismatch: bool = False
    enable_motors: bool = False
    retry: Retry = field(default_factory=Retry)


@dataclass(frozen=True, slots=True)
class BarometerConfig:
    port: str
    baud: int = 115200
    rate_hz: int = 50
    oversampling: int = 16
    temperature_oversampling: int = 2
    iir_filter: int = 16
    retry: Retry = field(default_factory=Retry)


@dataclass(frozen=True, slots=True)
class RecordingConfig:
    directory: Path = Path("/var/lib/baromapd")
    rotate_size_mb: float = 1024.0
    rotate_minutes: float = 60.0
    compression: str = "zstd"
    min_free_mb: float = 200.0
    flush_interval_s: float = 1.0
    queue_size: int = 8192


@dataclass(frozen=True, slots=True)
class DaemonConfig:
    robot: str
    role: Role = "robot"
    recording: RecordingConfig = field(default_factory=RecordingConfig)
    laser: LaserConfig | None = None
    base: BaseConfig | None = None
    barometer: BarometerConfig | None = None
    floors: FloorDetectorConfig = field(default_factory=FloorDetectorConfig)
    #: ``[zenoh]`` and ``[reference]`` as written, for the live publisher (None when absent).
    zenoh: Mapping[str, Any] | None = None
    reference: Mapping[str, Any] | None = None
    log_level: str = "info"
    #: The file's text, recorded in every recording's metadata.
    source_text: str = ""

    def devices(self) -> list[tuple[str, LaserConfig | BaseConfig | BarometerConfig]]:
        """(name, settings) of each configured device."""
        named = (("laser", self.laser), ("base", self.base), ("barometer", self.barometer))
        return [(name, device) for name, device in named if device is not None]


# ---------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------

Check = Callable[[Any], str | None]


class _Reader:
    """Takes keys out of TOML tables, type-checks them, and remembers every problem."""

    def __init__(self) -> None:
        self.problems: list[Problem] = []

    def problem(self, key: str, message: str, hint: str = "") -> None:
        self.problems.append(Problem(key, message, hint))

    def table(self, data: Mapping[str, Any], key: str, prefix: str = "") -> dict[str, Any] | None:
        value = data.get(key)
        if value is None:
            return None
        if not isinstance(value, dict):
            self.problem(prefix + key, f"must be a table, not {type(value).__name__}")
            return None
        return dict(value)

    def take(  # noqa: PLR0917 (a table, its prefix, the key, its type and default read best in a row)
        self,
        data: dict[str, Any],
        prefix: str,
        key: str,
        kind: type | tuple[type, ...],
        default: Any,
        check: Check | None = None,
        hint: str = "",
    ) -> Any:
        if key not in data:
            return default
        value = data.pop(key)
        kinds = kind if isinstance(kind, tuple) else (kind,)
        ok = isinstance(value, kinds) and not (isinstance(value, bool) and bool not in kinds)
        if float in kinds and isinstance(value, int) and not isinstance(value, bool):
            value, ok = float(value), True
        if not ok:
            names = " or ".join(k.__name__ for k in kinds)
            self.problem(f"{prefix}{key}", f"must be {names}, not {value!r}", hint)
            return default
        if isinstance(value, float) and not math.isfinite(value):
            self.problem(f"{prefix}{key}", f"must be finite, not {value!r}", hint)
            return default
        if check is not None:
            message = check(value)
            if message:
                self.problem(f"{prefix}{key}", message, hint)
                return default
        return value

    def unknown(self, data: Mapping[str, Any], prefix: str, known: str) -> None:
        for key in data:
            self.problem(f"{prefix}{key}", "unknown key", f"known here: {known}")


def _positive(value: float) -> str | None:
    return None if value > 0 else f"must be positive, not {value}"


def _one_of(choices: tuple[Any, ...] | list[Any]) -> Check:
    def check(value: Any) -> str | None:
        return None if value in choices else f"{value!r} is not one of {list(choices)}"

    return check


def port_problem(value: str) -> str | None:
    """Why ``value`` cannot name a port (a path, a pyserial URL, or vid:pid[:serial])."""
    if not value.strip():
        return "must not be empty"
    if value.startswith("/") or "://" in value or USB_IDENTITY.match(value):
        return None
    return f"{value!r} is neither a path, a pyserial URL, nor a USB identity vid:pid[:serial]"


PORT_HINT = "a device path like /dev/baromap-laser, a URL like loop://, or 0403:6001[:SERIAL]"


def _retry(r: _Reader, data: dict[str, Any], prefix: str, silence_s: float) -> Retry:
    initial = r.take(data, prefix, "retry_initial_s", float, 0.5, _positive)
    cap = r.take(data, prefix, "retry_max_s", float, 30.0, _positive)
    if cap < initial:
        r.problem(prefix + "retry_max_s", f"{cap} is below retry_initial_s {initial}")
    silence = r.take(data, prefix, "silence_s", float, silence_s, _positive)
    garbage = r.take(data, prefix, "garbage_s", float, max(2.0, silence_s), _positive)
    return Retry(initial, cap, silence, garbage)


_RETRY_KEYS = "retry_initial_s, retry_max_s, silence_s, garbage_s"


def _laser(r: _Reader, data: dict[str, Any]) -> LaserConfig | None:
    p = "laser."
    port = r.take(data, p, "port", str, "", port_problem, PORT_HINT)
    bauds = sorted(lms200.BAUD_MODES)
    baud = r.take(data, p, "baud", int, 38400, _one_of(bauds), "the LMS200 speaks these only")
    angle = r.take(data, p, "angle_deg", int, 180, _one_of([100, 180]))
    resolution = r.take(data, p, "resolution_deg", float, 1.0, _one_of([0.25, 0.5, 1.0]))
    if (angle, resolution) not in LMS_VARIANTS:
        r.problem(p + "resolution_deg", f"no LMS200 variant {angle} deg at {resolution} deg")
    units = r.take(data, p, "units", str, "mm", _one_of(["mm", "cm"]), "mm: 8 m, cm: 80 m")
    mount_data = r.table(data, "mount", p)
    data.pop("mount", None)
    mount = Mount()
    if mount_data is not None:
        mp = p + "mount."
        x = r.take(mount_data, mp, "x_m", float, 0.0)
        y = r.take(mount_data, mp, "y_m", float, 0.0)
        yaw = r.take(mount_data, mp, "yaw_deg", float, 0.0)
        r.unknown(mount_data, mp, "x_m, y_m, yaw_deg")
        mount = Mount(x, y, math.radians(yaw))
    restore = r.take(data, p, "restore_9600", bool, True)
    retry = _retry(r, data, p, silence_s=1.0)
    r.unknown(
        data, p, f"port, baud, angle_deg, resolution_deg, units, mount, restore_9600, {_RETRY_KEYS}"
    )
    if not port:
        r.problem(p + "port", "is required", PORT_HINT)
        return None
    variant = LMS_VARIANTS.get((angle, resolution), (180, 100))
    return LaserConfig(port, baud, variant[0], variant[1], units, mount, restore, retry)


def _model_problem(value: str) -> str | None:
    if value.strip().lower() == "auto" or find_model(value) is not None:
        return None
    return f"no parameter set for robot model {value!r}"


def _base(r: _Reader, data: dict[str, Any]) -> BaseConfig | None:
    p = "base."
    port = r.take(data, p, "port", str, "", port_problem, PORT_HINT)
    baud = r.take(data, p, "baud", int, 9600, _one_of([9600, 19200, 38400, 57600, 115200]))
    model = r.take(
        data,
        p,
        "model",
        str,
        "auto",
        _model_problem,
        f'"auto" takes the robot\'s SYNC2 subclass; models: {", ".join(sorted(MODELS))}',
    )
    mismatch = r.take(data, p, "allow_model_mismatch", bool, False)
    motors = r.take(data, p, "enable_motors", bool, False)
    retry = _retry(r, data, p, silence_s=2.0)
    r.unknown(data, p, f"port, baud, model, allow_model_mismatch, enable_motors, {_RETRY_KEYS}")
    if not port:
        r.problem(p + "port", "is required", PORT_HINT)
        return None
    return BaseConfig(port, baud, model.strip().lower(), mismatch, motors, retry)


def _barometer(r: _Reader, data: dict[str, Any]) -> BarometerConfig | None:
    p = "barometer."
    port = r.take(data, p, "port", str, "", port_problem, PORT_HINT)
    baud = r.take(data, p, "baud", int, 115200, _positive)
    rate = r.take(
        data,
        p,
        "rate_hz",
        int,
        50,
        lambda v: None if 1 <= v <= baro.MAX_RATE_HZ else f"{v} is outside 1..{baro.MAX_RATE_HZ}",
    )
    osrs = list(baro.OVERSAMPLING_VALUES)
    osrs_p = r.take(data, p, "oversampling", int, 16, _one_of(osrs))
    osrs_t = r.take(data, p, "temperature_oversampling", int, 2, _one_of(osrs))
    iir = r.take(data, p, "iir_filter", int, 16, _one_of(list(baro.IIR_FILTER_VALUES)))
    retry = _retry(r, data, p, silence_s=2.0)
    r.unknown(
        data,
        p,
        f"port, baud, rate_hz, oversampling, temperature_oversampling, iir_filter, {_RETRY_KEYS}",
    )
    if not port:
        r.problem(p + "port", "is required", PORT_HINT)
        return None
    return BarometerConfig(port, baud, rate, osrs_p, osrs_t, iir, retry)


def _recording(r: _Reader, data: dict[str, Any]) -> RecordingConfig:
    p = "recording."
    directory = r.take(data, p, "directory", str, "/var/lib/baromapd")
    size = r.take(data, p, "rotate_size_mb", float, 1024.0, _positive)
    minutes = r.take(data, p, "rotate_minutes", float, 60.0, _positive)
    compression = r.take(
        data,
        p,
        "compression",
        str,
        "zstd",
        _one_of(list(COMPRESSIONS)),
        "zstd is smallest; lz4 costs the CPU less; none leaves chunks as written",
    )
    min_free = r.take(
        data, p, "min_free_mb", float, 200.0, lambda v: None if v >= 0 else "must not be negative"
    )
    flush = r.take(
        data,
        p,
        "flush_interval_s",
        float,
        1.0,
        lambda v: None if 0 < v <= 1.0 else f"{v} is outside (0, 1]",
        "DESIGN.md: a power cut loses at most about a second",
    )
    queue = r.take(data, p, "queue_size", int, 8192, _positive)
    r.unknown(
        data,
        p,
        "directory, rotate_size_mb, rotate_minutes, compression, min_free_mb, "
        "flush_interval_s, queue_size",
    )
    return RecordingConfig(Path(directory), size, minutes, compression, min_free, flush, queue)


#: Settings of the detector that are not numbers (the rest are floats).
_FLOOR_TEXT: Final = ("start_floor", "building")
START_FLOOR_HINT: Final = 'the floor the robot starts on, e.g. start_floor = "0" or "lobby"'
BUILDING_HINT: Final = (
    "a building.yaml written by `baromap build-maps` (floors: index, elevation_m, name); "
    "a relative path is taken from the configuration file's directory"
)


def _floors(r: _Reader, data: dict[str, Any], directory: Path | None) -> FloorDetectorConfig:
    p = "floors."
    names = [f.name for f in fields(FloorDetectorConfig)]
    values: dict[str, Any] = {
        name: r.take(data, p, name, float, None)
        for name in names
        if name in data and name not in _FLOOR_TEXT
    }
    values["start_floor"] = r.take(
        data,
        p,
        "start_floor",
        str,
        None,
        lambda v: None if v.strip() else "must not be empty",
        START_FLOOR_HINT,
    )
    building = r.take(data, p, "building", str, None, None, BUILDING_HINT)
    r.unknown(data, p, ", ".join(names))
    if building is not None:
        path = Path(building)
        if not path.is_absolute() and directory is not None:
            path = directory / path
        try:
            values["building"] = load_building_model(path)
        except BaromapError as exc:
            r.problem(p + "building", str(exc), BUILDING_HINT)
    try:
        return FloorDetectorConfig(**{k: v for k, v in values.items() if v is not None})
    except ConfigError as exc:
        # The detector names the setting first ("start_floor 'x' is not a floor of ...").
        first = str(exc).split(" ", 1)[0]
        key = p + first if first in names else "floors"
        hint = {"start_floor": START_FLOOR_HINT, "building": BUILDING_HINT}.get(first, "")
        r.problem(key, str(exc), hint)
        return FloorDetectorConfig()


_TOP_KEYS = "robot, role, log_level, recording, laser, base, barometer, floors, zenoh, reference"


def parse_config(
    text: str, source: str = "<config>", directory: Path | None = None
) -> DaemonConfig:
    """The configuration in ``text``, or :class:`ConfigProblems` naming every problem.

    ``directory`` is where the file lives: relative paths in it (``floors.building``) are
    taken from there (the working directory when None).
    """
    r = _Reader()
    try:
        data: dict[str, Any] = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigProblems(source, [Problem("<file>", f"not valid TOML: {exc}")]) from exc
    if "robot" not in data:
        r.problem("robot", "is required", 'e.g. robot = "p3at-01"')
    robot = r.take(
        data,
        "",
        "robot",
        str,
        "",
        lambda v: None if re.fullmatch(r"[A-Za-z0-9_.-]+", v) else f"{v!r} has other characters",
        "letters, digits, '-', '_' and '.': it names files and Zenoh keys",
    )
    role = r.take(data, "", "role", str, "robot", _one_of(list(ROLES)))
    level = r.take(
        data, "", "log_level", str, "info", _one_of(["debug", "info", "warning", "error"])
    )
    sections: dict[str, dict[str, Any] | None] = {}
    for name in ("recording", "laser", "base", "barometer", "floors", "zenoh", "reference"):
        sections[name] = r.table(data, name)
        data.pop(name, None)
    r.unknown(data, "", _TOP_KEYS)
    recording = _recording(r, sections["recording"] or {})
    laser = _laser(r, sections["laser"]) if sections["laser"] is not None else None
    base = _base(r, sections["base"]) if sections["base"] is not None else None
    barometer = _barometer(r, sections["barometer"]) if sections["barometer"] is not None else None
    floors = _floors(r, sections["floors"] or {}, directory)
    live = config_problems(sections["zenoh"], sections["reference"], robot=robot, role=role)
    for key, message in live:
        r.problem(key, message)
    if role == "station" and (laser is not None or base is not None):
        r.problem("role", "a station records a barometer only", "remove [laser] and [base]")
    if laser is None and base is None and barometer is None and not r.problems:
        r.problem("<file>", "no device configured", "add [laser], [base] and/or [barometer]")
    ports = [
        (n, d.port) for n, d in (("laser", laser), ("base", base), ("barometer", barometer)) if d
    ]
    seen: dict[str, str] = {}
    for name, port in ports:
        if port in seen and "://" not in port:
            r.problem(f"{name}.port", f"{port!r} is also {seen[port]}.port")
        seen.setdefault(port, name)
    if r.problems:
        raise ConfigProblems(source, r.problems)
    return DaemonConfig(
        robot=robot,
        role=role,
        recording=recording,
        laser=laser,
        base=base,
        barometer=barometer,
        floors=floors,
        zenoh=sections["zenoh"],
        reference=sections["reference"],
        log_level=level,
        source_text=text,
    )


def load_config(path: str | Path) -> DaemonConfig:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigProblems(str(path), [Problem("<file>", f"cannot read: {exc}")]) from exc
    return parse_config(text, str(path), path.parent)
