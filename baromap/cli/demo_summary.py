"""What the demo tells the user at the end: floors, transitions, files, and how to look.

Floors come from build-maps (post-run, ordered by height, with their maps); transitions from
what the daemon published live (its recorded ``/floor/event``, corrections applied: what
``baromap watch`` printed). The live detector names floors from the start floor in storeys;
each post-run floor is given the live name of the floor at its height, so the two accounts can
be read side by side. The simulator's truth is shown beside them: it is a demo on simulated
hardware, and the user should see whether the product got it right.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from baromap.evaluation.map_files import MapFileScore
from baromap.messages import NS_PER_S, FloorEvent

#: A post-run floor takes a live floor's name when their heights agree this well (m).
SAME_FLOOR_M = 1.0


@dataclass(frozen=True, slots=True)
class TrueRun:
    """The simulator's account of the mission, for comparison."""

    elevations_m: tuple[float, ...]  # of the floors visited, lowest first, relative to it
    rides: tuple[tuple[int, int], ...]  # (from floor, to floor), building floor numbers
    maps: tuple[MapFileScore, ...] = ()  # the map files against the true plans


def live_floor_heights(events: Sequence[FloorEvent]) -> dict[str, float]:
    """Each live floor name and its height above the start floor."""
    heights: dict[str, float] = {}
    for e in events:
        heights.setdefault(e.to_name, e.height_m)
        heights.setdefault(e.from_name, e.height_m - e.delta_m)
    return heights


def name_floors(
    floors: Sequence[dict[str, Any]], events: Sequence[FloorEvent], start_floor: int | None
) -> dict[int, str]:
    """Post-run floor index -> name: building.yaml's own, else the live name at that height."""
    names = {int(f["index"]): str(f["name"]) for f in floors if f.get("name") is not None}
    elevation = {int(f["index"]): float(f["elevation_m"]) for f in floors}
    if start_floor is None or start_floor not in elevation:
        return names
    offset = elevation[start_floor]
    for name, height in live_floor_heights(events).items():
        index = min(elevation, key=lambda k: abs(elevation[k] - offset - height))
        if abs(elevation[index] - offset - height) < SAME_FLOOR_M:
            names.setdefault(index, name)
    return names


def _clock(t_ns: int, t0_ns: int) -> str:
    seconds = max(0.0, (t_ns - t0_ns) / NS_PER_S)
    return f"{int(seconds // 60):02d}:{seconds % 60:04.1f}"


def summary_lines(
    *,
    out: Path,
    recording: Path,
    building: dict[str, Any],
    events: Sequence[FloorEvent],
    t0_ns: int,
    start_floor: int | None,
    post_run_transitions: int,
    truth: TrueRun | None,
    files: Sequence[Path],
) -> list[str]:
    floors = list(building.get("floors", []))
    names = name_floors(floors, events, start_floor)

    def rel(path: Path) -> str:
        try:
            return str(path.relative_to(Path.cwd()))
        except ValueError:
            return str(path)

    lines = [f"floors: {len(floors)}, by height (build-maps; names as the live detector gave them)"]
    for f in floors:
        index = int(f["index"])
        visits = int(f.get("visits", 0))
        lines.append(
            f"  floor {index}  {float(f['elevation_m']):+6.2f} m  "
            f"name {names.get(index, '?'):>3s}  {visits} visit{'s' if visits != 1 else ''}  "
            f"map {rel(out / str(f['image'])) if f.get('image') else '(none)'}"
        )
    lines.append(
        f"transitions: {len(events)} decided live (what baromap watch printed), "
        f"{post_run_transitions} post-run; times from the start of the recording"
    )
    for e in events:
        lines.append(
            f"  {_clock(e.t_start_ns, t0_ns)}-{_clock(e.t_end_ns, t0_ns)}  floor {e.from_name:>3s}"
            f" -> {e.to_name:<3s} {e.delta_m:+6.2f} m  decided {_clock(e.t_ns, t0_ns)}"
            + ("  (correction)" if e.replaces is not None else "")
        )
    if truth is not None:
        heights = ", ".join(f"{z:+.2f}" for z in truth.elevations_m)
        rides = ", ".join(f"{a}->{b}" for a, b in truth.rides)
        lines.append(
            f"the simulator's truth: {len(truth.elevations_m)} floors at {heights} m; "
            f"{len(truth.rides)} rides ({rides}, building floor numbers)"
        )
        for m in truth.maps:
            lines.append(
                f"  map of floor {m.floor} against the true plan of floor {m.true_floor}: "
                f"{100 * m.occupied_precision:.0f} % of its walls within 10 cm, "
                f"{100 * m.free_precision:.0f} % of its free space free; at the lobby "
                f"{m.lobby_error_m:.2f} m / {m.lobby_error_deg:.1f} deg off the other floors"
            )
    lines.append("files:")
    lines.append(f"  recording        {rel(recording)}")
    described = {
        "building.yaml": "building model (floors, heights, maps)",
        "maps.mcap": "maps and corrected path for Foxglove",
        "trajectory.tum": "corrected trajectory (TUM)",
        "pressure.png": "pressure, smoothed, transitions",
        "building.png": "floors stacked at their heights",
    }
    for path in files:
        if path.name in described:
            lines.append(f"  {path.name:16s} {rel(path)}: {described[path.name]}")
    maps = sorted(p for p in files if p.name.startswith("floor_") and p.suffix == ".pgm")
    if maps:
        lines.append(
            f"  floor maps       {rel(maps[0].parent)}/floor_<k>.pgm + .yaml "
            "(ROS map_server) and .png"
        )
    lines.append("open it in Foxglove (app.foxglove.dev or the desktop app):")
    lines.append(
        f"  Open local file(s), choose {rel(recording)} and {rel(out / 'maps.mcap')} together;"
    )
    lines.append(
        "  a 3D panel with display frame `map` shows the scans on the floor maps, a Plot panel"
    )
    lines.append("  of /baro.pressure_pa the rides, a Raw Messages panel /floor/event.")
    return lines
