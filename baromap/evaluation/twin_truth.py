"""What really happened while a daemon recorded the pty twins, on the recording's own clock.

The daemon stamps every message on the host's Unix clock; the twins log, for every frame they
send, the instant its content was true on CLOCK_MONOTONIC and the simulated time it belongs to
(:mod:`baromap.sim.twins.truth`). The recording's metadata states the daemon's mapping between
the two host clocks, so each recorded time maps to the simulated run's time and from there to
the scenario: where the robot was, on which floor, when the car moved. That holds at any speed
of the twins, which is what lets a demo run them faster than real time and still be scored
against the building it drove through.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray, IntArray
from baromap.errors import InputFormatError
from baromap.floors.evaluation import FloorTruth, truth_from_series
from baromap.messages import NS_PER_S
from baromap.recording import read_metadata, topics
from baromap.sim.motion import PoseSamples
from baromap.sim.scenario import Scenario
from baromap.sim.twins.truth import FrameTruth

#: Twins whose truth records carry route time (the robot's own clock, which stands still
#: while the base's watchdog holds it): the laser and the base. The barometer's carry the
#: run's clock, which the weather follows.
ROUTE_TIME_DEVICES = ("lms200", "p3at")
#: Truth sampled this often (simulated seconds) for floor and pose series.
TRUTH_STEP_S = 0.05


@dataclass(frozen=True, slots=True)
class HostClock:
    """The daemon's one mapping: ``unix_ns = wall0 + CLOCK_MONOTONIC - mono0``."""

    wall0_ns: int
    mono0_ns: int

    @classmethod
    def of_recording(cls, path: str | Path) -> HostClock:
        header = read_metadata(path).get(topics.METADATA_NAME, {})
        try:
            return cls(int(header["clock_wall0_ns"]), int(header["clock_mono0_ns"]))
        except (KeyError, ValueError) as exc:
            raise InputFormatError(
                f"{path} states no host clock mapping (not a baromapd recording?)"
            ) from exc

    def unix_ns(self, mono_ns: npt.ArrayLike) -> IntArray:
        out: IntArray = np.asarray(mono_ns, dtype=np.int64) - self.mono0_ns + self.wall0_ns
        return out


@dataclass(frozen=True, slots=True, eq=False)
class SimTimeline:
    """Recording time (Unix ns) against the robot's route time (simulated seconds)."""

    unix_ns: IntArray
    sim_s: FloatArray

    def sim_s_at(self, unix_ns: npt.ArrayLike) -> FloatArray:
        """Route time at recording times (clamped to the span the twins logged)."""
        t = np.asarray(unix_ns, dtype=np.int64)
        out: FloatArray = np.interp(t - self.unix_ns[0], self.unix_ns - self.unix_ns[0], self.sim_s)
        return out

    def unix_ns_at(self, sim_s: npt.ArrayLike) -> IntArray:
        """Recording time at route times (the first instant, where the route stood still)."""
        keep = np.concatenate([[True], np.diff(self.sim_s) > 0])
        wanted = np.asarray(sim_s, dtype=np.float64)
        rel = np.interp(wanted, self.sim_s[keep], self.unix_ns[keep] - self.unix_ns[0])
        out: IntArray = self.unix_ns[0] + np.round(rel).astype(np.int64)
        return out

    @property
    def speed(self) -> float:
        """Simulated seconds per recorded second over the whole span."""
        wall = (self.unix_ns[-1] - self.unix_ns[0]) / NS_PER_S
        return float((self.sim_s[-1] - self.sim_s[0]) / wall) if wall > 0 else float("nan")

    @property
    def span_s(self) -> tuple[float, float]:
        return float(self.sim_s[0]), float(self.sim_s[-1])


def sim_timeline(
    records: Iterable[FrameTruth],
    clock: HostClock,
    devices: tuple[str, ...] = ROUTE_TIME_DEVICES,
) -> SimTimeline:
    """The timeline from the twins' truth records (any order, other devices ignored)."""
    pairs = sorted((r.t_mono_ns, r.t_sim_s) for r in records if r.device in devices)
    if len(pairs) < 2:
        raise InputFormatError(f"the truth log holds fewer than two frames of {devices}")
    mono = np.array([p[0] for p in pairs], dtype=np.int64)
    sim = np.maximum.accumulate(np.array([p[1] for p in pairs], dtype=np.float64))
    return SimTimeline(clock.unix_ns(mono), sim)


@dataclass(frozen=True, slots=True, eq=False)
class TruthSeries:
    """The scenario's truth sampled along the recording's clock."""

    t_ns: IntArray
    sim_s: FloatArray
    poses: PoseSamples

    @property
    def xyt(self) -> FloatArray:
        out: FloatArray = np.column_stack([self.poses.x, self.poses.y, self.poses.theta])
        return out

    @property
    def floor(self) -> IntArray:
        """True floor, -1 while the car moves (or halts on the way)."""
        return self.poses.floor

    def floor_truth(self) -> FloorTruth:
        """Transitions and floors for :func:`baromap.floors.evaluation.score`, heights too."""
        floor = np.where(self.floor >= 0, self.floor, np.nan).astype(np.float64)
        return truth_from_series(self.t_ns, floor, self.poses.z)

    def distance_m(self) -> float:
        """How far the robot drove (metres, rides excluded)."""
        step = np.hypot(np.diff(self.poses.x), np.diff(self.poses.y))
        return float(np.sum(step[(self.floor[1:] >= 0) & (self.floor[:-1] >= 0)]))


def truth_series(
    scenario: Scenario, timeline: SimTimeline, step_s: float = TRUTH_STEP_S
) -> TruthSeries:
    """The truth every ``step_s`` simulated seconds over the span the twins logged."""
    first, last = timeline.span_s
    sim = np.arange(first, last, step_s)
    return TruthSeries(timeline.unix_ns_at(sim), sim, scenario.truth(sim))
