"""Files a finished mapping run leaves behind, in formats other tools read.

- ROS map_server maps: a binary PGM (P5) whose first row is the top of the map, and a YAML
  with ``image, resolution, origin, negate, occupied_thresh, free_thresh, mode``; ``mode:
  trinary`` with 0 = occupied, 254 = free, 205 = unknown, as map_saver writes them.
- TUM trajectories (``t x y z qx qy qz qw``, seconds), read by evo and the TUM tools.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml

from baromap.errors import EncodeError, InputFormatError
from baromap.mapping.occupancy import FREE_THRESH, OCCUPIED_THRESH, OccupancyGrid

FREE_VALUE = 254
OCCUPIED_VALUE = 0
UNKNOWN_VALUE = 205


def map_image(grid: OccupancyGrid) -> npt.NDArray[np.uint8]:
    """Trinary image, top row = highest y (image convention)."""
    image = np.full(grid.shape, UNKNOWN_VALUE, dtype=np.uint8)
    image[grid.free()] = FREE_VALUE
    image[grid.occupied()] = OCCUPIED_VALUE
    flipped: npt.NDArray[np.uint8] = np.ascontiguousarray(image[::-1])
    return flipped


def write_pgm(path: Path, image: npt.NDArray[np.uint8]) -> None:
    """Write an 8-bit binary PGM (P5, maxval 255), with Pillow."""
    from PIL import Image

    if image.ndim != 2:
        raise EncodeError(f"a PGM holds one channel, not an image of shape {image.shape}")
    Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8)).save(path, format="PPM")


def read_pgm(path: Path) -> npt.NDArray[np.uint8]:
    """Read an 8-bit PGM (for tests and tools that check what we wrote), with Pillow."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            if image.format != "PPM" or image.mode != "L":
                raise InputFormatError(f"{path}: not an 8-bit greyscale PGM")
            pixels: npt.NDArray[np.uint8] = np.asarray(image, dtype=np.uint8)
    except (OSError, UnidentifiedImageError) as exc:
        raise InputFormatError(f"cannot read {path}: {exc}") from exc
    return pixels


def write_map_server(grid: OccupancyGrid, directory: Path, stem: str) -> tuple[Path, Path]:
    """``stem.pgm`` + ``stem.yaml`` loadable by ROS map_server / nav2 map_server."""
    pgm = directory / f"{stem}.pgm"
    write_pgm(pgm, map_image(grid))
    meta = {
        "image": pgm.name,
        "resolution": float(grid.resolution),
        "origin": [float(grid.origin_xy[0]), float(grid.origin_xy[1]), 0.0],
        "negate": 0,
        "occupied_thresh": OCCUPIED_THRESH,
        "free_thresh": FREE_THRESH,
        "mode": "trinary",
    }
    yml = directory / f"{stem}.yaml"
    yml.write_text(yaml.safe_dump(meta, sort_keys=False), encoding="utf-8")
    return pgm, yml


def write_png(grid: OccupancyGrid, path: Path, title: str | None = None) -> None:
    """A picture of the map with a metric frame, for people."""
    from baromap.mapping.figures import pyplot, settle_layout

    plt = pyplot()
    h, w = grid.shape
    extent = (
        grid.origin_xy[0],
        grid.origin_xy[0] + w * grid.resolution,
        grid.origin_xy[1],
        grid.origin_xy[1] + h * grid.resolution,
    )
    scale = max(w, h) * grid.resolution
    size = min(12.0, max(5.0, scale / 4))
    fig, ax = plt.subplots(figsize=(size, size * h / max(w, 1) + 0.6))
    ax.imshow(
        map_image(grid),
        cmap="gray",
        vmin=0,
        vmax=255,
        extent=extent,
        origin="upper",
        interpolation="nearest",  # a map's cells, not a photograph to smooth
    )
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title)
    settle_layout(fig)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_tum(
    path: Path,
    t_ns: npt.NDArray[np.int64],
    poses: npt.NDArray[np.float64],
    z_m: npt.NDArray[np.float64] | None = None,
) -> None:
    """TUM trajectory: one line per pose; z is the floor's elevation when known."""
    z = np.zeros(len(poses)) if z_m is None else np.asarray(z_m, dtype=np.float64)
    with path.open("w", encoding="ascii") as handle:
        for t, (x, y, theta), zz in zip(t_ns, poses, z, strict=True):
            sec, nsec = divmod(int(t), 1_000_000_000)
            qz, qw = math.sin(theta / 2), math.cos(theta / 2)
            handle.write(f"{sec}.{nsec:09d} {x:.6f} {y:.6f} {zz:.4f} 0 0 {qz:.9f} {qw:.9f}\n")


def read_tum(
    path: Path,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(t_ns, (N, 3) x y z, (N, 4) qx qy qz qw) of a TUM trajectory, times to the nanosecond
    (a float of Unix seconds holds only about a quarter of a microsecond)."""
    try:
        rows = np.loadtxt(path, dtype=str, ndmin=2)
        if rows.size == 0:
            return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4))
        if rows.shape[1] != 8:
            raise InputFormatError(f"{path}: TUM lines have 8 columns, not {rows.shape[1]}")
        seconds = [s.partition(".") for s in rows[:, 0]]
        t = np.array([int(a) * 1_000_000_000 + int(b[:9].ljust(9, "0")) for a, _, b in seconds])
        values = rows[:, 1:].astype(np.float64)
    except (OSError, ValueError) as exc:
        raise InputFormatError(f"{path}: not a TUM trajectory: {exc}") from exc
    return t.astype(np.int64), values[:, 0:3], values[:, 3:7]


def write_building_yaml(path: Path, building: dict[str, Any]) -> None:
    path.write_text(yaml.safe_dump(building, sort_keys=False), encoding="utf-8")
