"""``baromapd-bench`` on the twins: the same command a bench runs on real ports.

Any subset of ports: the three devices, then the barometer alone. Each report names its
device's rate against the expected one, its gaps, errors by reason, stamp offset and spread,
reconnects; the daemon's recording of the run holds each device's messages.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import pytest

from baromap.recording import read_messages
from baromap.sim.twins import SimDevices
from baromapd import bench


@pytest.fixture
def twins(tmp_path: Path) -> Iterator[SimDevices]:
    with SimDevices(link_dir=tmp_path / "links", minutes=10, seed=4) as devices:
        yield devices


def test_bench_reports_each_device_and_records_the_run(
    twins: SimDevices, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    paths = twins.paths()
    status = bench.main(
        ["--laser", paths["lms200"], "--base", paths["p3at"],
         "--barometer", paths["baro"], "--seconds", "4", "-o", str(tmp_path / "rec")]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert status == 0, out
    for device, expected in (("laser", 10.29), ("base", 10.0), ("barometer", 50.0)):
        block = out.split(f"{device} on ")[1].split("\n  reconnects")[0]
        rate = re.search(r"([\d.]+) Hz \(expected ([\d.]+)\)", block)
        assert rate is not None, block
        assert float(rate[2]) == pytest.approx(expected, rel=0.01)
        assert 0.8 * expected <= float(rate[1]) <= 1.1 * expected, block
        assert "errors by reason: none" in block
        assert "stamp - read" in block and "longest gap" in block
    assert "device clock against the host's" in out
    recordings = list((tmp_path / "rec").glob("*.mcap"))
    assert [str(p) in out for p in recordings] == [True]
    topics = Counter(record.topic for record in read_messages(recordings[0]))
    assert topics["/scan"] > 5 and topics["/odom"] > 15 and topics["/baro"] > 80, topics


def test_bench_takes_any_subset_of_ports(
    twins: SimDevices, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    status = bench.main(["--barometer", twins.paths()["baro"], "--seconds", "1.5", "-o",
                         str(tmp_path / "rec")])  # fmt: skip
    out = capsys.readouterr().out
    assert status == 0, out
    assert "barometer on " in out and "laser on " not in out and "base on " not in out


def test_bench_without_a_port_or_with_a_dead_one_fails(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert bench.main(["--seconds", "1"]) == 2
    status = bench.main(
        ["--base", str(tmp_path / "nothing"), "--seconds", "1", "-o", str(tmp_path / "rec")]
    )
    out = capsys.readouterr().out
    assert status == 1
    assert "base on " in out and "down" in out
