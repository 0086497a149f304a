"""The online floor detector: one pressure sample in, floor events out, never a look ahead.

How it decides, and why:

1. A Holt (double exponential) smoother with *time-based* gains gives the pressure level and
   its rate in Pa/s, so irregular sample spacing does not change its behaviour. It decides
   when a change begins. A plain exponential average with the same level constant (no trend,
   so it never overshoots a stop) is the "smoothed pressure" the end of a change is judged on.
2. While settled on a floor, slow changes are weather: the floor's level follows them with a
   critically damped second-order tracker (level and drift rate; no lag on a steady drift),
   its drift rate clipped to what weather can do.
3. A change *begins* when the Holt level leaves the tracked level by ``start_m`` or moves
   faster than ``start_rate_m_s``. From then on the level is only extrapolated with the drift
   rate; nothing the robot does moves it.
4. The change *ends* when the last ``settle_s`` seconds (all after the change began) were
   still: the smoothed pressure stayed within the band a vertical speed of ``settle_rate_m_s``
   would cross in that time, and the least-squares slope of the raw pressures over the same
   window is below that speed. One window, one test, one lag: the band catches a bump or a dip
   inside the window (where a slope alone reads zero), the slope catches pressure still moving
   at the window's end that the smoothing has not shown yet. (A Holt rate that must stay quiet
   for ``settle_s`` puts two lags in a row: the trend's exponential memory of the ride, about
   a second after the sensor has settled, then the hold.) The settled level is the smoothed
   pressure at that moment. The window holds only samples taken since the change began and
   is kept with running sums and monotonic queues, so the test costs O(1) per sample.
5. Only if the settled level differs from the current floor's by at least
   ``min_transition_m`` (hypsometric, measured temperature) is a transition emitted. An
   elevator ventilation spike or a door draught goes and comes back: no event. A settle short
   of that height (a ramp, a stair landing) is kept as an offset from the floor, so several
   small steps in a row still add up against the floor's own level.
6. Arrival: a decision comes as soon as the robot is still, which in an elevator is often
   before the doors open (the car is slightly pressurised) or while a ventilation spike is
   still fading. For ``landing_s`` after a transition the new floor's level therefore follows
   the smoothed pressure, as long as it stays within ``start_m`` of the decided level (beyond
   that it is a new change); then the floor keeps the level it arrived at (a new floor's
   relative level is corrected by as much) and the weather tracker takes over.
7. A stop of less than ``landing_s`` between two legs in the same direction (a stair landing)
   belongs to the trip: the transition is dated from the first leg; and if a first visit to a
   floor was decided on such a landing, the floor's level is moved to where the trip ended.
8. The destination is matched against known floors by level relative to the floor just left
   (:mod:`baromap.floors.identity`), so revisits get their old index back despite drift.

With a reference station (a barometer that does not move), its smoothed pressure change since
the start is subtracted from the robot's, which removes the weather directly.

All per-sample work is a few float operations on attributes; objects are built only when
something happens (an event) or someone asks (:attr:`OnlineFloorDetector.state`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import structlog

from baromap.floors.config import MAX_AIR_C, MIN_AIR_C, FloorDetectorConfig
from baromap.floors.height import height_difference_m, pa_per_m, pressure_drop_pa
from baromap.floors.identity import FloorRegistry
from baromap.messages import NS_PER_S, FloorEvent, FloorPhase, FloorState, PressureSample

log = structlog.get_logger(__name__)

#: Fastest weather trend the drift tracker will follow, Pa/s (7 hPa/h, beyond a strong storm).
MAX_WEATHER_RATE_PA_S = 0.2
#: Fewest samples in the settle window: a line through two points says nothing about stillness.
MIN_WINDOW_SAMPLES = 3
#: How often the window's running sums are recomputed around a new origin, ns (keeps the sums
#: small, so subtracting the samples that leave the window loses no precision).
_REBASE_NS = 60 * NS_PER_S

_UNKNOWN, _SETTLED, _CHANGING = 0, 1, 2
_PHASES = (FloorPhase.UNKNOWN, FloorPhase.SETTLED, FloorPhase.CHANGING)


@dataclass(slots=True)
class TransitionRecord:
    """What the detector concluded about one transition (by floor id, not index).

    ``at_end`` says the stream ended before the pressure
    had settled, and the decision was taken on what there was. ``delta_pa`` and ``level_pa``
    are refined after the decision while the robot arrives; ``completed`` says a first visit
    decided before its trip ended has been moved to where the trip ended (that happens once).
    """

    t_ns: int
    t_start_ns: int
    t_end_ns: int
    from_id: int
    to_id: int
    delta_pa: float
    level_pa: float
    temperature_c: float
    at_end: bool = False
    new_floor: bool = False
    completed: bool = False


class OnlineFloorDetector:
    """Streaming floor detector; see the module docstring for the method.

    ``update(sample)`` is to be called with samples in time order (older or repeated stamps are
    ignored and counted); ``update_reference`` with a reference station's samples when there is
    one; ``finish()`` when the stream ends, to decide on a change still in progress.
    """

    def __init__(self, config: FloorDetectorConfig | None = None) -> None:
        self.config = config or FloorDetectorConfig()
        c = self.config
        self.registry = FloorRegistry()
        self.transitions: list[TransitionRecord] = []
        self.ignored_samples = 0
        self._settle_ns = round(c.settle_s * NS_PER_S)
        self._gap_ns = round(c.max_gap_s * NS_PER_S)
        self._landing_ns = round(c.landing_s * NS_PER_S)
        self._level_tau = c.level_tau_s
        self._trend_tau = c.trend_tau_s
        self._drift_tau = c.drift_tau_s
        # Thresholds in Pa, set from the first sample's pressure and refreshed on decisions.
        self._start_pa = 0.0
        self._start_rate = 0.0
        self._settle_rate = 0.0
        self._settle_band = 0.0  # how far a still pressure may wander over settle_s
        self._temperature = c.default_temperature_c
        self._n = 0
        self._t = 0
        self.level = math.nan  # smoothed pressure, Pa (reference-corrected)
        self.rate = 0.0  # Pa/s
        self._phase = _UNKNOWN
        self._since = 0
        self._calm_ns = 0  # last time the rate was quiet while settled
        self.smoothed = math.nan  # exponential average of the pressure, Pa (no trend)
        self._window = StillWindow(self._settle_ns)
        self._anchor = math.nan  # tracked level of where the robot is, Pa
        self._drift = 0.0  # Pa/s
        self._offset = 0.0  # anchor minus the current floor's level, Pa
        self._floor = -1  # current floor id
        self._change_start = 0
        self._departed_ns = -1  # when the current offset from the floor's level began
        self._landed_ns = 0  # when the robot stopped at that offset
        self._arrival_until = -1  # while t < this, the floor's level follows the pressure
        self._arrival_level = 0.0  # the level decided on arrival (drift-extrapolated), Pa
        self._arrival_record: TransitionRecord | None = None
        self._continued: TransitionRecord | None = None  # arrival a change broke into
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

    def update(self, sample: PressureSample) -> list[FloorEvent]:
        """Feed one sample; returns the floor events it completes (usually none)."""
        t = sample.t_ns
        p = sample.pressure_pa - self._correction
        temperature = sample.temperature_c
        if temperature is not None and MIN_AIR_C < temperature < MAX_AIR_C:
            # a NaN or a sensor glitch below absolute zero would make the hypsometric
            # thresholds raise; the last plausible reading stands
            self._temperature = temperature
        if self._n == 0:
            return self._first(t, p)
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
        quiet = -self._settle_rate < rate < self._settle_rate
        phase = self._phase
        if phase == _SETTLED:
            if t < self._arrival_until:
                return self._arriving(dt, smoothed, rate, quiet)
            if self._arrival_until >= 0:
                self._arrived()
            anchor = self._anchor + self._drift * dt
            error = smoothed - anchor
            if (
                error > self._start_pa
                or error < -self._start_pa
                or rate > self._start_rate
                or rate < -self._start_rate
            ):
                self._anchor = anchor
                self._begin_change()
                return []
            if quiet:
                # Critically damped tracker with time constant drift_tau: weather only.
                tau = self._drift_tau
                self._anchor = anchor + 2.0 * dt / tau * error
                drift = self._drift + dt / (tau * tau) * error
                if drift > MAX_WEATHER_RATE_PA_S:
                    drift = MAX_WEATHER_RATE_PA_S
                elif drift < -MAX_WEATHER_RATE_PA_S:
                    drift = -MAX_WEATHER_RATE_PA_S
                self._drift = drift
                self._calm_ns = t
            else:
                self._anchor = anchor
            return []
        # Changing (or not yet settled at the start): wait until the last settle_s were still.
        self._anchor += self._drift * dt
        window = self._window
        window.push(t, p, average)
        if (
            t - window.start_ns < self._settle_ns
            or window.count < MIN_WINDOW_SAMPLES
            or window.spread() > self._settle_band
        ):
            return []
        slope = window.slope()
        if not -self._settle_rate < slope < self._settle_rate:
            return []
        # The Holt smoother still remembers the ride (its trend decays with trend_tau): start
        # it afresh from what the window has shown, or that memory would read as a new change.
        self.level = average
        self.rate = slope
        return self._settled(t, average, window.start_ns, at_end=False)

    def finish(self) -> list[FloorEvent]:
        """The stream ended: decide on a change in progress from the samples there were."""
        if self._phase == _SETTLED and self._arrival_until >= 0:
            self._arrived()
        if self._phase != _CHANGING or self._n == 0:
            return []
        return self._settled(self._t, self.smoothed, self._t, at_end=True)

    # -- state ---------------------------------------------------------------------------

    @property
    def phase(self) -> FloorPhase:
        return _PHASES[self._phase]

    @property
    def floor_id(self) -> int | None:
        """Stable id (discovery order) of the current floor, None before the first settle."""
        return self._floor if self._floor >= 0 else None

    @property
    def state(self) -> FloorState:
        """The live answer to "which floor are we on?" (built on demand)."""
        if self._floor < 0:
            return FloorState(
                t_ns=self._t,
                floor=None,
                phase=_PHASES[self._phase],
                level_pa=self.level + self._correction if self._n else math.nan,
                elevation_m=math.nan,
                floors_known=0,
                since_ns=self._since,
            )
        registry = self.registry
        here = registry.relative_pa(self._floor)
        lowest = max(registry.relative_pa(i) for i in range(len(registry)))
        floor_level = self._anchor - self._offset
        return FloorState(
            t_ns=self._t,
            floor=registry.index(self._floor),
            phase=_PHASES[self._phase],
            level_pa=floor_level + self._correction,
            elevation_m=height_difference_m(
                floor_level + lowest - here, floor_level, self._temperature
            ),
            floors_known=len(registry),
            since_ns=self._since,
        )

    # -- decisions -----------------------------------------------------------------------

    def _first(self, t: int, p: float) -> list[FloorEvent]:
        if not math.isfinite(p):
            self.ignored_samples += 1
            return []
        self._n = 1
        self._t = self._since = t
        self.level = self.smoothed = p
        self.rate = 0.0
        self._window.push(t, p, p)
        self._anchor = p
        self._thresholds(p)
        return []

    def _thresholds(self, p: float) -> None:
        c = self.config
        gradient = pa_per_m(p, self._temperature)
        self._start_pa = c.start_m * gradient
        self._start_rate = c.start_rate_m_s * gradient
        self._settle_rate = c.settle_rate_m_s * gradient
        self._settle_band = self._settle_rate * c.settle_s

    def _gap(self, t: int, p: float) -> None:
        """No data for longer than ``max_gap_s``: the robot may have moved meanwhile."""
        log.info("pressure gap", seconds=(t - self._t) / NS_PER_S)
        previous = self._t
        self._n += 1
        self._t = t
        self.level = self.smoothed = p
        self.rate = 0.0
        self._continued = None
        if self._phase == _SETTLED:
            if self._arrival_until >= 0:
                self._arrived()
            self._anchor += self._drift * (t - previous) * 1e-9
            self._calm_ns = previous
            self._begin_change()
        else:
            self._window.clear()  # what came before the gap says nothing about now
        self._window.push(t, p, p)

    def _begin_change(self) -> None:
        self._window.clear()  # stillness is judged on what came after the change began
        self._phase = _CHANGING
        self._since = self._t
        self._change_start = self._calm_ns

    def _arriving(self, dt: float, smoothed: float, rate: float, quiet: bool) -> list[FloorEvent]:
        """Just arrived: the floor's level follows the pressure while the air settles."""
        self._arrival_level += self._drift * dt
        error = smoothed - self._arrival_level
        if (
            error > self._start_pa
            or error < -self._start_pa
            or rate > self._start_rate
            or rate < -self._start_rate
        ):
            self._anchor += self._drift * dt
            self._continued = self._arrival_record
            self._arrived()
            self._begin_change()
            return []
        self._anchor = self.smoothed
        if quiet:
            self._calm_ns = self._t
        return []

    def _arrived(self) -> None:
        """The arrival is over: the level the floor has now is the one it arrived at."""
        self._arrival_until = -1
        moved = self._anchor - self._arrival_level
        record = self._arrival_record
        self._arrival_record = None
        if record is None:
            return
        record.delta_pa += moved
        record.level_pa += moved
        if record.new_floor and record.to_id == self._floor:
            self.registry.move(self._floor, moved)

    def _arrive(self, t: int, settled: float, record: TransitionRecord | None) -> None:
        self._arrival_until = t + self._landing_ns
        self._arrival_level = settled
        self._arrival_record = record

    def _settled(self, t: int, settled: float, t_end: int, *, at_end: bool) -> list[FloorEvent]:
        self._thresholds(settled)
        continued = self._continued
        self._continued = None
        if self._floor < 0:
            # First settle of the run: this is where we are.
            self._floor = self.registry.add(0.0)
            self._enter(t, settled, 0.0)
            self._arrive(t, settled, None)
            return []
        floor_level = self._anchor - self._offset
        step = settled - floor_level
        min_pa = pressure_drop_pa(self.config.min_transition_m, settled, self._temperature)
        if abs(step) < min_pa:
            self._sub_threshold(t, t_end, settled, step, floor_level, last=continued)
            return []
        relative = self.registry.relative_pa(self._floor) + step
        to_id = self.registry.match(relative, min_pa, exclude=self._floor)
        new_floor = to_id is None
        if to_id is None:
            to_id = self.registry.add(relative)
        else:
            self.registry.revisit(to_id)
        t_start = self._change_start
        if (
            self._departed_ns >= 0
            and self._offset * step > 0.0
            and self._change_start - self._landed_ns <= self._landing_ns
        ):
            t_start = self._departed_ns  # the trip paused on a landing: it began earlier
        record = TransitionRecord(
            t_ns=t,
            t_start_ns=t_start,
            t_end_ns=t_end,
            from_id=self._floor,
            to_id=to_id,
            delta_pa=step,
            level_pa=settled + self._correction,
            temperature_c=self._temperature,
            at_end=at_end,
            new_floor=new_floor,
        )
        self.transitions.append(record)
        event = FloorEvent(
            t_ns=t,
            t_start_ns=record.t_start_ns,
            t_end_ns=t_end,
            from_floor=self.registry.index(self._floor),
            to_floor=self.registry.index(to_id),
            delta_pa=step,
            delta_m=height_difference_m(floor_level, settled, self._temperature),
            level_pa=record.level_pa,
        )
        log.debug(
            "floor transition",
            from_floor=event.from_floor,
            to_floor=event.to_floor,
            delta_m=round(event.delta_m, 2),
        )
        self._floor = to_id
        self._enter(t, settled, 0.0)
        self._arrive(t, settled, record)
        return [event]

    def _sub_threshold(
        self,
        t: int,
        t_end: int,
        settled: float,
        step: float,
        floor_level: float,
        *,
        last: TransitionRecord | None,
    ) -> None:
        """Settled short of a floor change: a landing, a ramp, or a spike that went away.

        ``last`` is the transition whose arrival this change interrupted, if it did.
        """
        if (
            last is not None
            and last.new_floor
            and not last.completed
            and last.to_id == self._floor
            and step * last.delta_pa > 0.0
        ):
            # A first visit decided on a landing (or in a lull of the ride): the change began
            # while the robot was still arriving and went on the same way, so the trip went
            # on and the floor is where it ended. Only once, and only for a floor never seen
            # before (a known floor's level is already known: a leg away from it is a trip).
            last.completed = True
            last.t_end_ns = t_end
            last.delta_pa += step
            last.level_pa = settled + self._correction
            self.registry.move(self._floor, step)
            self._departed_ns = -1
            self._enter(t, settled, 0.0)
            self._arrive(t, settled, last)
            return
        offset = settled - floor_level
        if abs(offset) < self._start_pa:
            self._departed_ns = -1  # back at (or never left) the floor's level
        elif (
            self._departed_ns < 0
            or offset * self._offset <= 0.0
            or self._change_start - self._landed_ns > self._landing_ns
        ):
            # a new trip: the first leg, a turn back, or a leg after a stop too long for a
            # landing (the robot stayed at the old offset; that was no part of this trip)
            self._departed_ns = self._change_start
        self._landed_ns = t_end
        self._enter(t, settled, offset)

    def _enter(self, t: int, settled: float, offset: float) -> None:
        self._phase = _SETTLED
        self._since = t
        self._calm_ns = t
        self._anchor = settled
        self._offset = offset


class StillWindow:
    """The latest samples spanning at least ``window_ns``: were they still all along?

    Holds the shortest run of recent samples that spans the window, with running sums for a
    least-squares line through the raw pressures (:meth:`slope`) and monotonic queues for the
    highest and lowest smoothed pressure (:meth:`spread`), so each sample costs O(1) amortised
    at any sample rate. Sums are taken about an origin that is moved every ``_REBASE_NS``, so
    they stay small and removing old samples does not eat their precision.
    """

    __slots__ = (
        "_highs",
        "_lows",
        "_p0",
        "_samples",
        "_sx",
        "_sxx",
        "_sxy",
        "_sy",
        "_t0",
        "window_ns",
    )

    def __init__(self, window_ns: int) -> None:
        self.window_ns = window_ns
        self._samples: deque[tuple[int, float, float]] = deque()  # (t_ns, x s, y Pa)
        self._highs: deque[tuple[int, float]] = deque()  # (t_ns, smoothed), decreasing
        self._lows: deque[tuple[int, float]] = deque()  # (t_ns, smoothed), increasing
        self._t0 = 0
        self._p0 = 0.0
        self._sx = self._sxx = self._sy = self._sxy = 0.0

    @property
    def count(self) -> int:
        return len(self._samples)

    @property
    def start_ns(self) -> int:
        """Time of the oldest sample in the window (-1 when empty)."""
        return self._samples[0][0] if self._samples else -1

    def clear(self) -> None:
        self._samples.clear()
        self._highs.clear()
        self._lows.clear()
        self._sx = self._sxx = self._sy = self._sxy = 0.0

    def push(self, t: int, p: float, smoothed: float) -> None:
        samples = self._samples
        if not samples:
            self._t0, self._p0 = t, p
        elif t - self._t0 > _REBASE_NS:
            self._rebase(t, p)
        x = (t - self._t0) * 1e-9
        y = p - self._p0
        samples.append((t, x, y))
        self._sx += x
        self._sxx += x * x
        self._sy += y
        self._sxy += x * y
        highs = self._highs
        while highs and highs[-1][1] <= smoothed:
            highs.pop()
        highs.append((t, smoothed))
        lows = self._lows
        while lows and lows[-1][1] >= smoothed:
            lows.pop()
        lows.append((t, smoothed))
        limit = t - self.window_ns
        while len(samples) > 1 and samples[1][0] <= limit:
            _, x, y = samples.popleft()
            self._sx -= x
            self._sxx -= x * x
            self._sy -= y
            self._sxy -= x * y
        oldest = samples[0][0]
        while highs[0][0] < oldest:
            highs.popleft()
        while lows[0][0] < oldest:
            lows.popleft()

    def slope(self) -> float:
        """Least-squares slope of the raw pressures over the window, Pa/s (0 if undefined)."""
        n = len(self._samples)
        sxx = n * self._sxx - self._sx * self._sx
        if n < 2 or sxx <= 0.0:
            return 0.0
        return (n * self._sxy - self._sx * self._sy) / sxx

    def spread(self) -> float:
        """Highest minus lowest smoothed pressure over the window, Pa."""
        if not self._samples:
            return 0.0
        return self._highs[0][1] - self._lows[0][1]

    def _rebase(self, t: int, p: float) -> None:
        shift_y = self._p0 - p
        self._t0, self._p0 = t, p
        old = list(self._samples)
        self._samples.clear()
        self._sx = self._sxx = self._sy = self._sxy = 0.0
        for ti, _, yi in old:
            x = (ti - t) * 1e-9
            y = yi + shift_y
            self._samples.append((ti, x, y))
            self._sx += x
            self._sxx += x * x
            self._sy += y
            self._sxy += x * y
