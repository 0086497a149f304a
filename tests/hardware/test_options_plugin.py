"""The hardware options from the repository root: ``--lms-port PATH`` and ``--lms-port=PATH``,
with a port path outside the checkout, parse and leave pytest rooted at the checkout with its
configuration (``addopts``, markers, ``testpaths``), as ``pytest_baromap`` promises."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("form", ["space", "equals"])
def test_a_port_outside_the_checkout_parses_and_keeps_the_checkouts_configuration(
    tmp_path: Path, form: str
) -> None:
    port = tmp_path / "ttyUSB0"  # an existing path, as a real port is
    port.touch()
    option = ["--lms-port", str(port)] if form == "space" else [f"--lms-port={port}"]
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST_")}
    # --markers: what the configuration declares, without collecting the whole suite; a test
    # path on the command line would root the run at the checkout by itself
    result = subprocess.run(
        [sys.executable, "-m", "pytest", *option, "--markers", "-p", "no:cacheprovider"],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    out = result.stdout + result.stderr
    assert result.returncode == 0, out
    assert "@pytest.mark.hardware: needs a real device" in out, out[-2000:]
