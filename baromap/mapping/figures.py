"""The two pictures of a run, after the paper's Figures 4 and 7.

``pressure.png``: raw pressure, the smoothed series, its rate of change with the detection
threshold, and the detected transitions shaded, so a person can see why the run was cut where
it was. ``building.png``: every floor's walls drawn in 3D at the floor's measured height, with
the corrected path, so a person can see that the floors line up over the elevator.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from baromap.arrays import FloatArray
from baromap.mapping.occupancy import OccupancyGrid

#: Most wall points drawn per floor in the 3D view (more only slows matplotlib down).
MAX_POINTS_PER_FLOOR = 25_000


@dataclass(frozen=True, slots=True)
class Transition:
    t_start_s: float
    t_end_s: float
    label: str


def warm_up() -> None:
    """Load matplotlib and its fonts (a second or so, once per process) before a figure is
    asked for: a process drawing beside the SLAM does it while the SLAM runs."""
    plt = pyplot()
    fig, ax = plt.subplots()
    ax.set_title("warm-up \u2192")
    fig.canvas.draw()
    plt.close(fig)


def settle_layout(fig: Any) -> None:
    """Tight layout, computed once and then fixed: ``tight_layout`` leaves a placeholder
    layout engine behind, and with any engine set ``savefig`` draws the whole figure once
    more before the real draw (for constrained layout's sake), resampling every image again:
    a quarter of the time of a floor's picture."""
    fig.tight_layout()
    fig.set_layout_engine(None)


def pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    return plt


def pressure_figure(
    path: Path,
    t_s: FloatArray,
    raw_pa: FloatArray,
    *,
    smoothed_pa: FloatArray | None,
    rate_pa_per_s: FloatArray | None,
    transitions: Sequence[Transition],
    threshold_pa_per_s: float | None = None,
    smoothed_label: str = "smoothed",
    series_t_s: FloatArray | None = None,
) -> None:
    """``series_t_s``: times of the smoothed and rate series when they are not those of the
    raw samples (detection leaves out non-finite and repeated samples)."""
    plt = pyplot()
    series_t = t_s if series_t_s is None else series_t_s
    rows = 2 if rate_pa_per_s is not None else 1
    fig, axes = plt.subplots(rows, 1, figsize=(11, 3.2 * rows), sharex=True, squeeze=False)
    ax = axes[0, 0]
    ax.plot(t_s, raw_pa, color="0.7", lw=0.6, label="raw")
    if smoothed_pa is not None:
        ax.plot(series_t, smoothed_pa, color="C0", lw=1.2, label=smoothed_label)
    ax.set_ylabel("pressure [Pa]")
    for k, tr in enumerate(transitions):
        for a in axes[:, 0]:
            a.axvspan(
                tr.t_start_s,
                tr.t_end_s,
                color="C3",
                alpha=0.25,
                lw=0,
                label="transition" if (k == 0 and a is ax) else None,
            )
        ax.annotate(
            tr.label,
            ((tr.t_start_s + tr.t_end_s) / 2, ax.get_ylim()[1]),
            ha="center",
            va="top",
            fontsize=7,
        )
    ax.legend(loc="lower left", fontsize=8)
    ax.set_title("Pressure over the run, and the detected floor transitions")
    if rate_pa_per_s is not None:
        ax2 = axes[1, 0]
        ax2.plot(series_t, rate_pa_per_s, color="C2", lw=0.8, label="rate of change")
        if threshold_pa_per_s is not None:
            ax2.axhline(threshold_pa_per_s, color="C3", ls="--", lw=0.8, label="threshold")
            ax2.axhline(-threshold_pa_per_s, color="C3", ls="--", lw=0.8)
        ax2.set_ylabel("dP/dt [Pa/s]")
        ax2.legend(loc="lower left", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    settle_layout(fig)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def building_figure(
    path: Path,
    grids: Sequence[OccupancyGrid],
    elevations_m: Sequence[float],
    paths_xy: Sequence[FloatArray],
    names: Sequence[str],
) -> None:
    """Floors stacked at their heights in an oblique 3D view."""
    plt = pyplot()
    fig = plt.figure(figsize=(10, 8))
    ax = fig.add_subplot(projection="3d")
    rng = np.random.default_rng(0)
    for k, (grid, z, xy, name) in enumerate(zip(grids, elevations_m, paths_xy, names, strict=True)):
        rows, cols = np.nonzero(grid.occupied())
        if len(rows) > MAX_POINTS_PER_FLOOR:
            pick = rng.choice(len(rows), MAX_POINTS_PER_FLOOR, replace=False)
            rows, cols = rows[pick], cols[pick]
        x = grid.origin_xy[0] + (cols + 0.5) * grid.resolution
        y = grid.origin_xy[1] + (rows + 0.5) * grid.resolution
        color = f"C{k % 10}"
        ax.scatter(
            x,
            y,
            np.full(len(x), z),
            s=0.3,
            color=color,
            depthshade=False,
            label=f"{name}: {z:+.2f} m",
        )
        if len(xy):
            ax.plot(xy[:, 0], xy[:, 1], np.full(len(xy), z), color=color, lw=0.5, alpha=0.6)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("elevation [m]")
    ax.view_init(elev=28, azim=-60)
    ax.legend(loc="upper left", fontsize=8, markerscale=12)
    ax.set_title("Floor maps stacked at their barometric heights")
    settle_layout(fig)
    fig.savefig(path, dpi=110)
    plt.close(fig)
