"""The map_server image: a binary PGM that ROS map_server, nav2 and image tools all read."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from baromap.errors import EncodeError
from baromap.mapping.export import (
    FREE_VALUE,
    OCCUPIED_VALUE,
    UNKNOWN_VALUE,
    read_pgm,
    write_pgm,
)


@pytest.mark.parametrize("shape", [(1, 1), (3, 7), (101, 64)])
def test_a_pgm_is_a_p5_header_and_the_rows_top_first(
    tmp_path: Path, shape: tuple[int, int]
) -> None:
    rng = np.random.default_rng(7)
    values = np.array([FREE_VALUE, OCCUPIED_VALUE, UNKNOWN_VALUE], dtype=np.uint8)
    height, width = shape
    image = rng.choice(values, size=(height, 2 * width))[:, ::2]  # strided, as a view can be
    path = tmp_path / "floor_0.pgm"
    write_pgm(path, image)
    rows = np.ascontiguousarray(image).tobytes()
    assert path.read_bytes() == f"P5\n{width} {height}\n255\n".encode() + rows
    np.testing.assert_array_equal(read_pgm(path), image)


def test_an_image_with_channels_is_refused(tmp_path: Path) -> None:
    with pytest.raises(EncodeError, match="one channel"):
        write_pgm(tmp_path / "rgb.pgm", np.zeros((4, 4, 3), dtype=np.uint8))
