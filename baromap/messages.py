"""Typed messages every part of baromap exchanges.

Time is always ``t_ns``: integer nanoseconds since the Unix epoch, on the host clock unless a
field says otherwise. Integers keep nanosecond stamps exact through MCAP and JSON, where
float seconds would round at about a quarter of a microsecond today.

Messages are frozen and slotted: they cross threads (reader -> recorder, detector, publisher)
and must never be mutated on the way. Arrays inside a :class:`LaserScan` are made read-only
for the same reason.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

NS_PER_S = 1_000_000_000


def seconds(t_ns: int) -> float:
    """Nanosecond stamp to float seconds (for printing and plotting only)."""
    return t_ns / NS_PER_S


@dataclass(frozen=True, slots=True)
class PressureSample:
    """One barometer reading.

    ``seq`` and ``device_time_us`` come from the firmware's frame (wrapping counters of the
    board), so gaps and clock drift can be measured after the fact.
    """

    t_ns: int
    pressure_pa: float
    temperature_c: float | None = None
    seq: int | None = None
    device_time_us: int | None = None


class BeamFlag(enum.IntFlag):
    """Per-beam flags of a laser scan.

    Bits 0-2 carry the LMS200's three raw flag bits (bits 13-15 of each range word, field A/B
    and dazzle in the default mode). The upper bits say why a beam has no range: the sensor
    reports these as reserved range values, kept here so maps can treat "nothing within
    range" differently from "dazzled".
    """

    NONE = 0
    RAW_BIT13 = 1 << 0
    RAW_BIT14 = 1 << 1
    RAW_BIT15 = 1 << 2
    INVALID = 1 << 8
    DAZZLE = 1 << 9
    OVERFLOW = 1 << 10
    LOW_SNR = 1 << 11
    CHANNEL_ERROR = 1 << 12
    OVER_RANGE = 1 << 13

    @classmethod
    def error_mask(cls) -> int:
        """Flags that mean the beam carries no range."""
        return int(
            cls.INVALID
            | cls.DAZZLE
            | cls.OVERFLOW
            | cls.LOW_SNR
            | cls.CHANNEL_ERROR
            | cls.OVER_RANGE
        )


def _frozen_array(values: npt.ArrayLike, dtype: type[np.generic]) -> npt.NDArray[np.generic]:
    array = np.array(values, dtype=dtype, copy=True)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, slots=True, eq=False)
class LaserScan:
    """One planar scan, counter-clockwise from ``angle_min_rad`` in the laser's frame.

    ``ranges_m`` is float32 metres with NaN where the beam carries an error code; ``flags`` (one
    uint16 per beam, :class:`BeamFlag`) says which. ``status`` is the sensor's status byte.
    """

    t_ns: int
    angle_min_rad: float
    angle_increment_rad: float
    range_max_m: float
    ranges_m: npt.NDArray[np.float32]
    flags: npt.NDArray[np.uint16]
    status: int = 0
    scan_index: int | None = None
    range_min_m: float = 0.0

    def __post_init__(self) -> None:
        ranges = _frozen_array(self.ranges_m, np.float32)
        flags = _frozen_array(self.flags, np.uint16)
        if ranges.ndim != 1 or flags.shape != ranges.shape:
            raise ValueError(
                f"ranges {ranges.shape} and flags {flags.shape} must be equal 1-D arrays"
            )
        object.__setattr__(self, "ranges_m", ranges)
        object.__setattr__(self, "flags", flags)

    @property
    def beam_count(self) -> int:
        return int(self.ranges_m.shape[0])

    @property
    def angle_max_rad(self) -> float:
        return self.angle_min_rad + self.angle_increment_rad * (self.beam_count - 1)

    def angles_rad(self) -> npt.NDArray[np.float64]:
        return self.angle_min_rad + self.angle_increment_rad * np.arange(
            self.beam_count, dtype=np.float64
        )

    def valid(self) -> npt.NDArray[np.bool_]:
        """Beams that carry a usable range."""
        ok: npt.NDArray[np.bool_] = ((self.flags & BeamFlag.error_mask()) == 0) & np.isfinite(
            self.ranges_m
        )
        return ok

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, LaserScan):
            return NotImplemented
        return (
            self.t_ns == other.t_ns
            and self.angle_min_rad == other.angle_min_rad
            and self.angle_increment_rad == other.angle_increment_rad
            and self.range_max_m == other.range_max_m
            and self.range_min_m == other.range_min_m
            and self.status == other.status
            and self.scan_index == other.scan_index
            and np.array_equal(self.ranges_m, other.ranges_m, equal_nan=True)
            and np.array_equal(self.flags, other.flags)
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, slots=True)
class Odometry:
    """Wheel odometry of the base in its ``odom`` frame.

    The pose is integrated on the host (see the P2OS integrator) from ``raw_*``: the robot's
    own 15-bit position counters and 12-bit heading, kept so the integration can be redone
    with other conversion factors if the robot model was configured wrong.
    """

    t_ns: int
    x_m: float
    y_m: float
    theta_rad: float
    v_mps: float = 0.0
    omega_radps: float = 0.0
    raw_x: int = 0
    raw_y: int = 0
    raw_theta: int = 0


@dataclass(frozen=True, slots=True)
class FloorEvent:
    """A detected floor change.

    ``t_start_ns`` .. ``t_end_ns`` bound the pressure change; ``t_ns`` is when the detector
    decided (never before ``t_end_ns``: the online detector is causal). Floors are indices
    ordered by height, 0 = lowest visited so far (indices may shift as lower floors are
    found; ``level_pa`` identifies the new floor's settled pressure).
    """

    t_ns: int
    t_start_ns: int
    t_end_ns: int
    from_floor: int
    to_floor: int
    delta_pa: float
    delta_m: float
    level_pa: float


class FloorPhase(enum.StrEnum):
    """What the detector currently believes about vertical motion."""

    UNKNOWN = "unknown"
    SETTLED = "settled"
    CHANGING = "changing"


@dataclass(frozen=True, slots=True)
class FloorState:
    """The live answer to "which floor are we on?"."""

    t_ns: int
    floor: int | None
    phase: FloorPhase
    level_pa: float
    elevation_m: float
    floors_known: int
    since_ns: int


class DeviceState(enum.StrEnum):
    STARTING = "starting"
    UP = "up"
    DEGRADED = "degraded"
    DOWN = "down"


@dataclass(frozen=True, slots=True)
class DeviceHealth:
    """Health of one device session; counters are cumulative since the daemon started."""

    t_ns: int
    device: str
    state: DeviceState
    port: str = ""
    detail: str = ""
    counters: Mapping[str, int] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class TruthPose:
    """Ground truth from the simulator: where the robot really was (never from hardware)."""

    t_ns: int
    x_m: float
    y_m: float
    theta_rad: float
    floor: int
    z_m: float


@dataclass(frozen=True, slots=True)
class TruthFloor:
    """Ground truth floor from the simulator; ``floor`` is None while between floors."""

    t_ns: int
    floor: int | None
    z_m: float


Message = (
    PressureSample
    | LaserScan
    | Odometry
    | FloorEvent
    | FloorState
    | DeviceHealth
    | TruthPose
    | TruthFloor
)


def wrap_angle(theta: float) -> float:
    """Angle to (-pi, pi]."""
    wrapped = math.remainder(theta, math.tau)
    return math.pi if wrapped == -math.pi else wrapped
