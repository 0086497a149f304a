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


def usable_beams(
    ranges_m: npt.NDArray[np.float32], flags: npt.NDArray[np.uint16]
) -> npt.NDArray[np.bool_]:
    """Beams (of one scan, or of many stacked) that carry a usable range: no error flag and
    a finite range."""
    ok: npt.NDArray[np.bool_] = ((flags & BeamFlag.error_mask()) == 0) & np.isfinite(ranges_m)
    return ok


def _frozen_array(values: npt.ArrayLike, dtype: type[np.generic]) -> npt.NDArray[np.generic]:
    """A read-only array of ``dtype`` nobody else can write to: ``values`` itself if it is one
    already (read-only, of that type, owning its memory: a decoder that froze what it made),
    else a frozen copy. The laser makes 75 scans a second; two copies each are not free."""
    if (
        isinstance(values, np.ndarray)
        and values.dtype == dtype
        and not values.flags.writeable
        and values.flags.owndata
    ):
        return values
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
        return usable_beams(self.ranges_m, self.flags)

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


class FloorEventKind(enum.StrEnum):
    """Whether an event is a new decision or the revision of an earlier one."""

    #: A floor change, decided once the robot's stop at the new level counts as a visit.
    TRANSITION = "transition"
    #: A revised version of the transition named by ``replaces`` (a trip that went on past a
    #: landing, a floor found to be one already known): it stands in that event's place.
    CORRECTION = "correction"
    #: The transition named by ``replaces`` did not happen (the car went on and brought the
    #: robot back to the floor it left, without the robot leaving it): it is withdrawn.
    RETRACTION = "retraction"


@dataclass(frozen=True, slots=True)
class FloorEvent:
    """A floor change decided by the live detector, or a correction of one.

    Floor events are final or explicitly corrected: a consumer keeps the transitions by
    ``event_id`` and, on a correction, puts it in the place of the event named by ``replaces``
    (which may itself be a correction). Replaying the same samples (and odometry) in the same
    order gives the same events, ids included. ``event_id`` is unique and increasing within a
    run (the first event is 1).

    Floors are named by stable ids: ``from_id``/``to_id`` never change meaning during a run
    (the start floor is 0, later floors are numbered in the order they are first visited; an
    id whose floor turned out to be another one is not reused). ``from_name``/``to_name`` are
    the floors' names (the configured start floor, or from a known building model), and
    ``height_m`` is the height of ``to_id`` above the start floor as the detector knows it at
    ``t_ns``.

    ``t_start_ns`` .. ``t_end_ns`` bound the pressure change (the whole trip, landings and
    stops in the car included; ``t_end_ns`` is when the pressure came to rest at the new
    level); ``t_ns`` is when the detector decided, never before ``t_end_ns``: at the car's
    stop when the robot rode in it (odometry), else once the robot drove off or stayed long
    enough there. ``delta_pa``/``delta_m`` are the measured step, ``level_pa`` the pressure
    of the new floor at ``t_ns`` (reference-station correction undone). ``at_end`` says the
    input ended before the decision could be taken on a settled, confirmed stop.
    ``estimated_name`` says ``to_name`` was counted in storeys from a named floor (no
    building model placed it): a name a person could give otherwise, though never changed.

    A ``RETRACTION`` repeats the withdrawn transition's fields (its own ``event_id``,
    ``t_ns`` and ``replaces``): applying it removes that transition from the account.
    """

    t_ns: int
    event_id: int
    kind: FloorEventKind
    replaces: int | None
    t_start_ns: int
    t_end_ns: int
    from_id: int
    to_id: int
    from_name: str
    to_name: str
    height_m: float
    delta_pa: float
    delta_m: float
    level_pa: float
    at_end: bool = False
    estimated_name: bool = False


class FloorPhase(enum.StrEnum):
    """What the detector currently believes about vertical motion."""

    #: No settled pressure yet (the start of a run).
    UNKNOWN = "unknown"
    #: On ``FloorState.floor_id`` (possibly on a ramp or landing a little off its level).
    SETTLED = "settled"
    #: The pressure is changing: riding or climbing away from ``floor_id``.
    CHANGING = "changing"
    #: Stopped at a level at least a storey from ``floor_id`` during a ride, not yet a visit:
    #: the robot has not driven off (odometry) and has not stayed long enough (without it).
    STOPPED = "stopped"


@dataclass(frozen=True, slots=True)
class FloorState:
    """The live answer to "which floor are we on?".

    ``floor_id``/``name``/``height_m`` are the floor of the last decided visit (the start floor
    until the first transition; None/NaN before the pressure first settled), so the state
    never contradicts the events. ``level_m`` is the height of the current pressure level above
    the start floor (it moves during a ride). While ``phase`` is ``STOPPED`` the robot is
    stopped at a level during a ride: ``stop_floor_id``/``stop_name`` name the known floor at
    that level, if there is one (None otherwise, and in every other phase). ``since_ns`` is
    when the phase began; ``floors_known`` counts distinct floors visited so far.
    """

    t_ns: int
    phase: FloorPhase
    floor_id: int | None
    name: str | None
    height_m: float
    level_m: float
    level_pa: float
    since_ns: int
    floors_known: int
    stop_floor_id: int | None = None
    stop_name: str | None = None


class RideEventKind(enum.StrEnum):
    """Where a ride stands: announced, ended at a decided floor, or withdrawn."""

    #: The car (or the walker) began to move vertically away from ``from_id``.
    STARTED = "ride_started"
    #: The ride ended at ``to_id``: the floor event ``floor_event_id`` decided it.
    ENDED = "ride_ended"
    #: The announced ride was none (``reason`` says why): a transient, a ramp, a spike.
    RETRACTED = "ride_retracted"


class RideDirection(enum.StrEnum):
    UP = "up"
    DOWN = "down"


@dataclass(frozen=True, slots=True)
class RideEvent:
    """A ride announced as it starts, so a consumer can act before the floor is decided.

    ``ride_id`` numbers rides within a run (1, 2, ...); every event of one ride carries it.
    A ride is announced once (``STARTED``: ``direction``, the floor it left) and then either
    ends (``ENDED``: ``to_id``/``to_name`` of the floor decided, and ``floor_event_id``, the
    :class:`FloorEvent` that decided it, a transition or a correction) or is withdrawn
    (``RETRACTED``, with a ``reason``). A ride that turns the other way before it ends is
    withdrawn and announced again. Consumers that want only final floors ignore rides: the
    floor events alone are the account of the run.

    ``t_start_ns`` is when the vertical motion began (the last calm moment before it);
    ``t_ns`` when the event was published. ``estimated_name`` is as in :class:`FloorEvent`.
    """

    t_ns: int
    ride_id: int
    kind: RideEventKind
    direction: RideDirection
    t_start_ns: int
    from_id: int
    from_name: str
    to_id: int | None = None
    to_name: str | None = None
    floor_event_id: int | None = None
    estimated_name: bool = False
    reason: str = ""


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
    | RideEvent
    | FloorState
    | DeviceHealth
    | TruthPose
    | TruthFloor
)


def wrap_angle(theta: float) -> float:
    """Angle to (-pi, pi]."""
    wrapped = math.remainder(theta, math.tau)
    return math.pi if wrapped == -math.pi else wrapped
