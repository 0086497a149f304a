"""``baromap sim record``: a whole simulated run written straight to MCAP, with the truth.

Nothing waits on a clock: the run is sampled in time windows, scans are ray cast in batches,
and every message is built by the same protocol objects and conversions the live daemon
uses (LMS200 range words to a LaserScan, SIPs through the host's odometry integrator for
/odom, SAMPLE frames for /baro). Only the byte framing around them is skipped for speed; the
twins exercise it, and its round trips are tested on their own. So a recording made here holds
what the daemon would have recorded from the twins, plus the truth (/truth/pose at every scan,
/truth/floor every second and at every change) and a "baromap.sim" metadata record from which
an evaluator rebuilds the building.

Laser choice: 180 deg at 1 deg in mm units at 38400 baud, as the paper's era of Pioneer
setups ran it over RS-232: 372-byte telegrams give 10.3 scans per second. At 0.3-0.6 m/s and
40 deg/s turns that keeps the motion between scans under 6 cm and 4 deg, which scan matching
handles easily; 0.5 deg would halve the rate to 5 scans per second (8 deg per scan when
turning) for detail a 5 cm map does not need. The mm mode's 8.19 m range is the LMS200's
most accurate setting; corridors longer than that are what the clutter is there for.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import structlog

from baromap.arrays import FloatArray
from baromap.messages import Message, PressureSample, TruthFloor, TruthPose
from baromap.odometry.errors import OdometryErrorModel
from baromap.odometry.integrator import OdometryIntegrator
from baromap.odometry.robot_metadata import ROBOT_METADATA, robot_metadata
from baromap.protocols import baro
from baromap.protocols.robot_models import DEFAULT_MODEL, PIONEER_CLASS, RobotModel
from baromap.recording.frames import LaserMount
from baromap.sim.building import CAR_DOOR_WIDTH_M, CAR_RECT, ELEVATOR_XY, INTERIOR_WALL_M
from baromap.sim.laser import LaserConfig, Lms200Model
from baromap.sim.motion import PoseSamples
from baromap.sim.odometry import (
    SIP_PERIOD_S,
    OdometryModel,
    counters,
    sip,
    true_increments,
)
from baromap.sim.scenario import (
    REFERENCE_HEIGHT_M,
    ROBOT_SENSOR_HEIGHT_M,
    SIM_EPOCH_NS,
    STREAM_LASER,
    STREAM_ODOMETRY,
    Scenario,
    make_scenario,
    scenario_pressure_run,
)

log = structlog.get_logger(__name__)


METADATA_NAME = "baromap.sim"
REFERENCE_TOPIC = "/reference/pressure"
#: The simulated laser sits on the robot's centre, looking forward (its rays start at the
#: robot's pose); recorded as the static base_link -> laser transform like the daemon's.
LASER_MOUNT = LaserMount(0.0, 0.0, 0.0)
#: Where the closed car door stands (its inner face), blocking the laser during rides.
CAR_DOOR_SEGMENT = np.array(
    [
        [
            ELEVATOR_XY[0] - CAR_DOOR_WIDTH_M / 2,
            CAR_RECT[1] + INTERIOR_WALL_M / 2,
            ELEVATOR_XY[0] + CAR_DOOR_WIDTH_M / 2,
            CAR_RECT[1] + INTERIOR_WALL_M / 2,
        ]
    ]
)
WINDOW_S = 20.0


@dataclass(frozen=True, slots=True)
class RecordSummary:
    path: Path
    simulated_s: float
    wall_s: float
    counts: dict[str, int]


def doors_closed(sc: Scenario, t_s: FloatArray) -> npt.NDArray[np.bool_]:
    """Whether the elevator car's door is shut (from the ventilation model's seal times)."""
    v = sc.ventilation
    if len(v.seal_start_s) == 0:
        return np.zeros(len(t_s), dtype=bool)
    out: npt.NDArray[np.bool_] = np.any(
        (t_s[:, None] >= v.seal_start_s[None, :]) & (t_s[:, None] <= v.seal_end_s[None, :]),
        axis=1,
    )
    return out


def scan_floors(truth: PoseSamples, sc: Scenario) -> npt.NDArray[np.int64]:
    """Floor plan each scan sees: during a ride, the floor the car left (its door is shut)."""
    idx = np.clip(np.searchsorted(sc.moves.t0, truth.t_s, side="right") - 1, 0, len(sc.moves) - 1)
    out: npt.NDArray[np.int64] = np.where(truth.floor >= 0, truth.floor, sc.moves.floor[idx])
    return out


def sim_metadata(
    sc: Scenario,
    laser: LaserConfig,
    rate_hz: float,
    odo: OdometryErrorModel,
    model: RobotModel,
) -> dict[str, str]:
    b = sc.building
    return {
        "seed": str(sc.seed),
        "floors": str(sc.floors),
        "minutes": repr(sc.minutes),
        "drift_hpa_per_h": repr(sc.drift_hpa_per_h),
        "route": json.dumps(list(sc.route)),
        "start_ns": str(sc.start_ns),
        "baro_rate_hz": repr(rate_hz),
        "baro_height_m": repr(ROBOT_SENSOR_HEIGHT_M),
        "reference_height_m": repr(REFERENCE_HEIGHT_M),
        "reference_topic": REFERENCE_TOPIC,
        "laser": json.dumps(
            {
                "model": "LMS200",
                "angle_deg": laser.angle_deg,
                "resolution_deg": laser.resolution_cdeg / 100,
                "units": laser.units,
                "baud": laser.baud,
                "scan_rate_hz": laser.scan_rate_hz,
                "range_max_m": laser.range_max_m,
            }
        ),
        "laser_mount": LASER_MOUNT.to_json(),
        "robot_model": model.name,
        "odometry_errors": json.dumps(odo.as_dict()),
        "elevations_m": json.dumps([round(float(z), 3) for z in b.elevations_m]),
        "floor_names": json.dumps([f.name for f in b.floors]),
        "floor_kinds": json.dumps([f.kind for f in b.floors]),
        "mezzanine_m": repr(b.mezzanine_m),
        "elevator_xy": json.dumps(list(b.elevator_xy)),
        "transitions": json.dumps(
            [
                {
                    "t_start_ns": t.t_start_ns,
                    "t_end_ns": t.t_end_ns,
                    "from": t.from_floor,
                    "to": t.to_floor,
                }
                for t in sc.transitions()
            ]
        ),
        "frame": "building frame = world; /truth/pose in it; /odom starts at 0,0,0",
    }


class RunGenerator:
    """Produces the messages of one run in time order, window by window."""

    def __init__(
        self,
        *,
        seed: int,
        floors: int,
        minutes: float,
        drift_hpa_per_h: float,
        route: Sequence[int] | None,
        laser: LaserConfig,
        rate_hz: float,
        start_ns: int,
        model: RobotModel,
    ) -> None:
        self.sc = make_scenario(
            seed,
            floors=floors,
            minutes=minutes,
            drift_hpa_per_h=drift_hpa_per_h,
            route=route,
            start_ns=start_ns,
        )
        self.run = scenario_pressure_run(self.sc, rate_hz)
        self.laser = laser
        self.rate_hz = rate_hz
        self.lms = Lms200Model(laser, self.sc.rng(STREAM_LASER))
        odo_rng = self.sc.rng(STREAM_ODOMETRY)
        self.odo_errors = OdometryErrorModel.random(odo_rng)
        self.odometry = OdometryModel(self.odo_errors, odo_rng)
        self.model = model
        self.integrator = OdometryIntegrator(model)
        self.baro_clock_ppm = float(odo_rng.uniform(-800.0, 800.0))
        self.baro_boot_us = int(odo_rng.uniform(0.9e6, 1.6e6))
        dur = self.sc.duration_s
        self.t_scan = np.arange(0.013, dur, 1.0 / laser.scan_rate_hz)
        self.t_sip = np.arange(0.05, dur, SIP_PERIOD_S)
        self.metadata = sim_metadata(self.sc, laser, rate_hz, self.odo_errors, model)
        # What the daemon records for the model it chose: the simulated robot reports the
        # model's subclass in its SYNC2 echo, and the host takes the model from it.
        self.robot = robot_metadata(
            model, (self.sc.twins.robot_name, PIONEER_CLASS, model.name), "reported"
        )

    def windows(self) -> Iterator[list[tuple[int, int, str | None, Message]]]:
        dur = self.sc.duration_s
        n_windows = math.ceil(dur / WINDOW_S)
        prev_true = (
            float(self.sc.moves.start[0, 0]),
            float(self.sc.moves.start[0, 1]),
            float(self.sc.moves.start[0, 2]),
        )
        last_floor: int | None = -2
        for w in range(n_windows):
            lo, hi = w * WINDOW_S, min((w + 1) * WINDOW_S, dur)
            out: list[tuple[int, int, str | None, Message]] = []
            out += self._baro(lo, hi)
            out += self._scans(lo, hi)
            odo, prev_true = self._odometry(lo, hi, prev_true)
            out += odo
            floors, last_floor = self._truth_floor(lo, hi, last_floor)
            out += floors
            out.sort(key=lambda m: (m[0], m[1]))
            yield out

    def _baro(self, lo: float, hi: float) -> list[tuple[int, int, str | None, Message]]:
        run = self.run
        i0 = math.ceil(lo * self.rate_hz - 1e-9)
        i1 = min(math.ceil(hi * self.rate_hz - 1e-9), len(run.t_ns))
        out: list[tuple[int, int, str | None, Message]] = []
        for i in range(i0, i1):
            t_ns = int(run.t_ns[i])
            t_s = i / self.rate_hz
            device_us = (
                self.baro_boot_us + round(t_s * 1e6 * (1 + self.baro_clock_ppm * 1e-6))
            ) % baro.TIME_MODULO
            frame = baro.SampleFrame.from_values(
                i % baro.SEQ_MODULO,
                device_us,
                float(run.pressure_pa[i]),
                float(run.temperature_c[i]),
            )
            out.append((t_ns, 0, None, baro.to_pressure_sample(frame, t_ns)))
            ref = PressureSample(
                t_ns=t_ns,
                pressure_pa=float(run.reference_pa[i]),
                temperature_c=float(run.reference_temperature_c[i]),
                seq=i % baro.SEQ_MODULO,
            )
            out.append((t_ns, 1, REFERENCE_TOPIC, ref))
        return out

    def _scans(self, lo: float, hi: float) -> list[tuple[int, int, str | None, Message]]:
        t = self.t_scan[(self.t_scan >= lo) & (self.t_scan < hi)]
        if len(t) == 0:
            return []
        truth = self.sc.truth(t)
        floors = scan_floors(truth, self.sc)
        closed = doors_closed(self.sc, t)
        words = np.zeros((len(t), self.laser.beams), dtype=np.uint16)
        for f in np.unique(floors):
            for shut in (False, True):
                sel = (floors == f) & (closed == shut)
                if not sel.any():
                    continue
                segs = self.sc.building.floors[int(f)].walls_m
                if shut:
                    segs = np.concatenate([segs, CAR_DOOR_SEGMENT])
                words[sel] = self.lms.scans(segs, truth.x[sel], truth.y[sel], truth.theta[sel])
        t_ns = self.sc.t_ns(t)
        out: list[tuple[int, int, str | None, Message]] = []
        for i in range(len(t)):
            stamp = int(t_ns[i])
            out.append((stamp, 2, None, self.lms.laser_scan(words[i], stamp)))
            out.append(
                (
                    stamp,
                    3,
                    None,
                    TruthPose(
                        t_ns=stamp,
                        x_m=float(truth.x[i]),
                        y_m=float(truth.y[i]),
                        theta_rad=float(truth.theta[i]),
                        floor=int(truth.floor[i]),
                        z_m=float(truth.z[i]),
                    ),
                )
            )
        return out

    def _odometry(
        self, lo: float, hi: float, prev: tuple[float, float, float]
    ) -> tuple[list[tuple[int, int, str | None, Message]], tuple[float, float, float]]:
        t = self.t_sip[(self.t_sip >= lo) & (self.t_sip < hi)]
        if len(t) == 0:
            return [], prev
        truth = self.sc.truth(t)
        ds, dth = true_increments(truth.x, truth.y, truth.theta, prev)
        x, y, th = self.odometry.step(ds, dth)
        cx, cy, cth = counters(self.model, x, y, th)
        v = ds / SIP_PERIOD_S * (1.0 + self.odo_errors.scale)
        w = dth / SIP_PERIOD_S * (1.0 + self.odo_errors.rotation_scale)
        t_ns = self.sc.t_ns(t)
        out: list[tuple[int, int, str | None, Message]] = []
        for i in range(len(t)):
            packet = sip(
                self.model,
                x=cx[i],
                y=cy[i],
                theta=cth[i],
                v_mps=float(v[i]),
                omega_radps=float(w[i]),
                motors=True,
            )
            out.append((int(t_ns[i]), 4, None, self.integrator.update(packet, int(t_ns[i]))))
        last = (float(truth.x[-1]), float(truth.y[-1]), float(truth.theta[-1]))
        return out, last

    def _truth_floor(
        self, lo: float, hi: float, last: int | None
    ) -> tuple[list[tuple[int, int, str | None, Message]], int | None]:
        t = np.arange(math.ceil(lo * 10) / 10, hi, 0.1)
        truth = self.sc.truth(t)
        t_ns = self.sc.t_ns(t)
        out: list[tuple[int, int, str | None, Message]] = []
        for i in range(len(t)):
            floor = int(truth.floor[i])
            value = None if floor < 0 else floor
            whole_second = abs(t[i] - round(t[i])) < 1e-6
            if value != last or whole_second:
                out.append(
                    (
                        int(t_ns[i]),
                        5,
                        None,
                        TruthFloor(t_ns=int(t_ns[i]), floor=value, z_m=float(truth.z[i])),
                    )
                )
                last = value
        return out, last


def record_run(
    path: str | Path,
    *,
    seed: int = 0,
    floors: int = 6,
    minutes: float = 46.0,
    drift_hpa_per_h: float = 1.5,
    route: Sequence[int] | None = None,
    laser: LaserConfig | None = None,
    rate_hz: float = 25.0,
    start_ns: int = SIM_EPOCH_NS,
    model: RobotModel = DEFAULT_MODEL,
    progress: bool | None = None,
    overwrite: bool = False,
) -> RecordSummary:
    """Write a simulated run to ``path``; returns what was written and how long it took.

    ``model`` is the robot's base: the subclass it reports, the factors its counters are in,
    and the :data:`~baromap.odometry.robot_metadata.ROBOT_METADATA` record written with them.
    """
    from baromap.recording import RecordingWriter

    started = time.perf_counter()
    gen = RunGenerator(
        seed=seed,
        floors=floors,
        minutes=minutes,
        drift_hpa_per_h=drift_hpa_per_h,
        route=route,
        laser=laser or LaserConfig(),
        rate_hz=rate_hz,
        start_ns=start_ns,
        model=model,
    )
    show = sys.stderr.isatty() if progress is None else progress
    windows = gen.windows()
    bar = None
    if show:
        from tqdm import tqdm

        bar = tqdm(total=math.ceil(gen.sc.duration_s / WINDOW_S), unit="window", desc="sim record")
    header = {"source": "baromap.sim", "seed": str(seed), "floors": str(floors)}
    with RecordingWriter(
        path,
        robot="sim",
        metadata=header,
        laser_mount=LASER_MOUNT,
        fsync=False,  # a file written faster than real time, not a live run to protect
        allow_overwrite=overwrite,
    ) as writer:
        writer.write_metadata(METADATA_NAME, gen.metadata)
        writer.write_metadata(ROBOT_METADATA, gen.robot)
        for batch in windows:
            for _, _, topic, message in batch:
                writer.write(message, topic=topic)
            if bar is not None:
                bar.update(1)
        counts = dict(writer.counts)
    if bar is not None:
        bar.close()
    wall = time.perf_counter() - started
    log.info(
        "simulated run recorded", path=str(path), seconds=gen.sc.duration_s, wall_s=round(wall, 2)
    )
    return RecordSummary(Path(path), gen.sc.duration_s, wall, counts)
