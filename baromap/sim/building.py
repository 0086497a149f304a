"""A simulated multi-floor building: one floor plan per storey, all in one building frame.

Every floor shares the shell (a 60 m x 24 m footprint) and the elevator core, so the maps of
all floors line up and the robot always leaves the elevator into the same lobby, as in a real
building. What differs per floor is the layout behind the lobby: an open ground floor with
pillars, a corridor with offices and deep labs, a ring of corridors (loop closures for SLAM),
a comb of branch corridors. Rooms get doors, corridors get pilasters, cabinets and benches,
rooms get desks and tables, some of them rotated: long corridors must not be perfectly
degenerate for scan matching, as they are not in real buildings.

Structure is built on a 5 cm raster (walls are 20 cm thick, the shell 30 cm) and the wall
segments are the exact boundary of that raster, plus the edges of rotated furniture. A
navigation graph (corridor centrelines, doors, room waypoints) is built alongside so the
route planner never has to search free space; every edge is checked for clearance.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import structlog
from scipy import ndimage

from baromap.arrays import BoolArray, FloatArray, IntArray
from baromap.errors import ConfigError

log = structlog.get_logger(__name__)


#: Building footprint (x, y) in metres; the building frame has its origin at the south-west corner.
FOOTPRINT_M = (60.0, 24.0)
#: Raster the structure is drawn on; every structural coordinate is a multiple of it.
RASTER_M = 0.05
INTERIOR_WALL_M = 0.2
EXTERIOR_WALL_M = 0.3
DOOR_WIDTH_M = 0.9
#: Lobby in front of the elevator (plan rectangle x0, y0, x1, y1), the same on every floor.
LOBBY_RECT = (26.0, 8.8, 34.0, 14.0)
#: Elevator car (plan rectangle); its door opens south onto the lobby.
CAR_RECT = (28.6, 14.0, 31.4, 16.8)
CAR_DOOR_WIDTH_M = 1.1
#: Elevator core: the car, a second (closed) shaft and the stairs.
CORE_RECT = (25.8, 14.0, 34.2, 17.0)
ELEVATOR_XY = (30.0, 15.4)
LOBBY_XY = (30.0, 11.4)
#: Nav edges keep this far from walls (the P3-AT is 0.50 m wide, 0.63 m long).
NAV_CLEARANCE_M = 0.3
#: Furniture keeps this far from nav edges.
NAV_KEEPOUT_M = 0.5


@dataclass(frozen=True, slots=True)
class Room:
    """A room the route can visit: its plan rectangle and its waypoints in visiting order."""

    name: str
    rect: tuple[float, float, float, float]
    waypoints: tuple[int, ...]


@dataclass(frozen=True, slots=True, eq=False)
class NavGraph:
    """Where the robot can drive: nodes (K, 2) in metres and undirected edges (E, 2)."""

    nodes: FloatArray
    edges: IntArray
    kinds: tuple[str, ...]

    def lengths(self) -> FloatArray:
        a = self.nodes[self.edges[:, 0]]
        b = self.nodes[self.edges[:, 1]]
        out: FloatArray = np.hypot(*(b - a).T)
        return out


@dataclass(frozen=True, slots=True, eq=False)
class FloorPlan:
    """One storey: its walls in the building frame, its height, and where the robot can go."""

    index: int
    name: str
    kind: str
    elevation_m: float
    walls_m: FloatArray
    nav: NavGraph
    rooms: tuple[Room, ...]
    lobby_node: int
    elevator_node: int
    explore_nodes: tuple[int, ...]
    free_raster: BoolArray = field(repr=False)

    def occupancy_truth(
        self,
        resolution_m: float,
        origin_xy: tuple[float, float] = (0.0, 0.0),
        shape: tuple[int, int] | None = None,
    ) -> BoolArray:
        """Cells a wall surface passes through, ``[row, col]`` = ``[y, x]``.

        ``origin_xy`` is the building-frame position of the corner of cell (0, 0); rows grow
        with y. This is what a laser can see (wall faces), not the solid inside the walls, so
        it compares directly with the occupied cells of a map built from scans.
        """
        if resolution_m <= 0:
            raise ConfigError(f"resolution must be positive, got {resolution_m}")
        if shape is None:
            shape = (
                math.ceil((FOOTPRINT_M[1] - origin_xy[1]) / resolution_m) + 1,
                math.ceil((FOOTPRINT_M[0] - origin_xy[0]) / resolution_m) + 1,
            )
        grid = np.zeros(shape, dtype=bool)
        points = segment_points(self.walls_m, resolution_m / 3.0)
        cols = np.floor((points[:, 0] - origin_xy[0]) / resolution_m).astype(np.int64)
        rows = np.floor((points[:, 1] - origin_xy[1]) / resolution_m).astype(np.int64)
        inside = (rows >= 0) & (rows < shape[0]) & (cols >= 0) & (cols < shape[1])
        grid[rows[inside], cols[inside]] = True
        return grid

    def is_free(self, xy: npt.ArrayLike) -> BoolArray:
        """Whether building-frame points lie in free space of this floor's structure."""
        pts = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        cols = np.clip((pts[:, 0] / RASTER_M).astype(np.int64), 0, self.free_raster.shape[1] - 1)
        rows = np.clip((pts[:, 1] / RASTER_M).astype(np.int64), 0, self.free_raster.shape[0] - 1)
        out: BoolArray = self.free_raster[rows, cols]
        return out


@dataclass(frozen=True, slots=True, eq=False)
class Building:
    """All floors, lowest first, and the elevator they share."""

    seed: int
    floors: tuple[FloorPlan, ...]
    elevator_xy: tuple[float, float]
    lobby_xy: tuple[float, float]
    footprint_m: tuple[float, float]
    #: Height of the unvisited mezzanine the elevator passes without stopping (None if none).
    mezzanine_m: float | None

    @property
    def elevations_m(self) -> FloatArray:
        return np.array([f.elevation_m for f in self.floors])


def segment_points(segments: FloatArray, step_m: float) -> FloatArray:
    """Points spaced at most ``step_m`` along each segment (both ends included)."""
    if len(segments) == 0:
        return np.zeros((0, 2))
    d = segments[:, 2:] - segments[:, :2]
    counts = np.maximum(1, np.ceil(np.hypot(d[:, 0], d[:, 1]) / step_m).astype(np.int64)) + 1
    seg = np.repeat(np.arange(len(segments)), counts)
    offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    frac = offsets / np.repeat(counts - 1, counts)
    out: FloatArray = segments[seg, :2] + d[seg] * frac[:, None]
    return out


def _cells(v: float) -> int:
    return round(v / RASTER_M)


class _Builder:
    """Draws one floor: carve free space, fill blocks, add furniture, grow the nav graph."""

    def __init__(self, rng: np.random.Generator, index: int) -> None:
        self.rng = rng
        self.index = index
        self.nx = _cells(FOOTPRINT_M[0])
        self.ny = _cells(FOOTPRINT_M[1])
        self.free = np.zeros((self.ny, self.nx), dtype=bool)
        self.nodes: list[tuple[float, float]] = []
        self.kinds: list[str] = []
        self.edges: set[tuple[int, int]] = set()
        self.corridors: list[tuple[str, float, list[int]]] = []
        self.rooms: list[Room] = []
        self.explore: list[int] = []
        self.polygons: list[FloatArray] = []
        self.pending_blocks: list[tuple[float, float, float, float]] = []
        self.pending_objects: list[FloatArray] = []

    # ---- raster ---------------------------------------------------------------------------
    def carve(self, x0: float, y0: float, x1: float, y1: float, value: bool = True) -> None:
        c0, c1 = sorted((_cells(x0), _cells(x1)))
        r0, r1 = sorted((_cells(y0), _cells(y1)))
        self.free[max(r0, 0) : min(r1, self.ny), max(c0, 0) : min(c1, self.nx)] = value

    def fill(self, x0: float, y0: float, x1: float, y1: float) -> None:
        self.carve(x0, y0, x1, y1, value=False)

    def space(self, x0: float, y0: float, x1: float, y1: float) -> None:
        """Carve a plan rectangle whose edges are wall centre lines."""

        def inset(v: float, limit: float, sign: int) -> float:
            edge = v in (0.0, limit)
            return v + sign * (EXTERIOR_WALL_M if edge else INTERIOR_WALL_M / 2)

        self.carve(
            inset(x0, FOOTPRINT_M[0], 1),
            inset(y0, FOOTPRINT_M[1], 1),
            inset(x1, FOOTPRINT_M[0], -1),
            inset(y1, FOOTPRINT_M[1], -1),
        )

    def door(self, x: float, y: float, horizontal_wall: bool, width: float = DOOR_WIDTH_M) -> None:
        half = width / 2
        t = INTERIOR_WALL_M
        if horizontal_wall:
            self.carve(x - half, y - t, x + half, y + t)
        else:
            self.carve(x - t, y - half, x + t, y + half)

    # ---- nav graph --------------------------------------------------------------------------
    def node(self, x: float, y: float, kind: str) -> int:
        key = (round(x, 3), round(y, 3))
        for i, existing in enumerate(self.nodes):
            if existing == key:
                return i
        self.nodes.append(key)
        self.kinds.append(kind)
        return len(self.nodes) - 1

    def link(self, a: int, b: int) -> None:
        if a != b:
            self.edges.add((min(a, b), max(a, b)))

    def corridor(self, x0: float, y0: float, x1: float, y1: float) -> int:
        """Carve a corridor and register its centre line; returns the corridor id."""
        self.space(x0, y0, x1, y1)
        if (x1 - x0) >= (y1 - y0):
            self.corridors.append(("x", (y0 + y1) / 2, []))
        else:
            self.corridors.append(("y", (x0 + x1) / 2, []))
        return len(self.corridors) - 1

    def on_corridor(self, cid: int, along: float, kind: str = "corridor") -> int:
        axis, c, members = self.corridors[cid]
        n = self.node(along, c, kind) if axis == "x" else self.node(c, along, kind)
        if n not in members:
            members.append(n)
        return n

    def junction(self, a: int, b: int) -> int:
        """The node where two perpendicular corridors' centre lines cross."""
        axis_a, ca, _ = self.corridors[a]
        _, cb, _ = self.corridors[b]
        x, y = (cb, ca) if axis_a == "x" else (ca, cb)
        n = self.node(x, y, "junction")
        for cid in (a, b):
            if n not in self.corridors[cid][2]:
                self.corridors[cid][2].append(n)
        return n

    # ---- rooms -------------------------------------------------------------------------------
    def room(
        self,
        rect: tuple[float, float, float, float],
        doors: Sequence[tuple[str, int]],
        name: str,
    ) -> None:
        """A room with doors on the given sides ('S', 'N', 'W', 'E') onto the given corridors."""
        x0, y0, x1, y1 = rect
        self.space(x0, y0, x1, y1)
        w, h = x1 - x0, y1 - y0
        entries: list[int] = []
        for side, cid in doors:
            if side in "SN":
                lo, hi = x0 + 0.9, x1 - 0.9
                pos = self.rng.uniform(lo, hi) if hi > lo else (x0 + x1) / 2
                pos = round(pos / RASTER_M) * RASTER_M
                wall_y = y0 if side == "S" else y1
                self.door(pos, wall_y, horizontal_wall=True)
                inside = self.node(pos, wall_y + (1.0 if side == "S" else -1.0), "door")
            else:
                lo, hi = y0 + 0.9, y1 - 0.9
                pos = self.rng.uniform(lo, hi) if hi > lo else (y0 + y1) / 2
                pos = round(pos / RASTER_M) * RASTER_M
                wall_x = x0 if side == "W" else x1
                self.door(wall_x, pos, horizontal_wall=False)
                inside = self.node(wall_x + (1.0 if side == "W" else -1.0), pos, "door")
            outside = self.on_corridor(cid, pos)
            self.link(outside, inside)
            entries.append(inside)
        inner: list[int] = []
        if w * h > 36.0 and min(w, h) > 4.4:
            # A big room: a loop of waypoints around its middle, where tables will stand.
            mx, my = min(1.6, w / 4), min(1.6, h / 4)
            corners = [
                (x0 + mx, y0 + my),
                (x1 - mx, y0 + my),
                (x1 - mx, y1 - my),
                (x0 + mx, y1 - my),
            ]
            inner = [self.node(cx, cy, "room") for cx, cy in corners]
            for i in range(4):
                self.link(inner[i], inner[(i + 1) % 4])
        else:
            inner = [self.node((x0 + x1) / 2, (y0 + y1) / 2, "room")]
        for e in entries:
            nearest = min(inner, key=lambda n: math.dist(self.nodes[n], self.nodes[e]))
            self.link(e, nearest)
        self.rooms.append(Room(name, rect, tuple(inner)))
        self.furnish(rect, big=len(inner) > 1)

    def rooms_along(
        self,
        span: tuple[float, float],
        band: tuple[float, float],
        doors: Sequence[tuple[str, int]],
        widths: tuple[float, float],
        prefix: str,
        *,
        axis: str = "x",
    ) -> None:
        """Partition a band into rooms of random width, each with the given doors."""
        lo, hi = span
        cuts = [lo]
        while hi - cuts[-1] > widths[1]:
            step = self.rng.uniform(*widths)
            cuts.append(round((cuts[-1] + step) / RASTER_M) * RASTER_M)
        if hi - cuts[-1] < widths[0] and len(cuts) > 1:
            cuts.pop()
        cuts.append(hi)
        for i, (a, b) in enumerate(itertools.pairwise(cuts)):
            rect = (a, band[0], b, band[1]) if axis == "x" else (band[0], a, band[1], b)
            self.room(rect, doors, f"{prefix}{i + 1:02d}")

    # ---- clutter ------------------------------------------------------------------------------
    def furnish(self, rect: tuple[float, float, float, float], big: bool) -> None:
        """Desks against walls and a few free-standing (some rotated) pieces."""
        x0, y0, x1, y1 = rect
        ix0, iy0 = x0 + INTERIOR_WALL_M / 2, y0 + INTERIOR_WALL_M / 2
        ix1, iy1 = x1 - INTERIOR_WALL_M / 2, y1 - INTERIOR_WALL_M / 2
        for _ in range(self.rng.integers(2, 5)):
            depth = self.rng.uniform(0.5, 0.8)
            length = self.rng.uniform(0.8, 2.0)
            side = self.rng.integers(4)
            if side in (0, 1):
                x = self.rng.uniform(ix0, max(ix0, ix1 - length))
                y = iy0 if side == 0 else iy1 - depth
                self.pending_blocks.append((x, y, x + length, y + depth))
            else:
                y = self.rng.uniform(iy0, max(iy0, iy1 - length))
                x = ix0 if side == 2 else ix1 - depth
                self.pending_blocks.append((x, y, x + depth, y + length))
        for _ in range(self.rng.integers(2, 6) if big else self.rng.integers(0, 3)):
            cx = self.rng.uniform(ix0 + 0.5, ix1 - 0.5)
            cy = self.rng.uniform(iy0 + 0.5, iy1 - 0.5)
            angle = self.rng.uniform(0, math.pi) if self.rng.random() < 0.5 else 0.0
            self.pending_objects.append(
                box(cx, cy, self.rng.uniform(0.6, 1.8), self.rng.uniform(0.5, 1.0), angle)
            )

    def corridor_clutter(self, cid: int, extent: tuple[float, float], half_width: float) -> None:
        """Pilasters every few metres and the odd cabinet or bench against corridor walls."""
        axis, c, _ = self.corridors[cid]
        pos = extent[0] + self.rng.uniform(1.0, 4.0)
        while pos < extent[1] - 0.5:
            for sign in (-1.0, 1.0):
                wall = c + sign * half_width
                kind = self.rng.random()
                if kind < 0.55:
                    depth, length = 0.15, 0.45  # pilaster
                elif kind < 0.75:
                    depth, length = self.rng.uniform(0.3, 0.5), self.rng.uniform(0.6, 1.6)
                else:
                    continue
                lo, hi = (wall, wall - sign * depth)
                a, b = pos, pos + length
                if axis == "x":
                    self.pending_blocks.append((a, min(lo, hi), b, max(lo, hi)))
                else:
                    self.pending_blocks.append((min(lo, hi), a, max(lo, hi), b))
            pos += self.rng.uniform(3.0, 7.0)

    # ---- shared core -------------------------------------------------------------------------
    def core(self, south_corridor: int | None) -> tuple[int, int]:
        """Lobby, elevator car and door, the same on every floor; returns (lobby, car) nodes."""
        self.fill(CORE_RECT[0] - 0.1, CORE_RECT[1] - 0.1, CORE_RECT[2] + 0.1, CORE_RECT[3] + 0.1)
        self.space(*LOBBY_RECT)
        self.space(*CAR_RECT)
        self.door(ELEVATOR_XY[0], CAR_RECT[1], horizontal_wall=True, width=CAR_DOOR_WIDTH_M)
        # The closed doors of the second shaft: a shallow recess in the lobby wall.
        self.carve(26.6, CAR_RECT[1] - 0.2, 27.8, CAR_RECT[1] + 0.05)
        lobby = self.node(*LOBBY_XY, "lobby")
        car = self.node(*ELEVATOR_XY, "elevator")
        self.link(lobby, car)
        if south_corridor is not None:
            _axis, c, _ = self.corridors[south_corridor]
            # Open the whole lobby side onto the corridor.
            self.carve(LOBBY_RECT[0] + 0.1, c, LOBBY_RECT[2] - 0.1, LOBBY_RECT[1] + 0.2)
            self.link(lobby, self.on_corridor(south_corridor, LOBBY_XY[0]))
        return lobby, car

    # ---- finish -------------------------------------------------------------------------------
    def finish(self, name: str, kind: str, elevation: float, lobby: int, car: int) -> FloorPlan:
        for axis, _, members in self.corridors:
            key = 0 if axis == "x" else 1
            ordered = sorted(members, key=lambda n: self.nodes[n][key])
            for a, b in itertools.pairwise(ordered):
                self.link(a, b)
        nodes = np.array(self.nodes, dtype=np.float64)
        edges = np.array(sorted(self.edges), dtype=np.int64).reshape(-1, 2)
        keepout = self._keepout(nodes, edges)
        structure = self.free.copy()
        for x0, y0, x1, y1 in self.pending_blocks:
            c0, c1 = sorted((_cells(x0), _cells(x1)))
            r0, r1 = sorted((_cells(y0), _cells(y1)))
            r0, c0 = max(r0, 0), max(c0, 0)
            if r1 <= r0 or c1 <= c0 or keepout[r0:r1, c0:c1].any():
                continue
            structure[r0:r1, c0:c1] = False
        free_for_objects = ndimage.binary_erosion(structure, iterations=2) & ~keepout
        occupied_by_objects = np.zeros_like(structure)
        for poly in self.pending_objects:
            mask, window = _polygon_mask(poly, structure.shape)
            if mask is None:
                continue
            region = free_for_objects[window]
            if not region[mask].all() or occupied_by_objects[window][mask].any():
                continue
            occupied_by_objects[window] |= ndimage.binary_dilation(mask, iterations=3)
            self.polygons.append(poly)
            structure[window] &= ~mask
        walls = np.concatenate(
            [raster_boundary(self.free & structure)] + [_polygon_segments(p) for p in self.polygons]
        )
        nav, dropped = _checked_nav(nodes, edges, self.kinds, structure)
        if dropped:
            log.warning("nav edges without clearance dropped", floor=self.index, edges=dropped)
        walls.setflags(write=False)
        structure.setflags(write=False)
        explore = tuple(dict.fromkeys(self.explore))
        return FloorPlan(
            index=self.index,
            name=name,
            kind=kind,
            elevation_m=elevation,
            walls_m=walls,
            nav=nav,
            rooms=tuple(self.rooms),
            lobby_node=lobby,
            elevator_node=car,
            explore_nodes=explore,
            free_raster=structure,
        )

    def _keepout(self, nodes: FloatArray, edges: IntArray) -> BoolArray:
        mask = np.zeros((self.ny, self.nx), dtype=bool)
        if len(edges) == 0:
            return mask
        segs = np.hstack([nodes[edges[:, 0]], nodes[edges[:, 1]]])
        pts = segment_points(segs, RASTER_M)
        cols = np.clip((pts[:, 0] / RASTER_M).astype(np.int64), 0, self.nx - 1)
        rows = np.clip((pts[:, 1] / RASTER_M).astype(np.int64), 0, self.ny - 1)
        mask[rows, cols] = True
        dist = ndimage.distance_transform_edt(~mask) * RASTER_M
        out: BoolArray = dist < NAV_KEEPOUT_M
        return out


def box(cx: float, cy: float, length: float, width: float, angle: float) -> FloatArray:
    """Corners of a rotated rectangle, counter-clockwise."""
    c, s = math.cos(angle), math.sin(angle)
    local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * [length / 2, width / 2]
    rot = np.array([[c, -s], [s, c]])
    out: FloatArray = local @ rot.T + [cx, cy]
    return out


def octagon(cx: float, cy: float, radius: float) -> FloatArray:
    a = np.arange(8) * (math.pi / 4) + math.pi / 8
    out: FloatArray = np.column_stack([cx + radius * np.cos(a), cy + radius * np.sin(a)])
    return out


def _polygon_segments(poly: FloatArray) -> FloatArray:
    out: FloatArray = np.hstack([poly, np.roll(poly, -1, axis=0)])
    return out


def _polygon_mask(
    poly: FloatArray, shape: tuple[int, int]
) -> tuple[BoolArray | None, tuple[slice, slice]]:
    """Cells whose centres lie inside a convex counter-clockwise polygon, in its bounding box."""
    c0 = max(int(np.floor(poly[:, 0].min() / RASTER_M)), 0)
    c1 = min(int(np.ceil(poly[:, 0].max() / RASTER_M)), shape[1])
    r0 = max(int(np.floor(poly[:, 1].min() / RASTER_M)), 0)
    r1 = min(int(np.ceil(poly[:, 1].max() / RASTER_M)), shape[0])
    window = (slice(r0, r1), slice(c0, c1))
    if r1 <= r0 or c1 <= c0:
        return None, window
    ys = (np.arange(r0, r1) + 0.5) * RASTER_M
    xs = (np.arange(c0, c1) + 0.5) * RASTER_M
    gx, gy = np.meshgrid(xs, ys)
    inside = np.ones(gx.shape, dtype=bool)
    for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        inside &= (bx - ax) * (gy - ay) - (by - ay) * (gx - ax) >= 0
    return inside, window


def raster_boundary(free: BoolArray) -> FloatArray:
    """Wall segments between free and solid cells, merged into maximal straight runs."""
    padded = np.pad(free, 1, constant_values=False)
    segments: list[tuple[float, float, float, float]] = []
    horizontal = padded[1:, 1:-1] != padded[:-1, 1:-1]  # (ny + 1, nx): edge at y = row
    for row in np.nonzero(horizontal.any(axis=1))[0]:
        for a, b in _runs(horizontal[row]):
            y = row * RASTER_M
            segments.append((a * RASTER_M, y, b * RASTER_M, y))
    vertical = padded[1:-1, 1:] != padded[1:-1, :-1]  # (ny, nx + 1): edge at x = col
    for col in np.nonzero(vertical.any(axis=0))[0]:
        for a, b in _runs(vertical[:, col]):
            x = col * RASTER_M
            segments.append((x, a * RASTER_M, x, b * RASTER_M))
    return np.array(segments, dtype=np.float64).reshape(-1, 4)


def _runs(line: BoolArray) -> Iterable[tuple[int, int]]:
    d = np.diff(np.concatenate(([0], line.astype(np.int8), [0])))
    return zip(np.nonzero(d == 1)[0].tolist(), np.nonzero(d == -1)[0].tolist(), strict=True)


def _checked_nav(
    nodes: FloatArray, edges: IntArray, kinds: Sequence[str], structure: BoolArray
) -> tuple[NavGraph, int]:
    """Drop edges that pass closer to a wall than the robot's clearance."""
    clearance = ndimage.distance_transform_edt(structure) * RASTER_M
    keep = np.ones(len(edges), dtype=bool)
    for i, (a, b) in enumerate(edges):
        pts = segment_points(np.hstack([nodes[a], nodes[b]])[None, :], 0.05)
        cols = np.clip((pts[:, 0] / RASTER_M).astype(np.int64), 0, structure.shape[1] - 1)
        rows = np.clip((pts[:, 1] / RASTER_M).astype(np.int64), 0, structure.shape[0] - 1)
        keep[i] = bool(clearance[rows, cols].min() >= NAV_CLEARANCE_M)
    nodes.setflags(write=False)
    kept = edges[keep]
    kept.setflags(write=False)
    return NavGraph(nodes, kept, tuple(kinds)), int((~keep).sum())


# ---- floor layouts ----------------------------------------------------------------------------

SOUTH_CORRIDOR = (0.0, 6.6, 60.0, 8.8)


def _ground_floor(b: _Builder) -> tuple[int, int]:
    """An open hall with a grid of pillars, a reception desk, seating, and service rooms."""
    b.space(0.0, 0.0, 60.0, 24.0)
    # Service block along the north wall west of the core: toilets, a porter's room.
    b.fill(7.9, 19.3, 22.1, 24.0)
    lobby, car = b.core(None)

    def line(y: float) -> int:
        b.corridors.append(("x", y, []))  # a drive line across the hall, nothing carved
        return len(b.corridors) - 1

    row3, row9, row15w, row15e, row21w, row21e = (line(y) for y in (3, 9, 15, 15, 21.5, 21.5))
    for x in np.arange(3.75, 60.0, 7.5).tolist():
        low, mid = b.on_corridor(row3, x, "hall"), b.on_corridor(row9, x, "hall")
        b.link(low, mid)
        if not 25.0 < x < 35.0:
            upper = b.on_corridor(row15w if x < 25.0 else row15e, x, "hall")
            b.link(mid, upper)
            if x < 7.5 or x > 22.5:
                b.link(upper, b.on_corridor(row21w if x < 7.5 else row21e, x, "hall"))
        elif x > 22.5:
            b.on_corridor(row21e, x, "hall")
    for i, (a, c) in enumerate(((8.0, 12.5), (12.5, 17.0), (17.0, 22.0))):
        b.space(a, 19.4, c, 24.0)
        x = round(b.rng.uniform(a + 0.9, c - 0.9) / RASTER_M) * RASTER_M
        b.door(x, 19.4, horizontal_wall=True)
        inside = b.node(x, 20.5, "door")
        b.link(b.on_corridor(row15w, x, "hall"), inside)
        centre = b.node((a + c) / 2, 21.9, "room")
        b.link(inside, centre)
        b.rooms.append(Room(f"G-service{i + 1}", (a, 19.4, c, 24.0), (centre,)))
    b.link(lobby, b.on_corridor(row9, 26.25, "hall"))
    b.link(lobby, b.on_corridor(row9, 33.75, "hall"))
    # Pillars on a 7.5 m grid (octagonal, as in old engineering buildings); those in the way
    # of a drive line are left out by the keep-out check.
    for x in np.arange(7.5, 60.0, 7.5).tolist():
        for y in (6.0, 12.0, 18.0):
            b.pending_objects.append(octagon(x, y, 0.3))
    # Free-standing furniture: reception desk, benches, display stands, some rotated.
    b.pending_objects.append(box(21.0, 11.5, 3.0, 0.8, 0.0))
    for _ in range(16):
        b.pending_objects.append(
            box(
                b.rng.uniform(2.0, 58.0),
                b.rng.uniform(1.0, 23.0),
                b.rng.uniform(0.8, 2.2),
                b.rng.uniform(0.5, 0.9),
                b.rng.uniform(0.0, math.pi),
            )
        )
    b.explore.extend(
        b.on_corridor(r, x, "hall")
        for r, x in ((row3, 3.75), (row3, 56.25), (row21w, 3.75), (row21e, 56.25), (row3, 18.75))
    )
    return lobby, car


def _offices_and_labs(b: _Builder) -> tuple[int, int]:
    """One long corridor: offices to the south, deep labs (two doors each) to the north."""
    south = b.corridor(*SOUTH_CORRIDOR)
    lobby, car = b.core(south)
    b.rooms_along((0.0, 60.0), (0.0, 6.6), [("N", south)], (3.6, 6.0), f"{b.index}S")
    b.rooms_along((0.0, 26.0), (8.8, 24.0), [("S", south), ("S", south)], (7.0, 12.0), "W")
    b.rooms_along((34.0, 60.0), (8.8, 24.0), [("S", south), ("S", south)], (7.0, 12.0), "E")
    b.corridor_clutter(south, (0.5, 59.5), 1.0)
    b.explore.extend([b.on_corridor(south, 1.5), b.on_corridor(south, 58.5)])
    return lobby, car


def _ring(b: _Builder) -> tuple[int, int]:
    """Two parallel corridors joined at both ends: a loop around the core."""
    south = b.corridor(*SOUTH_CORRIDOR)
    north = b.corridor(3.0, 18.4, 57.0, 20.6)
    west = b.corridor(3.0, 8.8, 5.2, 18.4)
    east = b.corridor(54.8, 8.8, 57.0, 18.4)
    for cross in (west, east):
        b.carve(b.corridors[cross][1] - 1.0, 6.7, b.corridors[cross][1] + 1.0, 9.0)
        b.carve(b.corridors[cross][1] - 1.0, 18.2, b.corridors[cross][1] + 1.0, 18.6)
        b.junction(south, cross)
        b.junction(north, cross)
    lobby, car = b.core(south)
    b.rooms_along((0.0, 60.0), (0.0, 6.6), [("N", south)], (3.5, 5.5), f"{b.index}S")
    b.rooms_along((3.0, 57.0), (20.6, 24.0), [("S", north)], (3.2, 4.6), f"{b.index}N")
    for span, tag in (((5.2, 26.0), "W"), ((34.0, 54.8), "E")):
        if b.rng.random() < 0.5:
            # Through-rooms with a door on each corridor: more loops.
            b.rooms_along(span, (8.8, 18.4), [("S", south), ("N", north)], (5.0, 8.0), tag)
        else:
            b.rooms_along(span, (8.8, 13.6), [("S", south)], (4.0, 6.5), tag + "s")
            b.rooms_along(span, (13.6, 18.4), [("N", north)], (4.0, 6.5), tag + "n")
    for cid, extent in ((south, (0.5, 59.5)), (north, (3.5, 56.5))):
        b.corridor_clutter(cid, extent, 1.0)
    b.explore.extend([b.junction(north, west), b.junction(north, east)])
    return lobby, car


def _comb(b: _Builder) -> tuple[int, int]:
    """A main corridor with branches to the north; two of them joined into a loop."""
    south = b.corridor(*SOUTH_CORRIDOR)
    xa = round(b.rng.uniform(6.0, 9.0), 1)
    xb = round(b.rng.uniform(16.0, 19.0), 1)
    xc = round(b.rng.uniform(43.0, 47.0), 1)
    west_a = b.corridor(xa, 8.8, xa + 2.0, 21.6)
    west_b = b.corridor(xb, 8.8, xb + 2.0, 21.6)
    link = b.corridor(xa, 21.6, xb + 2.0, 23.7)
    east = b.corridor(xc, 8.8, xc + 2.0, 24.0)
    for branch in (west_a, west_b, east):
        c = b.corridors[branch][1]
        b.carve(c - 0.9, 8.0, c + 0.9, 9.2)
        b.junction(south, branch)
    for branch in (west_a, west_b):
        c = b.corridors[branch][1]
        b.carve(c - 0.9, 21.0, c + 0.9, 22.2)
        b.junction(link, branch)
    lobby, car = b.core(south)
    b.rooms_along((0.0, 60.0), (0.0, 6.6), [("N", south)], (3.8, 6.5), f"{b.index}S")
    b.rooms_along((8.8, 21.6), (0.0, xa), [("E", west_a)], (3.5, 5.0), "A", axis="y")
    b.rooms_along(
        (8.8, 21.6), (xa + 2.0, xb), [("W", west_a), ("E", west_b)], (4.0, 6.5), "B", axis="y"
    )
    b.rooms_along((8.8, 21.6), (xb + 2.0, 26.0), [("W", west_b)], (4.0, 6.0), "C", axis="y")
    b.rooms_along((8.8, 24.0), (34.0, xc), [("E", east)], (4.0, 6.5), "D", axis="y")
    b.rooms_along((8.8, 24.0), (xc + 2.0, 60.0), [("W", east)], (4.0, 6.5), "F", axis="y")
    b.corridor_clutter(south, (0.5, 59.5), 1.0)
    for branch in (west_a, west_b, east):
        b.corridor_clutter(branch, (9.5, 20.5), 1.0)
    b.explore.extend([b.on_corridor(east, 22.6), b.on_corridor(south, 1.5)])
    b.explore.append(b.on_corridor(south, 58.5))
    return lobby, car


def _open_office(b: _Builder) -> tuple[int, int]:
    """Offices to the south; to the north an open-plan office with desk islands and a loop."""
    south = b.corridor(*SOUTH_CORRIDOR)
    lobby, car = b.core(south)
    b.rooms_along((0.0, 60.0), (0.0, 6.6), [("N", south)], (3.0, 5.0), f"{b.index}S")
    b.rooms_along((34.0, 60.0), (8.8, 24.0), [("S", south)], (6.0, 9.0), "E")
    # The open-plan area west of the core: one big space, desk islands, two openings.
    b.space(0.0, 8.8, 26.0, 24.0)
    nodes = []
    for x in (4.0, 12.5, 21.5):
        b.carve(x - 1.0, 8.4, x + 1.0, 9.2)
        outside = b.on_corridor(south, x)
        inside = b.node(x, 10.6, "hall")
        b.link(outside, inside)
        nodes.append(inside)
    for a, c in itertools.pairwise(nodes):
        b.link(a, c)
    top = [b.node(x, 20.5, "hall") for x in (4.0, 12.5, 21.5)]
    for a, c in itertools.pairwise(top):
        b.link(a, c)
    for a, c in zip(nodes, top, strict=True):
        b.link(a, c)
    for cx in (8.25, 17.0):
        for cy in (13.0, 17.5):
            angle = b.rng.uniform(-0.4, 0.4)
            b.pending_objects.append(box(cx, cy, 4.0, 1.6, angle))
    b.corridor_clutter(south, (0.5, 59.5), 1.0)
    b.explore.extend([top[0], top[2], b.on_corridor(south, 58.5)])
    return lobby, car


LAYOUTS = {
    "offices-labs": _offices_and_labs,
    "ring": _ring,
    "comb": _comb,
    "open-office": _open_office,
}


def storey_elevations(rng: np.random.Generator, floors: int) -> tuple[list[float], float | None]:
    """Floor heights above floor 0: a tall ground storey and a gap for an unvisited mezzanine."""
    mezzanine_below = 3 if floors >= 4 else (2 if floors == 3 else None)
    elevations = [0.0]
    mezzanine: float | None = None
    for upper in range(1, floors):
        storey = rng.uniform(5.0, 5.6) if upper == 1 else rng.uniform(3.4, 3.9)
        if upper == mezzanine_below:
            mezzanine = elevations[-1] + storey
            storey += rng.uniform(3.0, 3.5)
        elevations.append(round(elevations[-1] + storey, 3))
    return elevations, (round(mezzanine, 3) if mezzanine is not None else None)


@functools.lru_cache(maxsize=16)
def make_building(seed: int = 0, floors: int = 6) -> Building:
    """The building of a seed: ``floors`` storeys, floor 0 the open ground floor.

    Deterministic for a given (seed, floors): an evaluator rebuilds the truth plans from the
    metadata of a recording.
    """
    if not 1 <= floors <= 40:
        raise ConfigError(f"floors must be between 1 and 40, got {floors}")
    rng = np.random.default_rng([seed, floors, 0xB1D])
    elevations, mezzanine = storey_elevations(rng, floors)
    kinds = list(LAYOUTS)
    order = list(rng.permutation(kinds))
    plans = []
    for index in range(floors):
        b = _Builder(np.random.default_rng([seed, floors, index]), index)
        if index == 0:
            kind = "ground"
            lobby, car = _ground_floor(b)
        else:
            kind = str(order[(index - 1) % len(order)])
            lobby, car = LAYOUTS[kind](b)
        name = f"Floor {index + 1}" + (" (ground)" if index == 0 else "")
        plans.append(b.finish(name, kind, elevations[index], lobby, car))
    log.debug("building made", seed=seed, floors=floors)
    return Building(
        seed=seed,
        floors=tuple(plans),
        elevator_xy=ELEVATOR_XY,
        lobby_xy=LOBBY_XY,
        footprint_m=FOOTPRINT_M,
        mezzanine_m=mezzanine,
    )
