"""The robot's true motion as a list of simple moves, evaluated at any times at once.

A P3-AT driven through a building does four things: stand still, turn in place, drive
straight, and ride an elevator (which may halt at a floor on the way, the robot inside).
Each move follows a trapezoidal speed profile (accelerate, cruise, brake) as the robot's own
motion controller does, so velocities and accelerations are realistic for odometry, and every
quantity has a closed form: a whole 46-minute run is sampled at any rate with a handful of
numpy operations, and a real-time twin asks for "now".
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from baromap.arrays import FloatArray, IntArray


class Move(enum.IntEnum):
    WAIT = 0
    TURN = 1
    DRIVE = 2
    RIDE = 3
    #: The car stands at a passing floor with the robot inside: still part of the ride.
    HALT = 4


def trapezoid_duration(distance: float, vmax: float, accel: float) -> float:
    """Time to cover ``distance`` from rest to rest with speed limit and acceleration."""
    d = abs(distance)
    if d == 0.0:
        return 0.0
    if d < vmax * vmax / accel:
        return float(2.0 * np.sqrt(d / accel))
    return d / vmax + vmax / accel


def trapezoid_progress(
    tau: FloatArray, distance: FloatArray, vmax: FloatArray, accel: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Distance covered and speed at time ``tau`` into a rest-to-rest move (all elementwise)."""
    d = np.abs(distance)
    triangular = d < vmax * vmax / np.maximum(accel, 1e-12)
    peak = np.where(triangular, np.sqrt(d * accel), vmax)
    t_acc = peak / np.maximum(accel, 1e-12)
    total = np.where(triangular, 2.0 * t_acc, d / np.maximum(vmax, 1e-12) + t_acc)
    tau = np.clip(tau, 0.0, total)
    rising = tau < t_acc
    falling = tau > total - t_acc
    s = np.where(
        rising,
        0.5 * accel * tau * tau,
        np.where(
            falling,
            d - 0.5 * accel * (total - tau) ** 2,
            0.5 * accel * t_acc * t_acc + peak * (tau - t_acc),
        ),
    )
    v = np.where(rising, accel * tau, np.where(falling, accel * (total - tau), peak))
    s = np.where(d > 0, np.minimum(s, d), 0.0)
    v = np.where(d > 0, np.maximum(v, 0.0), 0.0)
    return s, v


@dataclass(frozen=True, slots=True)
class Moves:
    """Moves back to back in time; arrays of one entry per move (times in seconds from start)."""

    t0: FloatArray
    duration: FloatArray
    kind: IntArray
    floor: IntArray
    to_floor: IntArray
    start: FloatArray  # (S, 4): x, y, theta, z at the move's start
    delta: FloatArray  # (S, 4): change over the move
    vmax: FloatArray
    accel: FloatArray

    @property
    def end_s(self) -> float:
        return float(self.t0[-1] + self.duration[-1]) if len(self.t0) else 0.0

    def __len__(self) -> int:
        return len(self.t0)


@dataclass(frozen=True, slots=True)
class PoseSamples:
    """Truth at sample times: pose, storey and speeds (robot frame)."""

    t_s: FloatArray
    x: FloatArray
    y: FloatArray
    theta: FloatArray
    z: FloatArray
    #: Floor the robot stands on; -1 while the elevator car is moving or halted on the way.
    floor: IntArray
    v: FloatArray
    omega: FloatArray
    vz: FloatArray
    move: IntArray


def sample(moves: Moves, t_s: npt.ArrayLike) -> PoseSamples:
    """The robot's true state at the given times (clamped to the plan's extent)."""
    t = np.asarray(t_s, dtype=np.float64)
    idx = np.clip(np.searchsorted(moves.t0, t, side="right") - 1, 0, len(moves) - 1)
    tau = t - moves.t0[idx]
    kind = moves.kind[idx]
    delta = moves.delta[idx]
    dist = np.where(
        kind == Move.DRIVE,
        np.hypot(delta[:, 0], delta[:, 1]),
        np.where(kind == Move.TURN, np.abs(delta[:, 2]), np.abs(delta[:, 3])),
    )
    s, speed = trapezoid_progress(tau, dist, moves.vmax[idx], moves.accel[idx])
    frac = np.where(dist > 0, s / np.where(dist > 0, dist, 1.0), 0.0)
    state = moves.start[idx] + delta * frac[:, None]
    sign_turn = np.sign(delta[:, 2])
    sign_z = np.sign(delta[:, 3])
    v = np.where(kind == Move.DRIVE, speed, 0.0)
    omega = np.where(kind == Move.TURN, speed * sign_turn, 0.0)
    vz = np.where(kind == Move.RIDE, speed * sign_z, 0.0)
    riding = ((kind == Move.RIDE) & (tau > 0) & (tau < moves.duration[idx])) | (kind == Move.HALT)
    floor = np.where(
        riding, -1, np.where(tau >= moves.duration[idx], moves.to_floor[idx], moves.floor[idx])
    )
    theta = np.arctan2(np.sin(state[:, 2]), np.cos(state[:, 2]))
    return PoseSamples(
        t_s=t,
        x=state[:, 0],
        y=state[:, 1],
        theta=theta,
        z=state[:, 3],
        floor=floor.astype(np.int64),
        v=v,
        omega=omega,
        vz=vz,
        move=kind.astype(np.int64),
    )


class MovesBuilder:
    """Appends moves one after another, keeping the running state."""

    def __init__(self, x: float, y: float, theta: float, z: float, floor: int) -> None:
        self.state = np.array([x, y, theta, z], dtype=np.float64)
        self.floor = floor
        self.t = 0.0
        self._rows: list[
            tuple[float, float, int, int, int, list[float], list[float], float, float]
        ] = []

    def _add(
        self, kind: Move, duration: float, delta: list[float], *, vmax: float, accel: float, to: int
    ) -> None:
        if duration <= 0.0:
            return
        self._rows.append(
            (self.t, duration, int(kind), self.floor, to, self.state.tolist(), delta, vmax, accel)
        )
        self.t += duration
        self.state = self.state + np.array(delta)
        self.floor = to

    def wait(self, duration: float) -> None:
        self._add(Move.WAIT, duration, [0.0, 0.0, 0.0, 0.0], vmax=0.0, accel=0.0, to=self.floor)

    def halt(self, duration: float) -> None:
        """The car stops at the floor it reached, doors open and close, the robot stays in."""
        self._add(Move.HALT, duration, [0.0, 0.0, 0.0, 0.0], vmax=0.0, accel=0.0, to=self.floor)

    def turn_to(self, heading: float, rate: float, accel: float) -> None:
        dth = float(np.arctan2(np.sin(heading - self.state[2]), np.cos(heading - self.state[2])))
        if abs(dth) < 1e-3:
            return
        self._add(
            Move.TURN,
            trapezoid_duration(dth, rate, accel),
            [0, 0, dth, 0],
            vmax=rate,
            accel=accel,
            to=self.floor,
        )

    def drive_to(self, x: float, y: float, speed: float, accel: float) -> None:
        dx, dy = x - self.state[0], y - self.state[1]
        d = float(np.hypot(dx, dy))
        if d < 1e-3:
            return
        self._add(
            Move.DRIVE,
            trapezoid_duration(d, speed, accel),
            [dx, dy, 0, 0],
            vmax=speed,
            accel=accel,
            to=self.floor,
        )

    def ride(self, z: float, to_floor: int, speed: float, accel: float) -> None:
        dz = z - float(self.state[3])
        self._add(
            Move.RIDE,
            trapezoid_duration(dz, speed, accel),
            [0, 0, 0, dz],
            vmax=speed,
            accel=accel,
            to=to_floor,
        )

    def build(self) -> Moves:
        rows = self._rows
        if not rows:
            self.wait(1.0)
            rows = self._rows
        return Moves(
            t0=np.array([r[0] for r in rows]),
            duration=np.array([r[1] for r in rows]),
            kind=np.array([r[2] for r in rows], dtype=np.int64),
            floor=np.array([r[3] for r in rows], dtype=np.int64),
            to_floor=np.array([r[4] for r in rows], dtype=np.int64),
            start=np.array([r[5] for r in rows], dtype=np.float64),
            delta=np.array([r[6] for r in rows], dtype=np.float64),
            vmax=np.array([r[7] for r in rows]),
            accel=np.array([r[8] for r in rows]),
        )
