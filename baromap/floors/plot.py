"""The paper's Figure 4 for any run: raw and smoothed pressure, rate of change, transitions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt

from baromap.errors import ConfigError
from baromap.floors.detection import FloorDetection
from baromap.messages import NS_PER_S


def plot_detection(
    detection: FloorDetection, t_ns: npt.ArrayLike, pressure_pa: npt.ArrayLike, path: str | Path
) -> None:
    """Write a PNG: pressure (raw, smoothed) with floor segments, and the rate below it.

    The raw series comes with its own times: detection leaves out non-finite and repeated
    samples, so its arrays can be shorter than the input's.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t0 = detection.t_ns[0]
    t = (detection.t_ns - t0) / NS_PER_S
    raw_t = (np.asarray(t_ns, dtype=np.int64) - t0) / NS_PER_S
    fig, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(12, 6.5))
    top.plot(raw_t, np.asarray(pressure_pa) / 100.0, lw=0.5, color="0.6", label="raw")
    top.plot(t, detection.smoothed_pa / 100.0, lw=1.0, color="C0", label="smoothed")
    bottom.plot(t, detection.rate_pa_per_s, lw=0.7, color="C1")
    for tr in detection.transitions:
        a, b = (tr.t_start_ns - t0) / NS_PER_S, (tr.t_end_ns - t0) / NS_PER_S
        for ax in (top, bottom):
            ax.axvspan(a, b, color="C3", alpha=0.25, lw=0)
        top.annotate(
            f"{tr.from_floor}\u2192{tr.to_floor}",
            ((a + b) / 2, 1.0),
            xycoords=("data", "axes fraction"),
            ha="center",
            va="bottom",
            fontsize=8,
        )
        bottom.axvline((tr.t_detect_ns - t0) / NS_PER_S, color="C3", lw=0.8)
    top.set_ylabel("pressure [hPa]")
    top.invert_yaxis()  # up the page = up the building
    top.legend(loc="best", fontsize=8)
    bottom.set_ylabel("rate [Pa/s]")
    bottom.set_xlabel("time [s]")
    fig.suptitle(f"floor detection ({detection.method}): shaded = transitions, line = decided")
    fig.tight_layout()
    try:
        # a name without a suffix is written as PNG under that very name (matplotlib would
        # otherwise add ".png" behind the caller's back)
        fig.savefig(path, dpi=100, format=None if Path(path).suffix else "png")
    except (OSError, ValueError) as exc:  # unwritable place, unknown image format
        raise ConfigError(f"cannot write the plot {path}: {exc}") from exc
    finally:
        plt.close(fig)
