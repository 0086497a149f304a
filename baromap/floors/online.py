"""The online floor detector: pressure samples (and odometry) in, floor events out, causally.

How it decides, and why:

1. A Holt (double exponential) smoother with *time-based* gains gives the pressure level and
   its rate in Pa/s, so irregular sample spacing does not change its behaviour. It decides
   when a change begins. A plain exponential average with the same level constant (no trend,
   so it never overshoots a stop) is the "smoothed pressure" the end of a change is judged on.
2. While settled on a floor, slow changes are weather: the floor's level follows them with a
   critically damped second-order tracker (level and drift rate; no lag on a steady drift),
   its drift rate clipped to what weather can do.
3. A change *begins* when the Holt level leaves the tracked level by ``start_m`` or moves
   faster than ``start_rate_m_s``. From then on the floor's level is only extrapolated with
   the drift rate; nothing the robot does moves it.
4. The change *ends* when the last ``settle_s`` seconds (all after the change began) were
   still (:class:`~baromap.floors.still_window.StillWindow`): the smoothed pressure stayed
   within the band a vertical speed of ``settle_rate_m_s`` would cross in that time, and the
   least-squares slope of the raw pressures is below that speed. One window, one lag.
5. A level less than ``min_transition_m`` from the floor's (hypsometric, measured
   temperature) is no floor change: a ramp, a stair landing, a spike that went away. It is
   kept as an offset from the floor, so several small legs in a row still add up.
6. A level at least that far is a *stop* (phase ``STOPPED``). When the robot rode the change
   in a car (live odometry: it moved less than ``leave_m`` since the change began), the stop
   is decided at once: the transition is published as the car stops. The car's stop shows
   one short window (``stop_s``) after the pressure comes to rest, in a band wide enough for
   the car doors' seal and the sensor's lag (``stop_band_m``, ``stop_rate_m_s``), so the
   decision comes before the slower still test of step 4 would pass. A car that goes on
   (a halt at a passing floor) corrects it (step 8). Otherwise the stop is not yet a visit:
   an elevator stops at passing floors, a walker pauses on landings. It becomes a visit, and
   only then the transition is published, when the robot drives ``leave_m`` away from where
   it stood when the pressure came to rest (odometry, :mod:`baromap.floors.motion`); or, with
   no live odometry, when it lasted ``min_visit_s``, or the next leg goes back the other way
   (the stop was where the trip went). Legs that stay within a storey (``min_transition_m``)
   of where the trip first came to rest do not restart that count: levels that close are one
   floor. A leg on in the same direction continues the same trip, dated from its first leg;
   a change from the stop that settles less than half a minimum storey from it (the car's
   doors, a spike's tail) is no leg, and the stop goes on as it was.
7. The level of the new floor is the smoothed pressure when the visit is decided, matched
   against the known floors by level relative to the floor just left
   (:mod:`baromap.floors.identity`): a revisit gets its old stable id despite drift, a new
   floor a new id and a name (:mod:`baromap.floors.names`). A decision taken as the car stops
   sees the doors' seal and the sensor's lag in that level; the floor's level is measured
   again once the pressure has been still for ``settle_s`` on it (no event: identity is
   decided, the measurement only gets better).
8. Decisions are final unless the trip was not over: if a leg begins within ``landing_s`` of
   the stop a visit was decided on, without the robot having driven off, and it goes on in
   the same direction (or, the robot riding in the car, either way), the transition is
   revised by a :attr:`~baromap.messages.FloorEventKind.CORRECTION` event to where the trip
   ended, and the floor's identity is decided again there: a new floor that turns out to be
   a known one is merged into it (two floors closer than ``min_transition_m`` cannot both
   exist). A trip that ends where it began is withdrawn
   (:attr:`~baromap.messages.FloorEventKind.RETRACTION`).
9. Rides are announced as they start (:class:`~baromap.messages.RideEvent`): once a change
   has moved ``ride_m`` from the floor's level with the smoothed rate the same way, a
   ``ride_started`` (direction, floor left); the floor event that decides where it went
   comes with a ``ride_ended``; a change that comes to rest short of a floor change, or
   turns the other way first, withdraws it with a reason.

Every floor event returned is also kept in :attr:`OnlineFloorDetector.events` (rides in
:attr:`OnlineFloorDetector.rides`); the detector's results change only through events, so
:attr:`OnlineFloorDetector.transitions` is always the published transitions with their
corrections applied, and a replay of the same inputs in the same order gives the same
events, ids included.

With a reference station (a barometer that does not move), its smoothed pressure change since
the start is subtracted from the robot's, which removes the weather directly.

All per-sample work is a few float operations on attributes; objects are built only when
something happens (an event) or someone asks (:meth:`OnlineFloorDetector.state`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import structlog

from baromap.floors.config import MAX_AIR_C, MIN_AIR_C, FloorDetectorConfig
from baromap.floors.height import height_difference_m, pa_per_m, pressure_drop_pa
from baromap.floors.identity import FloorRegistry
from baromap.floors.motion import StopWatch
from baromap.floors.names import FloorNamer
from baromap.floors.still_window import StillWindow
from baromap.messages import (
    NS_PER_S,
    FloorEvent,
    FloorEventKind,
    FloorPhase,
    FloorState,
    Odometry,
    PressureSample,
    RideDirection,
    RideEvent,
    RideEventKind,
)

log = structlog.get_logger(__name__)

#: Fastest weather trend the drift tracker will follow, Pa/s (7 hPa/h, beyond a strong storm).
MAX_WEATHER_RATE_PA_S = 0.2
#: Fewest samples in the settle window: a line through two points says nothing about stillness.
#: A barometer read more slowly than that (a sample every 1.5 s or more against the window's
#: 1.5 s) has the window stretched past ``settle_s`` to hold this many; a window of
#: ``settle_s`` alone would never hold three, and such a run would never settle on a floor.
MIN_WINDOW_SAMPLES = 3
#: Fastest a lift car speeds up or slows down, m/s² (passenger lifts keep to 1-1.5 for
#: comfort; the simulated car does 0.6): a step of d metres from rest to rest takes at least
#: 2 sqrt(d / this).
MAX_CAR_ACCEL_M_S2 = 1.5

_UNKNOWN, _SETTLED, _CHANGING, _STOPPED = 0, 1, 2, 3
_PHASES = (FloorPhase.UNKNOWN, FloorPhase.SETTLED, FloorPhase.CHANGING, FloorPhase.STOPPED)

#: Whatever the detector publishes: floor events (the account of the run) and ride events.
DetectorEvent = FloorEvent | RideEvent


@dataclass(slots=True)
class _Held:
    """A stop left by a change that may turn out to be a spike (then the stop goes on)."""

    level: float
    start_ns: int
    since_ns: int
    dwell_ns: int
    dwell_level: float


@dataclass(slots=True)
class _Visit:
    """The last decided transition, while its trip could still turn out to go on."""

    position: int
    stop_ns: int
    direction: float
    new_floor: bool
    #: The step from the floor the trip left to the current floor's level (Pa); the floor
    #: left is at the current floor's level minus this.
    delta_pa: float
    #: Decided as the car stopped with the robot in it.
    in_car: bool


@dataclass(slots=True)
class _Ride:
    """A ride announced and not yet ended or withdrawn."""

    ride_id: int
    direction: RideDirection
    sign: float  # of the pressure change: + going down
    t_start_ns: int
    from_id: int


class OnlineFloorDetector:
    """Streaming floor detector; see the module docstring for the method.

    Call :meth:`update` with the robot's pressure samples in time order (older or repeated
    stamps are ignored and counted), :meth:`update_odometry` with its odometry when there is
    any, :meth:`update_reference` with a reference station's samples when there is one, and
    :meth:`finish` when the stream ends, to decide on a change or stop still in progress.
    Events come only from :meth:`update` and :meth:`finish`, in the order they are published;
    decisions depend only on the sequence of calls, so a replay in the recorded order gives
    identical events.
    """

    def __init__(self, config: FloorDetectorConfig | None = None) -> None:
        self.config = config or FloorDetectorConfig()
        c = self.config
        self.registry = FloorRegistry()
        #: Every floor event published, in order (transitions, corrections, retractions).
        self.events: list[FloorEvent] = []
        #: Every ride event published, in order.
        self.rides: list[RideEvent] = []
        self._current: list[FloorEvent] = []
        self._next_id = 1
        self._next_ride = 1
        self._ride: _Ride | None = None
        self._outbox: list[DetectorEvent] = []
        self.ignored_samples = 0
        self.ignored_odometry = 0
        self._namer = FloorNamer(
            c.start_floor,
            storey_m=c.storey_m,
            tolerance_m=c.min_transition_m / 2,
            model=c.building,
        )
        self._motion = StopWatch()  # since the stop began
        self._ride_motion = StopWatch()  # since the change began
        self._moved_before_leg = 0.0
        self._settle_ns = round(c.settle_s * NS_PER_S)
        self._stop_ns = round(c.stop_s * NS_PER_S)
        self._gap_ns = round(c.max_gap_s * NS_PER_S)
        self._landing_ns = round(c.landing_s * NS_PER_S)
        self._visit_ns = round(c.min_visit_s * NS_PER_S)
        self._level_tau = c.level_tau_s
        self._trend_tau = c.trend_tau_s
        self._drift_tau = c.drift_tau_s
        # Thresholds in Pa, set from the first sample's pressure and refreshed on decisions.
        self._start_pa = 0.0
        self._start_rate = 0.0
        self._settle_rate = 0.0
        self._settle_band = 0.0  # how far a still pressure may wander over settle_s
        self._stop_rate = 0.0
        self._stop_band = 0.0
        self._ride_pa = 0.0
        self._storey_pa = 0.0  # min_transition_m
        self._pa_per_m = 0.0
        self._temperature = c.default_temperature_c
        self._n = 0
        self._t = 0
        self.level = math.nan  # Holt level of the pressure, Pa (reference-corrected)
        self.rate = 0.0  # Pa/s
        self.smoothed = math.nan  # exponential average of the pressure, Pa (no trend)
        self._phase = _UNKNOWN
        self._since = 0
        self._calm_ns = 0  # last time the pressure was quiet where the robot is
        self._window = StillWindow(self._settle_ns, MIN_WINDOW_SAMPLES)
        self._stop_window = StillWindow(self._stop_ns, MIN_WINDOW_SAMPLES)
        # Where the robot is: the tracked level there, and the current floor's level.
        self._anchor = math.nan
        self._drift = 0.0  # Pa/s
        self._offset = 0.0  # anchor minus the floor's level while settled (ramp, landing)
        self._floor = -1  # stable id of the current floor
        self._floor_level = math.nan
        # The trip under way and the landings of sub-threshold legs.
        self._change_start = 0  # the calm moment before the current leg
        self._trip_start = -1  # start of the trip's first leg (-1: no trip at storey height)
        self._departed_ns = -1  # when the current offset from the floor's level began
        self._landed_ns = 0  # when the robot stopped at that offset
        # A stop at a storey's height, not yet a visit.
        self._stop_level = math.nan
        self._stop_start = 0  # when the pressure came to rest at the stop's level
        self._dwell_start = 0  # when the trip came to rest within a storey of that level
        self._dwell_level = math.nan
        self._held: _Held | None = None
        self._visit: _Visit | None = None
        # Until when the level of a floor decided as the car stopped is measured again (0: not)
        self._measure_until = 0
        # Reference station.
        self._ref_level = math.nan
        self._ref_origin = math.nan
        self._ref_t = 0
        self._correction = 0.0

    # -- input ---------------------------------------------------------------------------

    def update_reference(self, sample: PressureSample) -> None:
        """A reference station's reading: its change since the start is weather."""
        if not math.isfinite(sample.pressure_pa):
            # one NaN in the correction would make every later robot sample NaN (ignored)
            self.ignored_samples += 1
            return
        if math.isnan(self._ref_level):
            self._ref_level = self._ref_origin = sample.pressure_pa
            self._ref_t = sample.t_ns
            return
        dt = (sample.t_ns - self._ref_t) / NS_PER_S
        if dt <= 0.0:
            return
        self._ref_t = sample.t_ns
        gain = dt / (self.config.reference_tau_s + dt)
        self._ref_level += gain * (sample.pressure_pa - self._ref_level)
        self._correction = self._ref_level - self._ref_origin

    def update_odometry(self, odometry: Odometry) -> None:
        """The robot's odometry: says whether it rode in a car and whether it drove off at a
        stop (no events here; a decision it makes possible comes with the next
        :meth:`update`)."""
        if not self._motion.update(odometry):
            self.ignored_odometry += 1
            return
        self._ride_motion.update(odometry)

    def update(self, sample: PressureSample) -> list[DetectorEvent]:
        """Feed one sample; returns the events it completes (usually none), in order."""
        t = sample.t_ns
        p = sample.pressure_pa - self._correction
        temperature = sample.temperature_c
        if temperature is not None and MIN_AIR_C < temperature < MAX_AIR_C:
            # a NaN or a sensor glitch below absolute zero would make the hypsometric
            # thresholds raise; the last plausible reading stands
            self._temperature = temperature
        if self._n == 0:
            self._first(t, p)
            return []
        dt_ns = t - self._t
        if dt_ns <= 0 or not math.isfinite(p):
            self.ignored_samples += 1
            return []
        if dt_ns > self._gap_ns:
            self._gap(t, p)
            return []
        self._n += 1
        self._t = t
        dt = dt_ns * 1e-9
        # Holt smoothing with time-based gains: level in Pa, trend in Pa/s.
        level = self.level
        predicted = level + self.rate * dt
        smoothed = predicted + dt / (self._level_tau + dt) * (p - predicted)
        rate = self.rate + dt / (self._trend_tau + dt) * ((smoothed - level) / dt - self.rate)
        self.level = smoothed
        self.rate = rate
        average = self.smoothed + dt / (self._level_tau + dt) * (p - self.smoothed)
        self.smoothed = average
        phase = self._phase
        if phase == _SETTLED:
            # On a floor (inline: this runs for nearly every sample of a run).
            anchor = self._anchor + self._drift * dt
            error = smoothed - anchor
            start_pa, start_rate = self._start_pa, self._start_rate
            if error > start_pa or error < -start_pa or rate > start_rate or rate < -start_rate:
                self._anchor = anchor
                self._floor_level = anchor - self._offset
                self._begin_change()
                return self._flush()
            if -self._settle_rate < rate < self._settle_rate:
                # Critically damped tracker with time constant drift_tau: weather only.
                tau = self._drift_tau
                drift = self._drift + dt / (tau * tau) * error
                if drift > MAX_WEATHER_RATE_PA_S:
                    drift = MAX_WEATHER_RATE_PA_S
                elif drift < -MAX_WEATHER_RATE_PA_S:
                    drift = -MAX_WEATHER_RATE_PA_S
                self._drift = drift
                anchor += 2.0 * dt / tau * error
                self._calm_ns = t
            self._anchor = anchor
            self._floor_level = anchor - self._offset
            if t <= self._measure_until:
                self._measure_again(t, p, average)
            return []
        if phase == _STOPPED:
            self._on_stop(t, dt, smoothed, rate)
            return self._flush()
        # Changing (or not yet settled at the start): wait until the last settle_s were still.
        self._floor_level += self._drift * dt
        window = self._window
        window.push(t, p, average)
        stop = self._stop_window
        stop.push(t, p, average)
        if self._floor >= 0:
            self._announce(t, average)
            if self._car_stopped(t, average):
                # The car has stopped with the robot in it: decide now, on the short window.
                self.level = average
                self.rate = stop.slope()
                self._settled(t, average, stop.start_ns, at_end=False)
                return self._flush()
        if (
            t - window.start_ns < self._settle_ns
            or window.count < MIN_WINDOW_SAMPLES
            or window.spread() > self._settle_band
        ):
            return self._flush()
        slope = window.slope()
        if not -self._settle_rate < slope < self._settle_rate:
            return self._flush()
        # The Holt smoother still remembers the ride (its trend decays with trend_tau): start
        # it afresh from what the window has shown, or that memory would read as a new change.
        self.level = average
        self.rate = slope
        self._settled(t, average, window.start_ns, at_end=False)
        return self._flush()

    def finish(self) -> list[DetectorEvent]:
        """The stream ended: decide on a change or a stop in progress from what there was."""
        if self._n == 0:
            return []
        if self._phase == _STOPPED:
            self._confirm(self._t, at_end=True)
        elif self._phase == _CHANGING:
            self._settled(self._t, self.smoothed, self._t, at_end=True)
        if self._ride is not None:
            self._withdraw_ride(self._t, "the input ended before the ride did")
        return self._flush()

    # -- results -------------------------------------------------------------------------

    @property
    def transitions(self) -> tuple[FloorEvent, ...]:
        """The published transitions with their corrections applied, in order."""
        return tuple(self._current)

    @property
    def phase(self) -> FloorPhase:
        return _PHASES[self._phase]

    @property
    def floor_id(self) -> int | None:
        """Stable id of the current floor, None before the first settle."""
        return self._floor if self._floor >= 0 else None

    def state(self) -> FloorState:
        """The live answer to "which floor are we on?" (built on demand)."""
        level_pa = self.level + self._correction if self._n else math.nan
        if self._floor < 0:
            return FloorState(
                t_ns=self._t,
                phase=_PHASES[self._phase],
                floor_id=None,
                name=None,
                height_m=math.nan,
                level_m=math.nan,
                level_pa=level_pa,
                since_ns=self._since,
                floors_known=0,
            )
        registry = self.registry
        here = self._anchor if self._phase in (_SETTLED, _STOPPED) else self.smoothed
        stop_id: int | None = None
        if self._phase == _STOPPED:
            stop_id = registry.match(
                registry.relative_pa(self._floor) + self._stop_level - self._floor_level,
                pressure_drop_pa(self.config.min_transition_m, here, self._temperature),
                exclude=self._floor,
            )
        return FloorState(
            t_ns=self._t,
            phase=_PHASES[self._phase],
            floor_id=self._floor,
            name=registry.name(self._floor),
            height_m=registry.height_m(self._floor),
            level_m=self._height_of(here - self._floor_level + registry.relative_pa(self._floor)),
            level_pa=level_pa,
            since_ns=self._since,
            floors_known=registry.known,
            stop_floor_id=stop_id,
            stop_name=None if stop_id is None else registry.name(stop_id),
        )

    # -- per sample, by phase ------------------------------------------------------------

    def _flush(self) -> list[DetectorEvent]:
        if not self._outbox:
            return []
        out, self._outbox = self._outbox, []
        return out

    def _in_car(self, t: int) -> bool:
        """The robot rode the change standing (turning, shuffling) in place: in a car."""
        return self._ride_motion.live(t) and self._ride_motion.moved_m < self.config.leave_m

    def _car_stopped(self, t: int, average: float) -> bool:
        """The short test of a car's stop: still for ``stop_s`` at a storey from the floor
        (or half a storey on from a stop decided in the car), the robot in the car."""
        stop = self._stop_window
        if (
            t - stop.start_ns < self._stop_ns
            or stop.count < MIN_WINDOW_SAMPLES
            or stop.spread() > self._stop_band
        ):
            return False
        if not -self._stop_rate < stop.slope() < self._stop_rate:
            return False
        step = average - self._floor_level
        least = self._storey_pa
        began = self._change_start
        if self._trip_start >= 0:
            began = self._trip_start
        elif self._departed_ns >= 0:
            began = self._departed_ns  # the car paused short of a storey on the way
        visit = self._visit
        if (
            visit is not None
            and visit.in_car
            and self._trip_start < 0
            and self._moved_before_leg < self.config.leave_m
        ):
            # the car going on from a stop decided in it: a leg corrects that decision, and
            # the car's trip began with the decided one
            least /= 2
            began = self._current[visit.position].t_start_ns
            step += visit.delta_pa
        if -least < average - self._floor_level < least or not self._in_car(t):
            return False
        return self._like_a_car(began, stop.start_ns, step)

    def _like_a_car(self, began: int, stopped: int, step_pa: float) -> bool:
        """A car starts from rest and stops at rest: it covers a step no faster than its
        acceleration allows. A spike (or two) rises as far in a second, and is no ride."""
        metres = abs(step_pa) / self._pa_per_m
        return (stopped - began) / NS_PER_S >= 2.0 * math.sqrt(metres / MAX_CAR_ACCEL_M_S2)

    def _on_stop(self, t: int, dt: float, smoothed: float, rate: float) -> None:
        """Stopped at a storey's height during a ride: a visit yet?"""
        self._floor_level += self._drift * dt
        stop = self._stop_level + self._drift * dt
        error = smoothed - stop
        if self._leaves(error, rate):
            self._held = self._hold(stop)
            self._stop_level = stop
            self._begin_change()
            return
        if -self._settle_rate < rate < self._settle_rate:
            stop = self._track(stop, error, dt)
            self._calm_ns = t
        self._stop_level = stop
        # The level of the stop is the pressure now: the car's doors open and their
        # transient fades while it waits, and the decision takes the level it has reached.
        self._anchor = smoothed
        if self._motion.live(t):
            if self._motion.moved_m >= self.config.leave_m:
                self._confirm(t, at_end=False)
        elif t - self._dwell_start >= self._visit_ns:
            self._confirm(t, at_end=False)

    def _leaves(self, error: float, rate: float) -> bool:
        start_pa, start_rate = self._start_pa, self._start_rate
        return error > start_pa or error < -start_pa or rate > start_rate or rate < -start_rate

    def _track(self, level: float, error: float, dt: float) -> float:
        """Critically damped tracker with time constant drift_tau: weather only."""
        tau = self._drift_tau
        drift = self._drift + dt / (tau * tau) * error
        self._drift = min(max(drift, -MAX_WEATHER_RATE_PA_S), MAX_WEATHER_RATE_PA_S)
        return level + 2.0 * dt / tau * error

    def _measure_again(self, t: int, p: float, average: float) -> None:
        """On a floor decided as the car stopped, until the robot drives off or ``landing_s``
        passed: whenever the pressure has been still for ``settle_s`` (the doors open, a
        spike faded, the sensor caught up), that is the floor's level."""
        window = self._window
        window.push(t, p, average)
        if self._motion.live(t) and self._motion.moved_m >= self.config.leave_m:
            self._measure_until = 0  # out of the car: what it measured last stands
        if (
            t - window.start_ns < self._settle_ns
            or window.count < MIN_WINDOW_SAMPLES
            or window.spread() > self._settle_band
            or not -self._settle_rate < window.slope() < self._settle_rate
        ):
            return
        self._rebase(average - self._offset)

    def _rebase(self, level: float) -> None:
        """The current floor's level is ``level``: a floor first measured at this visit
        takes it (relative to the floor the trip left), the trip's step with it."""
        shift = level - self._floor_level
        self._floor_level = level
        self._anchor = level + self._offset
        visit = self._visit
        if visit is None:
            return
        visit.delta_pa += shift
        if visit.new_floor:
            relative = self.registry.relative_pa(self._floor) + shift
            self.registry.move(self._floor, relative, self._height_of(relative))

    # -- rides ---------------------------------------------------------------------------

    def _announce(self, t: int, average: float) -> None:
        """During a change: announce a ride once it moved ``ride_m`` one way and is still
        moving that way, or withdraw one that turned the other way."""
        step = average - self._floor_level
        # a floor decided as the car stopped has a level good to the stop's band until it
        # is measured again: what the doors and the sensor do meanwhile is no ride
        threshold = self._ride_pa + (self._stop_band if self._t <= self._measure_until else 0.0)
        if -threshold < step < threshold:
            return
        slope = self._stop_window.slope()
        if step * slope <= 0.0 or -self._settle_rate < slope < self._settle_rate:
            return
        ride = self._ride
        if ride is not None:
            if step * ride.sign > 0.0:
                return
            self._withdraw_ride(t, "the pressure turned the other way: a transient, not the car")
        sign = 1.0 if step > 0.0 else -1.0
        self._start_ride(t, sign)

    def _start_ride(self, t: int, sign: float) -> None:
        start = self._trip_start if self._trip_start >= 0 else self._change_start
        ride = _Ride(
            self._next_ride,
            RideDirection.DOWN if sign > 0.0 else RideDirection.UP,
            sign,
            start,
            self._floor,
        )
        self._next_ride += 1
        self._ride = ride
        self._emit_ride(t, ride, RideEventKind.STARTED)

    def _withdraw_ride(self, t: int, reason: str) -> None:
        ride = self._ride
        if ride is None:
            return
        self._ride = None
        self._emit_ride(t, ride, RideEventKind.RETRACTED, reason=reason)

    def _end_ride(self, event: FloorEvent) -> None:
        """The floor event that decides where the open ride went (announcing it first if the
        change never showed a direction before it ended)."""
        if self._ride is None:
            self._start_ride(event.t_ns, 1.0 if event.delta_pa > 0.0 else -1.0)
        ride = self._ride
        assert ride is not None
        self._ride = None
        self._emit_ride(event.t_ns, ride, RideEventKind.ENDED, event=event)

    def _emit_ride(
        self,
        t: int,
        ride: _Ride,
        kind: RideEventKind,
        *,
        event: FloorEvent | None = None,
        reason: str = "",
    ) -> None:
        registry = self.registry
        to_id: int | None = None
        if event is not None:
            # a retraction sends the robot back to the floor the withdrawn transition left
            retracted = event.kind is FloorEventKind.RETRACTION
            to_id = event.from_id if retracted else event.to_id
        out = RideEvent(
            t_ns=t,
            ride_id=ride.ride_id,
            kind=kind,
            direction=ride.direction,
            t_start_ns=ride.t_start_ns,
            from_id=ride.from_id,
            from_name=registry.name(ride.from_id),
            to_id=to_id,
            to_name=None if to_id is None else registry.name(to_id),
            floor_event_id=None if event is None else event.event_id,
            estimated_name=False if to_id is None else registry.estimated(to_id),
            reason=reason,
        )
        self.rides.append(out)
        self._outbox.append(out)
        log.debug("ride event", kind=kind.value, ride_id=ride.ride_id, reason=reason)

    # -- decisions -----------------------------------------------------------------------

    def _first(self, t: int, p: float) -> None:
        if not math.isfinite(p):
            self.ignored_samples += 1
            return
        self._n = 1
        self._t = self._since = t
        self.level = self.smoothed = p
        self.rate = 0.0
        self._window.push(t, p, p)
        self._stop_window.push(t, p, p)
        self._anchor = p
        self._thresholds(p)

    def _thresholds(self, p: float) -> None:
        c = self.config
        gradient = pa_per_m(p, self._temperature)
        self._start_pa = c.start_m * gradient
        self._start_rate = c.start_rate_m_s * gradient
        self._settle_rate = c.settle_rate_m_s * gradient
        self._settle_band = self._settle_rate * c.settle_s
        self._stop_rate = c.stop_rate_m_s * gradient
        self._stop_band = c.stop_band_m * gradient
        self._ride_pa = c.ride_m * gradient
        self._storey_pa = c.min_transition_m * gradient
        self._pa_per_m = gradient

    def _gap(self, t: int, p: float) -> None:
        """No data for longer than ``max_gap_s``: the robot may have moved meanwhile."""
        log.info("pressure gap", seconds=(t - self._t) / NS_PER_S)
        elapsed = (t - self._t) * 1e-9
        previous = self._t
        self._n += 1
        self._t = t
        self.level = self.smoothed = p
        self.rate = 0.0
        self._measure_until = 0
        if self._phase in (_SETTLED, _STOPPED):
            self._floor_level += self._drift * elapsed
            if self._phase == _SETTLED:
                self._anchor += self._drift * elapsed
            else:
                self._stop_level += self._drift * elapsed
                self._held = self._hold(self._stop_level)
            self._calm_ns = previous
            self._begin_change()
        else:
            if self._floor >= 0:
                self._floor_level += self._drift * elapsed
            self._window.clear()  # what came before the gap says nothing about now
            self._stop_window.clear()
        self._window.push(t, p, p)
        self._stop_window.push(t, p, p)

    def _begin_change(self) -> None:
        self._window.clear()  # stillness is judged on what came after the change began
        self._stop_window.clear()
        self._phase = _CHANGING
        self._since = self._t
        self._change_start = self._calm_ns
        self._ride_motion.watch(self._calm_ns)
        # where the robot had got to from its last stop when this leg began (it may drive
        # off at the leg's end before the pressure is known to have settled there)
        self._moved_before_leg = self._motion.moved_m

    def _settled(self, t: int, settled: float, t_end: int, *, at_end: bool) -> None:
        """The pressure came to rest (or the input ended): where does that leave the robot?"""
        self._thresholds(settled)
        held, self._held = self._held, None
        if self._floor < 0:
            # First settle of the run: this is the start floor.
            self._floor = self.registry.add(0.0, 0.0, self._namer.start_name, estimated=False)
            self._enter(t, settled, 0.0)
            return
        min_pa = pressure_drop_pa(self.config.min_transition_m, settled, self._temperature)
        # A leg of a trip moves at least half a minimum storey; less is the car's doors
        # (their seal is a few pascals), a spike's tail, a shuffle on a landing.
        leg_pa = min_pa / 2
        if held is not None:
            back = settled - held.level
            if -leg_pa < back < leg_pa:
                # No leg: the stop goes on as it was, from when it began.
                self._resume(held, settled)
                self._due(t, at_end)
                return
            if back * (held.level - self._floor_level) < 0.0 and not self._motion.live(t):
                # The trip turned back: the stop was where it went, however short; the leg
                # back is a ride of its own.
                self._confirm_at(t, held)
                step = settled - self._floor_level
                if step >= self._ride_pa or step <= -self._ride_pa:
                    self._start_ride(t, 1.0 if step > 0.0 else -1.0)
                self._settled_on_floor(t, settled, t_end, min_pa, at_end=at_end)
                return
            self._settled_on_floor(t, settled, t_end, min_pa, at_end=at_end, held=held)
        elif self._continues(t, settled, leg_pa):
            self._continue_trip(t, settled, t_end, min_pa)
        else:
            self._settled_on_floor(t, settled, t_end, min_pa, at_end=at_end)

    def _settled_on_floor(
        self,
        t: int,
        settled: float,
        t_end: int,
        min_pa: float,
        *,
        at_end: bool,
        held: _Held | None = None,
    ) -> None:
        """Settled at ``settled`` on the current floor's trip (``held``: the stop the leg
        that just ended came from)."""
        step = settled - self._floor_level
        if -min_pa < step < min_pa:
            self._sub_threshold(t, t_end, settled, step)
            return
        if self._trip_start < 0:
            self._trip_start = self._change_start
            if (
                self._departed_ns >= 0
                and self._offset * step > 0.0
                and self._change_start - self._landed_ns <= self._landing_ns
            ):
                self._trip_start = self._departed_ns  # the trip paused on a landing first
        self._phase = _STOPPED
        self._since = t
        self._calm_ns = t
        self._anchor = self._stop_level = settled
        self._stop_start = t_end
        self._measure_until = 0
        if held is not None and -min_pa < settled - held.dwell_level < min_pa:
            # Still within a storey of where the trip first came to rest (the end of a
            # staircase, a floor that slopes): the same stop for the dwell and for odometry.
            self._dwell_start, self._dwell_level = held.dwell_ns, held.dwell_level
        else:
            self._dwell_start, self._dwell_level = t_end, settled
            self._motion.watch(t_end)
        self._due(t, at_end)

    def _hold(self, level: float) -> _Held:
        return _Held(level, self._stop_start, self._since, self._dwell_start, self._dwell_level)

    def _resume(self, held: _Held, settled: float) -> None:
        self._phase = _STOPPED
        self._since = held.since_ns
        self._calm_ns = self._t
        self._anchor = self._stop_level = settled
        self._stop_start = held.start_ns
        self._dwell_start, self._dwell_level = held.dwell_ns, held.dwell_level

    def _due(self, t: int, at_end: bool) -> None:
        """A stop just began or went on: is it a visit already? (At once when the robot
        rode to it in a car, as a car rides.)"""
        began = self._trip_start if self._trip_start >= 0 else self._change_start
        in_car = self._in_car(t) and self._like_a_car(
            began, self._stop_start, self._stop_level - self._floor_level
        )
        if (
            at_end
            or in_car
            or (self._motion.live(t) and self._motion.moved_m >= self.config.leave_m)
        ):
            self._confirm(t, at_end=at_end)

    def _confirm_at(self, t: int, held: _Held) -> None:
        """Decide on a stop that a change has already left (the trip turned back)."""
        self._stop_level = held.level
        self._stop_start = held.start_ns
        self._anchor = held.level
        self._confirm(t, at_end=False)

    def _confirm(self, t: int, *, at_end: bool) -> None:
        """The stop is a visit: publish the transition to the floor at its level."""
        registry = self.registry
        level = self._anchor
        step = level - self._floor_level
        from_id = self._floor
        relative = registry.relative_pa(from_id) + step
        min_pa = pressure_drop_pa(self.config.min_transition_m, level, self._temperature)
        to_id = registry.match(relative, min_pa, exclude=from_id)
        new_floor = to_id is None
        if to_id is None:
            to_id = self._new_floor(relative)
        else:
            registry.revisit(to_id)
        start = self._trip_start if self._trip_start >= 0 else self._change_start
        span = (start, self._stop_start)
        in_car = self._in_car(t)
        self._publish(t, span, (from_id, to_id), step, level, at_end=at_end)
        # a later leg continues this trip only if it leaves within landing_s of the rest
        self._visit = _Visit(
            len(self._current) - 1, self._dwell_start, step, new_floor, step, in_car
        )
        self._floor = to_id
        self._trip_start = -1
        self._departed_ns = -1
        self._enter(t, level, 0.0)
        # decided on the car's stop: the level is measured again while the robot is in it
        self._measure_until = t + self._landing_ns if in_car and not at_end else 0
        self._window.clear()

    def _continues(self, t: int, settled: float, leg_pa: float) -> bool:
        """Did the leg that just ended carry on the trip of the last transition?"""
        visit = self._visit
        if visit is None or self._trip_start >= 0:
            return False
        step = settled - self._floor_level
        if -leg_pa < step < leg_pa:
            return False
        if self._motion.live(t):
            if self._moved_before_leg >= self.config.leave_m:
                return False  # the robot drove off before this leg: it visited that floor
            if visit.in_car and self._in_car(t):
                return True  # it never left the car, however long the car stood there
        if self._change_start - visit.stop_ns >= self._landing_ns:
            return False  # a stop as long as a landing can be was no landing
        return step * visit.direction > 0.0

    def _continue_trip(self, t: int, settled: float, t_end: int, min_pa: float) -> None:
        """The trip of the last transition went on: correct it to where it ended."""
        visit = self._visit
        assert visit is not None  # checked by _continues
        registry = self.registry
        old = self._current[visit.position]
        origin_level = self._floor_level - visit.delta_pa
        total = settled - origin_level
        if -min_pa < total < min_pa:
            self._retract(t, old, visit, settled)
            return
        relative = registry.relative_pa(old.from_id) + total
        to_id = registry.match(relative, min_pa, exclude=old.from_id)
        same = to_id == old.to_id or (to_id is None and visit.new_floor)
        if visit.in_car and same and -min_pa < total - visit.delta_pa < min_pa:
            # Still the floor decided as the car stopped: its level, measured again (a
            # transient at the stop, the last of the car's motion), and no event (identity is
            # what was decided).
            self._measured_again(t, settled)
            return
        if to_id is None or to_id == old.to_id:
            if visit.new_floor:
                to_id = old.to_id
                height = self._height_of(relative)
                registry.move(to_id, relative, height)
                # the landing's name was counted for another height: count it again
                registry.rename(to_id, *self._namer.name(height, registry.names(exclude=to_id)))
            elif to_id is None:
                to_id = self._new_floor(relative)
        elif visit.new_floor:
            registry.merge(old.to_id, into=to_id)  # the landing was no floor
        else:
            registry.revisit(to_id)
        in_car = self._in_car(t)
        self._publish(
            t, (old.t_start_ns, t_end), (old.from_id, to_id), total, settled, replaces=old
        )
        self._visit = _Visit(
            visit.position,
            t_end,
            visit.direction,
            visit.new_floor and to_id == old.to_id,
            total,
            in_car,
        )
        self._floor = to_id
        self._departed_ns = -1
        self._enter(t, settled, 0.0)
        self._measure_until = t + self._landing_ns if in_car else 0
        self._window.clear()

    def _retract(self, t: int, old: FloorEvent, visit: _Visit, settled: float) -> None:
        """The trip came back to the floor it left, the robot never out of the car: the
        transition did not happen."""
        registry = self.registry
        if visit.new_floor:
            registry.merge(old.to_id, into=old.from_id)  # never a floor: its id is retired
        self._publish(
            t,
            (old.t_start_ns, old.t_end_ns),
            (old.from_id, old.to_id),
            old.delta_pa,
            settled,
            replaces=old,
            retract=True,
        )
        self._visit = None
        self._floor = old.from_id
        self._departed_ns = -1
        self._enter(t, settled, 0.0)
        self._measure_until = 0

    def _measured_again(self, t: int, settled: float) -> None:
        """The current floor is at ``settled``: take it as its level, with no event."""
        if self._ride is not None:
            self._withdraw_ride(t, "the pressure settled on the floor just decided: no ride")
        self._trip_start = -1
        self._departed_ns = -1
        self._enter(t, settled, settled - self._floor_level)
        self._rebase(settled)
        self._offset = 0.0
        self._anchor = settled
        self._window.clear()

    def _sub_threshold(self, t: int, t_end: int, settled: float, step: float) -> None:
        """Settled short of a floor change: a landing, a ramp, or a spike that went away."""
        self._trip_start = -1
        if self._ride is not None:
            metres = abs(height_difference_m(settled - step, settled, self._temperature))
            name = self.registry.name(self._floor)
            self._withdraw_ride(t, f"came to rest {metres:.1f} m from floor {name}: no ride")
        if -self._start_pa < step < self._start_pa:
            self._departed_ns = -1  # back at (or never left) the floor's level
        elif (
            self._departed_ns < 0
            or step * self._offset <= 0.0
            or self._change_start - self._landed_ns > self._landing_ns
        ):
            # a new trip: the first leg, a turn back, or a leg after a stop too long for a
            # landing (the robot stayed at the old offset; that was no part of this trip)
            self._departed_ns = self._change_start
        self._landed_ns = t_end
        if t <= self._measure_until:
            # the doors' seal, a spike or the sensor's lag moved the pressure after the
            # decision: this is the floor's level
            self._measured_again(t, settled)
            return
        self._enter(t, settled, step)

    def _enter(self, t: int, settled: float, offset: float) -> None:
        self._phase = _SETTLED
        self._since = t
        self._calm_ns = t
        self._anchor = settled
        self._offset = offset
        self._floor_level = settled - offset

    # -- floors and events ---------------------------------------------------------------

    def _height_of(self, relative_pa: float) -> float:
        """Height above the start floor of a level ``relative_pa`` from the start floor's."""
        start = self._floor_level - self.registry.relative_pa(self._floor)
        return height_difference_m(start, start + relative_pa, self._temperature)

    def _new_floor(self, relative_pa: float) -> int:
        height = self._height_of(relative_pa)
        name, estimated = self._namer.name(height, self.registry.names())
        return self.registry.add(relative_pa, height, name, estimated=estimated)

    def _publish(
        self,
        t: int,
        span: tuple[int, int],
        floors: tuple[int, int],
        delta_pa: float,
        level: float,
        *,
        at_end: bool = False,
        replaces: FloorEvent | None = None,
        retract: bool = False,
    ) -> FloorEvent:
        """Publish a transition ``floors`` (from, to) over ``span`` (start, end of the trip),
        or a correction of the event it ``replaces``, or its retraction."""
        registry = self.registry
        t_start, t_end = span
        from_id, to_id = floors
        if replaces is None:
            kind = FloorEventKind.TRANSITION
        else:
            kind = FloorEventKind.RETRACTION if retract else FloorEventKind.CORRECTION
        event = FloorEvent(
            t_ns=t,
            event_id=self._next_id,
            kind=kind,
            replaces=None if replaces is None else replaces.event_id,
            t_start_ns=t_start,
            t_end_ns=t_end,
            from_id=from_id,
            to_id=to_id,
            from_name=registry.name(from_id),
            to_name=registry.name(to_id),
            height_m=registry.height_m(to_id),
            delta_pa=delta_pa,
            delta_m=height_difference_m(level - delta_pa, level, self._temperature),
            level_pa=level + self._correction,
            at_end=at_end,
            estimated_name=registry.estimated(to_id),
        )
        self._next_id += 1
        self.events.append(event)
        self._outbox.append(event)
        if replaces is None:
            self._current.append(event)
        elif retract:
            self._current.remove(replaces)
        else:
            self._current[self._current.index(replaces)] = event
        log.debug(
            "floor event",
            kind=event.kind.value,
            event_id=event.event_id,
            from_name=event.from_name,
            to_name=event.to_name,
            delta_m=round(event.delta_m, 2),
        )
        self._end_ride(event)
        return event
