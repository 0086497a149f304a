"""Plan a run: which floors in which order, and how the robot explores each of them.

The default follows the paper's run through Steinman Hall: start on floor 5 (1-based, as the
paper counts), then 6, 4, 3, 2, 1, and then back to a floor seen before, so a revisit must be
recognised as the same floor. On each floor the robot leaves the elevator into the lobby,
visits rooms and corridor ends along the navigation graph (turning in place, driving at
0.3-0.6 m/s), which closes loops through the lobby and around ring corridors, and returns to
the lobby to wait for the elevator. Time is budgeted so the whole run lasts what was asked.

A ride past at least one floor may stop at one of them on the way (``stops``): ``"stay"``,
the car halts for its door cycle with the robot inside (part of the ride); ``"leave"``, the
robot drives out to the lobby to make room, waits, and drives back in (a short visit).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from baromap.errors import ConfigError
from baromap.sim.building import Building, FloorPlan
from baromap.sim.motion import Moves, MovesBuilder, trapezoid_duration


@dataclass(frozen=True, slots=True)
class DriveProfile:
    """How the (tele-operated) P3-AT moves: ARIA-like accelerations, cautious indoor speeds."""

    speed_min_mps: float = 0.3
    speed_max_mps: float = 0.6
    accel_mps2: float = 0.3
    turn_rate_radps: float = math.radians(40.0)
    turn_accel_radps2: float = math.radians(100.0)


@dataclass(frozen=True, slots=True)
class ElevatorProfile:
    """An old building's elevator: slow car, slow doors, waiting for it to come."""

    speed_mps: float = 1.0
    accel_mps2: float = 0.6
    call_wait_s: tuple[float, float] = (8.0, 30.0)
    doors_close_s: tuple[float, float] = (4.0, 8.0)
    doors_open_s: tuple[float, float] = (2.0, 5.0)


#: What the car does at a passing floor: nothing, halt with the robot in, or let it out.
STOP_KINDS = ("none", "stay", "leave")
#: How long the robot waits in the lobby when it left the car to make room, s.
LEAVE_WAIT_S = (3.0, 10.0)


@dataclass(frozen=True, slots=True)
class _Stop:
    """A stop at a passing floor: door opening, a wait (robot out of the car), closing."""

    floor: int
    opening_s: float
    wait_s: float
    closing_s: float


@dataclass(frozen=True, slots=True)
class Visit:
    """One stay on a floor, as planned (seconds from the run's start)."""

    floor: int
    t_arrive_s: float
    t_leave_s: float


def default_route(floors: int) -> tuple[int, ...]:
    """The paper's order generalised: second-highest, highest, then down, then one revisit."""
    if floors == 1:
        return (0,)
    if floors == 2:
        return (0, 1, 0)
    return (floors - 2, floors - 1, *range(floors - 3, -1, -1), (floors - 1) // 2)


def check_route(route: Sequence[int], floors: int) -> tuple[int, ...]:
    out = tuple(int(f) for f in route)
    if not out:
        raise ConfigError("a route needs at least one floor")
    for f in out:
        if not 0 <= f < floors:
            raise ConfigError(f"route floor {f} outside 0..{floors - 1}")
    for a, b in itertools.pairwise(out):
        if a == b:
            raise ConfigError(f"route repeats floor {a} without leaving it")
    return out


def check_stops(stops: str) -> str:
    if stops not in STOP_KINDS:
        raise ConfigError(f"stops must be one of {', '.join(STOP_KINDS)}, not {stops!r}")
    return stops


class _FloorNav:
    """Shortest paths on one floor's navigation graph."""

    def __init__(self, plan: FloorPlan) -> None:
        self.plan = plan
        nodes = plan.nav.nodes
        edges = plan.nav.edges
        w = plan.nav.lengths()
        n = len(nodes)
        graph = csr_matrix(
            (
                np.concatenate([w, w]),
                (
                    np.concatenate([edges[:, 0], edges[:, 1]]),
                    np.concatenate([edges[:, 1], edges[:, 0]]),
                ),
            ),
            shape=(n, n),
        )
        self.dist, self.pred = dijkstra(graph, directed=False, return_predecessors=True)

    def path(self, a: int, b: int) -> list[int]:
        if a == b:
            return [a]
        if not np.isfinite(self.dist[a, b]):
            raise ConfigError(f"floor {self.plan.index}: node {b} unreachable from {a}")
        out = [b]
        while out[-1] != a:
            out.append(int(self.pred[a, out[-1]]))
        return out[::-1]

    def reachable(self, a: int, b: int) -> bool:
        return bool(np.isfinite(self.dist[a, b]))


class Planner:
    """Turns a route and a time budget into the robot's moves."""

    def __init__(
        self,
        building: Building,
        rng: np.random.Generator,
        drive: DriveProfile = DriveProfile(),
        elevator: ElevatorProfile = ElevatorProfile(),
    ) -> None:
        self.building = building
        self.rng = rng
        self.drive = drive
        self.elevator = elevator
        self.navs = [_FloorNav(f) for f in building.floors]

    # -- timing of a path ------------------------------------------------------------------
    def _simplify(self, plan: FloorPlan, path: Sequence[int]) -> list[tuple[float, float]]:
        pts = [tuple(plan.nav.nodes[n]) for n in path]
        out = [pts[0]]
        for i in range(1, len(pts) - 1):
            a, b, c = np.array(out[-1]), np.array(pts[i]), np.array(pts[i + 1])
            h1 = math.atan2(*(b - a)[::-1])
            h2 = math.atan2(*(c - b)[::-1])
            if abs(math.remainder(h2 - h1, math.tau)) > math.radians(2.0):
                out.append(pts[i])
        if len(pts) > 1:
            out.append(pts[-1])
        return [(float(x), float(y)) for x, y in out]

    def _speed(self, length: float) -> float:
        d = self.drive
        base = d.speed_min_mps + (d.speed_max_mps - d.speed_min_mps) * min(1.0, length / 8.0)
        return float(np.clip(base + self.rng.normal(0, 0.04), d.speed_min_mps, d.speed_max_mps))

    def _legs(
        self, heading: float, pts: Sequence[tuple[float, float]]
    ) -> tuple[list[tuple[float, float, float, float]], float, float]:
        """Turn-then-drive legs (heading, x, y, speed), their total time, the final heading."""
        d = self.drive
        legs = []
        total = 0.0
        for (ax, ay), (bx, by) in itertools.pairwise(pts):
            length = math.hypot(bx - ax, by - ay)
            if length < 1e-3:
                continue
            h = math.atan2(by - ay, bx - ax)
            speed = self._speed(length)
            total += trapezoid_duration(
                math.remainder(h - heading, math.tau), d.turn_rate_radps, d.turn_accel_radps2
            )
            total += trapezoid_duration(length, speed, d.accel_mps2)
            legs.append((h, bx, by, speed))
            heading = h
        return legs, total, heading

    def _follow(self, mb: MovesBuilder, legs: Sequence[tuple[float, float, float, float]]) -> None:
        d = self.drive
        for heading, x, y, speed in legs:
            mb.turn_to(heading, d.turn_rate_radps, d.turn_accel_radps2)
            mb.drive_to(x, y, speed, d.accel_mps2)

    # -- exploring one floor ---------------------------------------------------------------
    def _targets(self, plan: FloorPlan, nav: _FloorNav) -> list[list[int]]:
        targets = [list(r.waypoints) for r in plan.rooms]
        targets += [[n] for n in plan.explore_nodes]
        return [t for t in targets if nav.reachable(plan.lobby_node, t[0])]

    def _excursion(self, nav: _FloorNav, here: int, target: list[int]) -> list[int]:
        """Nodes from ``here`` to the target, around a room's loop of waypoints and back."""
        entry = min(range(len(target)), key=lambda i: nav.dist[here, target[i]])
        loop = target[entry:] + target[:entry]
        if len(loop) > 1:
            if self.rng.random() < 0.5:
                loop = [loop[0], *loop[1:][::-1]]
            loop = [*loop, loop[0]]
        nodes = nav.path(here, loop[0])
        for a, b in itertools.pairwise(loop):
            nodes += nav.path(a, b)[1:]
        return nodes

    def explore(self, mb: MovesBuilder, floor: int, budget_s: float, seen: set[int]) -> None:
        """Visit targets until the budget would not cover another one and the way back."""
        nav = self.navs[floor]
        plan = nav.plan
        lobby = plan.lobby_node
        targets = self._targets(plan, nav)
        if floor in seen and targets:
            # A revisit: go back to places mapped before (loop closures across visits).
            order = self.rng.permutation(len(targets))
            targets = [targets[i] for i in order[: max(2, len(targets) // 3)]]
        todo = list(range(len(targets)))
        here = lobby
        heading = float(mb.state[2])
        spent = 0.0
        while True:
            if not todo:
                todo = list(range(len(targets)))
            if not todo:
                break
            costs = sorted(todo, key=lambda i: nav.dist[here, targets[i][0]])
            pick = costs[min(len(costs) - 1, int(self.rng.integers(0, 3)))]
            nodes = self._excursion(nav, here, targets[pick])
            legs, t_go, h_end = self._legs(heading, self._simplify(plan, nodes))
            _, t_back, _ = self._legs(h_end, self._simplify(plan, nav.path(nodes[-1], lobby)))
            if spent + t_go + t_back > budget_s:
                # Try cheaper targets before giving up.
                todo.remove(pick)
                if not todo:
                    break
                continue
            self._follow(mb, legs)
            spent += t_go
            heading = h_end
            here = nodes[-1]
            todo.remove(pick)
        legs, _, _ = self._legs(heading, self._simplify(plan, nav.path(here, lobby)))
        self._follow(mb, legs)

    # -- the whole run ---------------------------------------------------------------------
    def plan(
        self,
        route: Sequence[int],
        duration_s: float,
        *,
        stops: str = "none",
        stop_rng: np.random.Generator | None = None,
    ) -> tuple[Moves, list[Visit]]:
        b = self.building
        el = self.elevator
        lobby_xy = b.lobby_xy
        car_xy = b.elevator_xy
        floors = b.floors
        mb = MovesBuilder(
            lobby_xy[0], lobby_xy[1], math.pi / 2, floors[route[0]].elevation_m, route[0]
        )
        warmup = 15.0
        into_car = trapezoid_duration(
            math.dist(lobby_xy, car_xy), self.drive.speed_min_mps, self.drive.accel_mps2
        ) + trapezoid_duration(math.pi, self.drive.turn_rate_radps, self.drive.turn_accel_radps2)
        rides = []
        on_the_way: list[_Stop | None] = []
        for a, c in itertools.pairwise(route):
            stop = self._stop(a, c, check_stops(stops), stop_rng)
            on_the_way.append(stop)
            if stop is None:
                ride_s = trapezoid_duration(
                    abs(floors[c].elevation_m - floors[a].elevation_m), el.speed_mps, el.accel_mps2
                )
            else:
                z = [floors[f].elevation_m for f in (a, stop.floor, c)]
                ride_s = sum(
                    trapezoid_duration(abs(z1 - z0), el.speed_mps, el.accel_mps2)
                    for z0, z1 in itertools.pairwise(z)
                )
                ride_s += stop.opening_s + stop.wait_s + stop.closing_s
                if stops == "leave":
                    ride_s += 2 * into_car
            rides.append(
                (
                    self.rng.uniform(*el.call_wait_s),
                    self.rng.uniform(*el.doors_close_s),
                    ride_s,
                    self.rng.uniform(*el.doors_open_s),
                )
            )
        fixed = warmup + sum(sum(r) + 2 * into_car for r in rides)
        weights = []
        seen_w: set[int] = set()
        for f in route:
            weights.append(0.5 if f in seen_w else 1.0)
            seen_w.add(f)
        explore_total = max(0.0, duration_s - fixed)
        budgets = [explore_total * w / sum(weights) for w in weights]
        visits: list[Visit] = []
        seen: set[int] = set()
        mb.wait(warmup)
        for i, floor in enumerate(route):
            arrive = mb.t
            if i > 0:
                mb.drive_to(*lobby_xy, self.drive.speed_min_mps, self.drive.accel_mps2)
            self.explore(mb, floor, budgets[i] - (mb.t - arrive), seen)
            seen.add(floor)
            if i == len(route) - 1:
                visits.append(Visit(floor, arrive, duration_s))
                break
            call, close, _, opened = rides[i]
            # Slack left over from exploring is spent waiting for the elevator.
            slack = max(0.0, arrive + budgets[i] - mb.t)
            mb.turn_to(math.pi / 2, self.drive.turn_rate_radps, self.drive.turn_accel_radps2)
            mb.wait(call + slack)
            mb.drive_to(*car_xy, self.drive.speed_min_mps, self.drive.accel_mps2)
            mb.turn_to(-math.pi / 2, self.drive.turn_rate_radps, self.drive.turn_accel_radps2)
            mb.wait(close)
            leave = mb.t
            visits.append(Visit(floor, arrive, leave))
            stop = on_the_way[i]
            if stop is not None:
                mb.ride(floors[stop.floor].elevation_m, stop.floor, el.speed_mps, el.accel_mps2)
                if stops == "stay":
                    mb.halt(stop.opening_s + stop.wait_s + stop.closing_s)
                else:
                    visits.append(self._make_room(mb, stop))
            nxt = route[i + 1]
            mb.ride(floors[nxt].elevation_m, nxt, el.speed_mps, el.accel_mps2)
            mb.wait(opened)
        if mb.t < duration_s:
            mb.wait(duration_s - mb.t)
        return mb.build(), visits

    def _stop(self, a: int, c: int, stops: str, rng: np.random.Generator | None) -> _Stop | None:
        """Where (and for how long) a ride from ``a`` to ``c`` stops on the way, if it does."""
        if stops == "none" or abs(c - a) < 2:
            return None
        if rng is None:
            raise ConfigError("stops on the way need their own random stream")
        step = 1 if c > a else -1
        el = self.elevator
        return _Stop(
            floor=int(rng.choice(list(range(a + step, c, step)))),
            opening_s=float(rng.uniform(*el.doors_open_s)),
            wait_s=float(rng.uniform(*LEAVE_WAIT_S)) if stops == "leave" else 0.0,
            closing_s=float(rng.uniform(*el.doors_close_s)),
        )

    def _make_room(self, mb: MovesBuilder, stop: _Stop) -> Visit:
        """Out of the car to the lobby, a wait there, and back in (facing the doors)."""
        d = self.drive
        b = self.building
        arrive = mb.t
        mb.wait(stop.opening_s)
        mb.drive_to(*b.lobby_xy, d.speed_min_mps, d.accel_mps2)
        mb.turn_to(math.pi / 2, d.turn_rate_radps, d.turn_accel_radps2)
        mb.wait(stop.wait_s)
        mb.drive_to(*b.elevator_xy, d.speed_min_mps, d.accel_mps2)
        mb.turn_to(-math.pi / 2, d.turn_rate_radps, d.turn_accel_radps2)
        mb.wait(stop.closing_s)
        return Visit(stop.floor, arrive, mb.t)
