"""``build-maps``: a recorded run in, one aligned map per floor and a building model out.

Order of work: load the run, cut it into floors from the barometer, run floor-aware graph
SLAM over the whole run (one frame for all floors), rasterise each floor's keyframes into an
occupancy grid, then write the files docs/design.md promises. Everything in one place here so the
CLI, the demo, tests and the benchmark produce identical outputs.
"""

from __future__ import annotations

import math
import shutil
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import structlog

from baromap.arrays import FloatArray
from baromap.building import (
    Building,
    BuildingFloor,
    BuildingRide,
    LoopClosures,
    UntiedStretch,
    write_building,
)
from baromap.errors import ConfigError
from baromap.floors.names import names_by_height
from baromap.mapping import export, figures
from baromap.mapping.foxglove_maps import FloorMap, MapsRun, write_maps_mcap
from baromap.mapping.keyframes import motion_spaced
from baromap.mapping.live_names import live_floor_names, recorded_floor_events
from baromap.mapping.occupancy import OccupancyGrid, build_grid
from baromap.mapping.restarts import check_runs, run_slam_best_of
from baromap.mapping.run_data import RunData, load_scans, load_series, run_data
from baromap.mapping.scans import ScanBlock
from baromap.mapping.segmentation import FloorInfo, Segmentation, segment_run
from baromap.mapping.slam import BETWEEN_FLOORS, SlamConfig, SlamResult
from baromap.recording.run_parts import Recording, run_parts

log = structlog.get_logger(__name__)


@dataclass(slots=True)
class BuildResult:
    run: RunData
    segmentation: Segmentation
    slam: SlamResult
    grids: dict[int, OccupancyGrid]
    files: list[Path] = field(default_factory=list)
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def cross_floor_closures(self) -> int:
        """Loop closures between keyframes the barometer put on different floors (none by
        construction: only the elevator car is matched across floors, see car_edges)."""
        kf_floor = self.segmentation.scan_floor[self.slam.keyframes]
        return sum(1 for i, j in self.slam.loop_edges if kf_floor[i] != kf_floor[j])


def _progress_bar(total: int, enabled: bool) -> tuple[Callable[[int], None] | None, Any]:
    if not enabled or not sys.stderr.isatty():
        return None, None
    from tqdm import tqdm

    bar = tqdm(total=total, unit="scan", desc="SLAM", leave=False)
    state = {"last": 0}

    def update(scan_index: int) -> None:
        bar.update(scan_index + 1 - state["last"])
        state["last"] = scan_index + 1

    return update, bar


def map_floors(
    run: RunData,
    segmentation: Segmentation,
    *,
    config: SlamConfig | None = None,
    resolution: float = 0.05,
    progress: bool = False,
    runs: int = 1,
) -> tuple[SlamResult, dict[int, OccupancyGrid]]:
    """SLAM over the run (the best agreeing of ``runs``: :mod:`baromap.mapping.restarts`)
    and one grid per floor, in one frame."""
    slam = _slam(run, segmentation, config, progress, runs)
    grids: dict[int, OccupancyGrid] = {}
    for info in segmentation.floors:
        job = _grid_job(run, segmentation, slam, info.index, resolution=resolution, config=config)
        if job is not None:
            grids[info.index] = floor_grid(*job)
    return slam, grids


def _slam(
    run: RunData,
    segmentation: Segmentation,
    config: SlamConfig | None,
    progress: bool,
    runs: int,
) -> SlamResult:
    update, bar = _progress_bar(len(run.scans), progress)
    try:
        return run_slam_best_of(
            run.scans,
            run.odom,
            segmentation.scan_floor,
            segmentation.scan_visit,
            runs=runs,
            config=config,
            progress=update,
            travel=run.travel(),
            blind=run.blind,
            breaks=run.breaks,
        )
    finally:
        if bar is not None:
            bar.close()


def floor_grid(
    scans: ScanBlock, poses: FloatArray, resolution: float, max_range_m: float
) -> OccupancyGrid:
    """The grid of one floor from its scans (all of them) at their corrected poses."""
    return build_grid(
        scans, np.arange(len(scans)), poses, resolution=resolution, max_range_m=max_range_m
    )


def _grid_job(
    run: RunData,
    segmentation: Segmentation,
    slam: SlamResult,
    floor: int,
    *,
    resolution: float,
    config: SlamConfig | None,
) -> tuple[ScanBlock, FloatArray, float, float] | None:
    """What :func:`floor_grid` needs for one floor, small enough to hand to another process:
    only that floor's grid scans."""
    # a scan the odometry said nothing about has a pose drawn across the gap (see
    # run_slam's ``blind``): it is left out of the map
    chosen = floor_scans(slam, (segmentation.scan_floor == floor) & ~run.blind)
    if len(chosen) == 0:
        return None
    max_range = (config or SlamConfig()).max_range_m
    return run.scans.subset(chosen), slam.scan_poses[chosen], resolution, max_range


#: Scans inserted into a grid are at least this far apart (in the corrected trajectory).
GRID_SCAN_M = 0.1
GRID_SCAN_RAD = math.radians(5.0)


def floor_scans(slam: SlamResult, on_floor: npt.NDArray[np.bool_]) -> npt.NDArray[np.int64]:
    """The scans of a floor that go into its grid (:func:`grid_scans`), less those between
    keyframes that agreed with too little of the floor's finished map to be placed by it: a
    stamp that paired one with the wrong odometry, the inside of the elevator car. Its pose is
    odometry's guess, and what it saw is not the floor where that guess puts it."""
    return grid_scans(slam.scan_poses, on_floor & slam.scan_registered)


def grid_scans(
    poses: FloatArray,
    on_floor: npt.NDArray[np.bool_],
    min_m: float = GRID_SCAN_M,
    min_rad: float = GRID_SCAN_RAD,
) -> npt.NDArray[np.int64]:
    """Scans of a floor that go into its grid: about three per keyframe spacing.

    Keyframes alone leave cells far from the path crossed by one or two beams, too little
    evidence to call them free; every scan would repeat the same evidence ten times over a
    standing robot. Every scan has a corrected pose (matched against the finished map), so a
    denser, motion-spaced subset is used.
    """
    group = np.where(on_floor, 0, -1)
    return motion_spaced(poses, group, min_m, min_rad, last_of_group=False)


def build_maps(
    recording: Recording,
    out_dir: str | Path,
    *,
    resolution: float = 0.05,
    method: str = "online",
    progress: bool = False,
    config: SlamConfig | None = None,
    runs: int = 1,
    across_runs: bool = False,
) -> BuildResult:
    """Run the whole pipeline and write every output file into ``out_dir``; the SLAM keeps
    the best agreeing of ``runs`` runs (:mod:`baromap.mapping.restarts`). ``recording``: a
    run's file, or all of its files (a run baromapd rotated), or a directory of them; with
    ``across_runs``, the runs of one exploration (:func:`run_parts`)."""
    if not 0.005 <= resolution <= 1.0:
        raise ConfigError(f"resolution {resolution} m is outside 0.005..1")
    check_runs(runs)
    out = Path(out_dir)
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a file of that name, no permission
        raise ConfigError(f"cannot use {out} as the output directory: {exc}") from exc
    try:
        return _build(
            run_parts(recording, across_runs=across_runs),
            out,
            resolution=resolution,
            method=method,
            progress=progress,
            config=config,
            runs=runs,
        )
    except BaseException:
        # a failed build leaves nothing behind where there was nothing before
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise


def _build(
    parts: tuple[Path, ...],
    out: Path,
    *,
    resolution: float,
    method: str,
    progress: bool,
    config: SlamConfig | None,
    runs: int,
) -> BuildResult:
    timings: dict[str, float] = {}
    with _Painter() as painter:
        t0 = time.perf_counter()
        # the series in the painter while this process reads the scans; then matplotlib
        series = painter.submit(load_series, parts)
        painter.warm_up()
        block, metadata = load_scans(parts)
        run = run_data(block, metadata, series.result())
        timings["load"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        segmentation = segment_run(
            run.scans.t_ns,
            run.pressure_t_ns,
            run.pressure_pa,
            run.temperature_c,
            method=method,
            reference=(run.reference_t_ns, run.reference_pa) if len(run.reference_t_ns) else None,
            odometry=(run.odometry_t_ns, run.odometry_poses),
            scan_odom=run.odom,
        )
        timings["segmentation"] = time.perf_counter() - t0
        # the pressure figure needs nothing the SLAM makes: drawn while it runs
        pressure_png = out / "pressure.png"
        painter.submit(figures.pressure_figure, pressure_png, **_pressure_args(run, segmentation))
        t0 = time.perf_counter()
        slam = _slam(run, segmentation, config, progress, runs)
        timings["slam"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        result = BuildResult(run, segmentation, slam, {}, timings_s=timings)
        result.files = write_outputs(
            result, parts, out, painter, resolution=resolution, config=config
        )
        result.files.append(pressure_png)
        painter.wait()
        timings["grids_and_outputs"] = time.perf_counter() - t0
    log.info(
        "maps built",
        floors=len(result.grids),
        keyframes=len(slam.keyframes),
        loops=len(slam.loop_edges),
        car_closures=len(slam.car_edges),
        **{f"t_{k}": round(v, 2) for k, v in timings.items()},
    )
    return result


class _Painter:
    """A second process for reading the run's series, the figures and half the floors'
    grids, so a build uses both cores of a small robot computer: the series are read beside
    the scans, matplotlib and ray casting run beside the SLAM and the rest of the outputs.
    Forked at the start, before the recording is read. A process that runs other threads
    (a daemon, a live publisher) is not forked, since a fork copies their locks in whatever
    state they are: then, and where no process can be started, it paints in this one."""

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None
        self._jobs: list[Future[Any]] = []

    def __enter__(self) -> _Painter:
        if threading.active_count() > 1:
            return self
        try:
            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=get_context("fork"))
        except (OSError, RuntimeError, ValueError) as exc:  # no processes: paint in this one
            log.warning("outputs drawn in one process", error=str(exc))
            self._pool = None
        return self

    def submit(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Future[Any]:
        if self._pool is None:
            done: Future[Any] = Future()
            done.set_result(fn(*args, **kwargs))
            return done
        job = self._pool.submit(fn, *args, **kwargs)
        self._jobs.append(job)
        return job

    def warm_up(self) -> None:
        """Load matplotlib in the painter ahead of its first figure; painting in this
        process, there is nothing to do ahead."""
        if self._pool is not None:
            self._jobs.append(self._pool.submit(figures.warm_up))

    def wait(self) -> None:
        """Every job done; the first failure raised here."""
        for job in self._jobs:
            job.result()
        self._jobs.clear()

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)


def scan_elevations(result: BuildResult) -> FloatArray:
    """Elevation of each scan's floor; transitions interpolate between their two floors."""
    seg = result.segmentation
    elevation = {f.index: f.elevation_m for f in seg.floors}
    z = np.array([elevation.get(int(f), np.nan) for f in seg.scan_floor])
    known = np.isfinite(z)
    if known.any() and not known.all():
        idx = np.arange(len(z))
        z[~known] = np.interp(idx[~known], idx[known], z[known])
    out: FloatArray = np.nan_to_num(z)
    return out


def write_outputs(
    result: BuildResult,
    parts: tuple[Path, ...],
    out: Path,
    painter: _Painter,
    *,
    resolution: float,
    config: SlamConfig | None,
) -> list[Path]:
    """Grids and every file but pressure.png, the figures in the painter. Fills
    ``result.grids``.

    Every grid is cast here and handed to the painter as soon as it is done: drawing a floor's
    picture takes longer than casting its grid (matplotlib), so the painter draws one floor
    while this process casts the next, and a grid cast in the painter would only queue the
    pictures behind it.
    """
    seg = result.segmentation
    files: list[Path] = []
    # the names the daemon published (its [floors] settings), else the replay's own
    live = {info.index: info.name for info in seg.floors if info.name}
    if seg.detection is not None:
        live |= live_floor_names(recorded_floor_events(parts), seg.detection.segments)
    names = _names_by_height(seg, live)
    floor_entries: list[BuildingFloor] = []
    for info in seg.floors:
        entry, written = _floor_outputs(
            result,
            info,
            out,
            painter,
            name=names.get(info.index, str(info.index)),
            live_name=live.get(info.index),
            resolution=resolution,
            config=config,
        )
        floor_entries.append(entry)
        files += written
    order = [f for f in seg.floors if f.index in result.grids]
    # the poses the SLAM estimated: a scan the odometry said nothing about is not mapped, its
    # pose only drawn across the gap (metres off); the trajectory, the paths and the picture
    # have a gap there
    kept = ~result.run.blind
    building_png = out / "building.png"
    painter.submit(
        figures.building_figure,
        building_png,
        [result.grids[f.index] for f in order],
        [f.elevation_m for f in order],
        [
            _path_with_gaps(result.slam.scan_poses[:, :2], seg.scan_floor == f.index, kept)
            for f in order
        ],
        [f"floor {f.index}" for f in order],
    )
    files.append(building_png)
    z = scan_elevations(result)
    tum = out / "trajectory.tum"
    export.write_tum(tum, result.run.scans.t_ns[kept], result.slam.scan_poses[kept], z[kept])
    files.append(tum)
    building_yaml = out / "building.yaml"
    write_building(building_yaml, _building(result, parts, floor_entries, resolution))
    files.append(building_yaml)
    maps = out / "maps.mcap"
    write_maps_mcap(
        maps,
        int(result.run.scans.t_ns[0]),
        [FloorMap(f.index, result.grids[f.index], f.elevation_m) for f in order],
        MapsRun(
            poses=result.slam.scan_poses,
            z_m=z,
            floor=np.where(seg.scan_floor == BETWEEN_FLOORS, -1, seg.scan_floor),
            t_ns=result.run.scans.t_ns,
            odom=result.run.odom,
            transform_at=result.slam.keyframes,
            estimated=kept,
        ),
    )
    files.append(maps)
    return files


def _floor_outputs(
    result: BuildResult,
    info: FloorInfo,
    out: Path,
    painter: _Painter,
    *,
    name: str,
    live_name: str | None,
    resolution: float,
    config: SlamConfig | None,
) -> tuple[BuildingFloor, list[Path]]:
    """One floor's entry in building.yaml and the files written for it: its grid (into
    ``result.grids``), map_server files and picture (drawn by the painter)."""
    seg = result.segmentation
    job = _grid_job(result.run, seg, result.slam, info.index, resolution=resolution, config=config)
    grid = None if job is None else floor_grid(*job)
    files: list[Path] = []
    entry: dict[str, Any] = {
        "index": info.index,
        "name": name,
        "live_name": live_name if live_name != name else None,
        "elevation_m": round(info.elevation_m, 3),
        "mean_pressure_pa": None if info.level_pa is None else round(info.level_pa, 2),
        "visits": info.visits,
        "keyframes": int(np.sum(seg.scan_floor[result.slam.keyframes] == info.index)),
        "scans": int(np.sum(seg.scan_floor == info.index)),
    }
    if grid is not None:
        result.grids[info.index] = grid
        stem = f"floor_{info.index}"
        png = out / f"{stem}.png"
        painter.submit(
            export.write_png, grid, png, f"floor {info.index} ({info.elevation_m:+.2f} m)"
        )
        pgm, yml = export.write_map_server(grid, out, stem)
        files = [pgm, yml, png]
        entry.update({"map": yml.name, "image": pgm.name, "png": png.name})
    return BuildingFloor(**entry), files


def _building(
    result: BuildResult,
    parts: tuple[Path, ...],
    floors: list[BuildingFloor],
    resolution: float,
) -> Building:
    """building.yaml's content: the floors' entries, the rides, the closures, what is untied."""
    seg = result.segmentation
    return Building(
        source=str(parts[0]),
        parts=[str(p) for p in parts] if len(parts) > 1 else None,
        frame="one frame for all floors: the robot's start pose on its first floor",
        resolution_m=resolution,
        segmentation=seg.source,
        floors=floors,
        rides=[BuildingRide(r.t_start_ns, r.t_end_ns, r.from_floor, r.to_floor) for r in seg.rides],
        loop_closures=LoopClosures(
            within_floors=len(result.slam.loop_edges),
            cross_floor=result.cross_floor_closures,
            elevator_car=len(result.slam.car_edges),
        ),
        untied=_untied_entries(result),
        keyframes=len(result.slam.keyframes),
        scans=len(result.run.scans),
    )


def _names_by_height(seg: Segmentation, live: dict[int, str]) -> dict[int, str]:
    """``building.yaml``'s floor names: by order in height, counted from the name the live
    detector gave the start floor (the configured one), so consecutive floors have
    consecutive names; the index when no floor has a live name (the paper's method)."""
    detection = seg.detection
    if detection is None or not detection.segments or not live:
        return {info.index: str(info.index) for info in seg.floors}
    start = int(detection.segments[0].floor)
    if start not in live:
        return {info.index: str(info.index) for info in seg.floors}
    count = max(info.index for info in seg.floors) + 1
    return dict(enumerate(names_by_height(count, start, live[start])))


def _untied_entries(result: BuildResult) -> list[UntiedStretch]:
    """``building.yaml``'s account of the parts of the run that nothing but odometry across a
    gap places in the building (:attr:`SlamResult.untied`): each stretch of consecutive
    keyframes of such a part, in time order, with the floors it is on. Empty when the whole
    run is tied together."""
    t_ns = result.run.scans.t_ns
    floor = result.segmentation.scan_floor
    entries = []
    evidence = result.slam.untied_evidence
    for number, part in enumerate(result.slam.untied, start=1):
        breaks = np.flatnonzero(np.diff(part) > 1) + 1
        for stretch in np.split(part, breaks):
            scans = result.slam.keyframes[stretch]
            entries.append(
                UntiedStretch(
                    part=number,
                    t_start_ns=int(t_ns[scans[0]]),
                    t_end_ns=int(t_ns[scans[-1]]),
                    keyframes=len(stretch),
                    floors=sorted({int(f) for f in floor[scans] if f != BETWEEN_FLOORS}),
                    cut_by=evidence[number - 1] if number <= len(evidence) else "",
                )
            )
    return sorted(entries, key=lambda e: e.t_start_ns)


def _path_with_gaps(
    xy: FloatArray, on_floor: npt.NDArray[np.bool_], estimated: npt.NDArray[np.bool_]
) -> FloatArray:
    """A floor's path for the picture: its estimated poses, with a NaN row where poses were
    left out between two of them, so the line breaks at a gap rather than crossing it."""
    idx = np.flatnonzero(on_floor & estimated)
    left_out = np.cumsum(~estimated)
    gap_after = np.flatnonzero(np.diff(left_out[idx]) > 0)
    return np.insert(xy[idx], gap_after + 1, np.nan, axis=0)


def _pressure_args(run: RunData, segmentation: Segmentation) -> dict[str, Any]:
    """What figures.pressure_figure draws for a run (all arrays: cheap to send)."""
    det = segmentation.detection
    if len(run.pressure_t_ns) == 0:
        t = run.scans.t_ns
        return {
            "t_s": (t - t[0]) / 1e9,
            "raw_pa": np.full(len(t), np.nan),
            "smoothed_pa": None,
            "rate_pa_per_s": None,
            "transitions": [],
        }
    t0 = run.pressure_t_ns[0]
    args: dict[str, Any] = {
        "t_s": (run.pressure_t_ns - t0) / 1e9,
        "raw_pa": run.pressure_pa,
        "smoothed_pa": None,
        "rate_pa_per_s": None,
        "transitions": [],
        "smoothed_label": (
            "smoothed, weather removed with the reference station"
            if len(run.reference_t_ns)
            else "smoothed"
        ),
    }
    if det is not None:
        args["smoothed_pa"] = np.asarray(det.smoothed_pa, dtype=np.float64)
        args["rate_pa_per_s"] = np.asarray(det.rate_pa_per_s, dtype=np.float64)
        args["series_t_s"] = (det.t_ns - t0) / 1e9
        args["threshold_pa_per_s"] = det.threshold_pa_per_s
        args["transitions"] = [
            figures.Transition(
                (tr.t_start_ns - t0) / 1e9,
                (tr.t_end_ns - t0) / 1e9,
                f"{tr.from_floor}\u2192{tr.to_floor}",
            )
            for tr in det.transitions
        ]
    return args


def summary_lines(result: BuildResult, out: Path) -> list[str]:
    """What the CLI prints: one line per floor and the run's totals."""
    lines = [f"maps of {len(result.grids)} floor(s) in {out} ({result.segmentation.source})"]
    for info in result.segmentation.floors:
        grid = result.grids.get(info.index)
        size = "" if grid is None else f"{grid.shape[1]}x{grid.shape[0]} cells"
        pressure = "" if info.level_pa is None else f", {info.level_pa:.1f} Pa"
        lines.append(
            f"  floor {info.index}: {info.elevation_m:+.2f} m{pressure}, "
            f"{info.visits} visit(s), {size}"
        )
    slam = result.slam
    lines.append(
        f"  {len(result.run.scans)} scans, {len(slam.keyframes)} keyframes, "
        f"{len(slam.loop_edges)} loop closures within floors, "
        f"{len(slam.car_edges)} between the elevator car at different rides"
    )
    t0 = int(result.run.scans.t_ns[0])
    for stretch in _untied_entries(result):
        lines.append(
            f"  placed by odometry alone ({stretch.cut_by}; nothing the scans "
            f"saw ties it to the rest): {stretch.keyframes} keyframes from "
            f"{(stretch.t_start_ns - t0) / 1e9:.1f} to {(stretch.t_end_ns - t0) / 1e9:.1f} s"
            f" on floor(s) {', '.join(map(str, stretch.floors)) or 'none'}"
        )
    total = sum(result.timings_s.values())
    lines.append(
        "  time "
        + ", ".join(f"{k} {v:.1f} s" for k, v in result.timings_s.items())
        + f" (total {total:.1f} s)"
    )
    return lines
