"""The live map on a simulated run: it follows the detector's floors, resumes a floor it saw
before, and keeps the robot where it really was (the simulator's truth)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from baromap.errors import ConfigError
from baromap.floors import OnlineFloorDetector
from baromap.liveview.floor_map import LiveFloorMap, LiveMapSettings, LiveMapSnapshot
from baromap.mapping import se2
from baromap.messages import (
    NS_PER_S,
    FloorPhase,
    FloorState,
    LaserScan,
    Odometry,
    PressureSample,
    TruthPose,
)
from baromap.protocols.robot_models import DEFAULT_MODEL
from baromap.sim.laser import LaserConfig
from baromap.sim.record import LASER_MOUNT, RunGenerator
from baromap.sim.scenario import SIM_EPOCH_NS

#: The live map's keyframe poses against the truth, after the start's alignment (m): no loop
#: closure, so the drift of a few minutes' driving is allowed, not metres of it.
PATH_ERROR_M = 0.5


class Drive:
    """A simulated run fed to the live map as the daemon feeds it: floor states once a second
    of sample time (and at every event), odometry and scans as they come."""

    def __init__(self, minutes: float, route: tuple[int, ...]) -> None:
        self.gen = RunGenerator(
            seed=0,
            floors=3,
            minutes=minutes,
            drift_hpa_per_h=1.5,
            route=route,
            laser=LaserConfig(),
            rate_hz=25.0,
            start_ns=SIM_EPOCH_NS,
            model=DEFAULT_MODEL,
        )
        mount = (LASER_MOUNT.x_m, LASER_MOUNT.y_m, LASER_MOUNT.yaw_rad)
        self.map = LiveFloorMap(LiveMapSettings(), mount)
        self.detector = OnlineFloorDetector()
        #: (detector's floor id, the map's floor id) after each state
        self.floors: list[tuple[int | None, int | None]] = []
        self.snapshots: list[LiveMapSnapshot] = []
        self.keyframes: list[tuple[int, np.ndarray]] = []  # (t_ns, map pose)
        self.truth: list[TruthPose] = []
        self.phases: set[FloorPhase] = set()
        #: the detector's phase and floor as each keyframe was drawn
        self.drawn_while: list[tuple[FloorPhase, int | None]] = []

    def run(self) -> Drive:
        last_state: int | None = None
        phase, floor = FloorPhase.UNKNOWN, None
        for batch in self.gen.windows():
            for _, _, topic, message in batch:
                if isinstance(message, PressureSample) and topic in (None, "/baro"):
                    events = self.detector.update(message)
                    due = last_state is None or message.t_ns - last_state >= NS_PER_S
                    if events or due:
                        last_state = message.t_ns
                        state = self.detector.state()
                        phase, floor = state.phase, state.floor_id
                        self.phases.add(state.phase)
                        self.map.floor_state(state)
                        self.floors.append((state.floor_id, self.map.floor_id))
                elif isinstance(message, Odometry) and topic in (None, "/odom"):
                    self.detector.update_odometry(message)
                    self.map.odometry(message)
                elif isinstance(message, LaserScan):
                    drawn_before = self._drawn()
                    if self.map.scan(message) and self._drawn() > drawn_before:
                        self.keyframes.append((message.t_ns, self.map.snapshot().path[-1]))
                        self.drawn_while.append((phase, floor))
                elif isinstance(message, TruthPose):
                    self.truth.append(message)
        return self

    def _drawn(self) -> int:
        return sum(g.keyframes for g in self.map._floors.values())


@pytest.fixture(scope="module")
def drive() -> Drive:
    # floors 1 -> 2 -> 1 of a three-floor building: a new floor, then one seen before
    return Drive(minutes=7.0, route=(1, 2, 1)).run()


def test_the_map_follows_the_detectors_floor(drive: Drive) -> None:
    assert FloorPhase.CHANGING in drive.phases, "the run has no ride"
    decided = [d for d, _ in drive.floors if d is not None]
    assert decided[0] == 0 and 1 in decided and decided[-1] == 0  # start, up, back
    assert all(d == m for d, m in drive.floors if d is not None)
    # drawn only on a settled floor (or the start's, before the first settled pressure):
    # never while riding or while a stop is being decided
    assert drive.drawn_while, "nothing drawn"
    assert all(p is FloorPhase.SETTLED or f is None for p, f in drive.drawn_while)
    assert FloorPhase.SETTLED in {p for p, _ in drive.drawn_while}


def test_a_floor_seen_before_is_resumed_not_started_afresh(drive: Drive) -> None:
    start = drive.map._floors[0]
    upper = drive.map._floors[1]
    snapshot = drive.map.snapshot()
    assert snapshot.info.floor_id == 0
    assert snapshot.info.resumed
    # the start floor's grid holds both visits; the upper floor's only its own
    assert start.keyframes > upper.keyframes > 10
    assert snapshot.info.keyframes == start.keyframes
    assert snapshot.grid.shape == start.log_odds.shape
    # most keyframes matched against the floor's map, not placed by odometry alone
    for grid in (start, upper):
        assert grid.matched >= 0.9 * grid.keyframes


def test_the_live_path_stays_on_the_true_path(drive: Drive) -> None:
    truth_t = np.array([p.t_ns for p in drive.truth])
    truth_xyt = np.array([[p.x_m, p.y_m, p.theta_rad] for p in drive.truth])
    start = truth_xyt[0]  # the map frame is the odometry's at the start: the robot's start pose
    errors = []
    for t_ns, pose in drive.keyframes:
        i = min(int(np.searchsorted(truth_t, t_ns)), len(truth_t) - 1)
        true_in_map = se2.between(start, truth_xyt[i])
        errors.append(math.hypot(*(pose[:2] - true_in_map[:2])))
    assert len(errors) > 50
    assert max(errors) < PATH_ERROR_M, (
        f"worst {max(errors):.2f} m, median {np.median(errors):.2f} m"
    )


def test_settings_are_checked() -> None:
    with pytest.raises(ConfigError, match="resolution"):
        LiveMapSettings(resolution_m=2.0)
    with pytest.raises(ConfigError):
        LiveMapSettings(keyframe_deg=0.0)


def _state(t_s: float, phase: FloorPhase, floor: int | None) -> FloorState:
    return FloorState(
        t_ns=int(t_s * NS_PER_S),
        phase=phase,
        floor_id=floor,
        name=None if floor is None else str(floor),
        height_m=0.0 if floor is None else 4.0 * floor,
        level_m=0.0,
        level_pa=0.0,
        since_ns=0,
        floors_known=1 if floor is None else floor + 1,
    )


def _room_scan(t_s: float) -> LaserScan:
    """A scan of a 6 m round room from its middle: walls every beam sees."""
    beams = 181
    return LaserScan(
        t_ns=int(t_s * NS_PER_S),
        angle_min_rad=-math.pi / 2,
        angle_increment_rad=math.pi / (beams - 1),
        range_max_m=8.0,
        ranges_m=np.full(beams, 3.0, dtype=np.float32),
        flags=np.zeros(beams, dtype=np.uint16),
    )


def test_nothing_is_drawn_while_riding_and_the_next_floor_gets_its_own_grid() -> None:
    """A keyframe while the detector says CHANGING is counted, not drawn; once a floor is
    decided the keyframes go to that floor's grid."""
    live = LiveFloorMap(LiveMapSettings(), (0.0, 0.0, 0.0))
    t = 0.0
    for phase, floor, scans in (
        (FloorPhase.SETTLED, 0, 3),
        (FloorPhase.CHANGING, 0, 2),
        (FloorPhase.SETTLED, 1, 3),
    ):
        live.floor_state(_state(t, phase, floor))
        for _ in range(scans):
            t += 1.0
            # a turn on the spot per scan: a keyframe each time, the room the same
            live.odometry(Odometry(t_ns=int(t * NS_PER_S), x_m=0.0, y_m=0.0, theta_rad=t))
            assert live.scan(_room_scan(t))
    assert live.not_drawn == 2
    assert (live._floors[0].keyframes, live._floors[1].keyframes) == (3, 3)
    assert live.snapshot().info.floor_id == 1
