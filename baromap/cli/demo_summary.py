"""What the demo tells the user at the end: floors, transitions, files, and how to look.

Floors come from build-maps (post-run, ordered by height, with their maps and names:
``building.yaml`` names them by order in height and keeps the live detector's name beside
each); transitions from what the daemon published live (its recorded ``/floor/event``,
corrections applied: what ``baromap watch`` printed). The simulator's truth is shown beside
them: it is a demo on simulated hardware, and the user should see whether the product got it
right.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from baromap.building import Building
from baromap.evaluation.map_files import MapFileScore
from baromap.messages import NS_PER_S, FloorEvent


@dataclass(frozen=True, slots=True)
class TrueRun:
    """The simulator's account of the mission, for comparison."""

    elevations_m: tuple[float, ...]  # of the floors visited, lowest first, relative to it
    rides: tuple[tuple[int, int], ...]  # (from floor, to floor), building floor numbers
    maps: tuple[MapFileScore, ...] = ()  # the map files against the true plans


def _clock(t_ns: int, t0_ns: int) -> str:
    seconds = max(0.0, (t_ns - t0_ns) / NS_PER_S)
    return f"{int(seconds // 60):02d}:{seconds % 60:04.1f}"


def summary_lines(
    *,
    out: Path,
    recording: Path,
    building: Building,
    events: Sequence[FloorEvent],
    t0_ns: int,
    post_run_transitions: int,
    truth: TrueRun | None,
    files: Sequence[Path],
) -> list[str]:
    floors = building.floors

    def rel(path: Path) -> str:
        try:
            return str(path.relative_to(Path.cwd()))
        except ValueError:
            return str(path)

    lines = [
        f"floors: {len(floors)}, by height (build-maps; named in order of height, and as the "
        "live detector named them)"
    ]
    for k, f in enumerate(floors):
        name = f.label(k)
        live = f.live_name or name
        visits = f.visits or 0
        lines.append(
            f"  floor {f.index}  {f.elevation_m:+6.2f} m  name {name:>3s}  live name "
            f"{live:>3s}  {visits} visit{'s' if visits != 1 else ''}  "
            f"map {rel(out / f.image) if f.image else '(none)'}"
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
