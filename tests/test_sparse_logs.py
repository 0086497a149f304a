"""Sparse logs (a scan every metre or more, as many public logs keep them): what the SLAM
does with a step longer than its matching searches."""

from __future__ import annotations

from pathlib import Path

import yaml

from baromap.mapping.build import build_maps


def test_a_sparse_logs_long_step_is_no_gap(shared_data: Path, tmp_path: Path) -> None:
    """Every fourth scan of Intel: steps of up to 4 m and 100 degrees, each in the time the
    scans always take. A step longer than the matching searches is begun anew as after a
    silence, and where nothing ties the part after it back, that part is listed, but the
    laser was never silent: the log says so at info, not as the warning of a break."""
    from structlog.testing import capture_logs

    from baromap.evaluation.log_variants import Variant, make_variant, read_source
    from baromap.recording.carmen_import import import_carmen

    source = read_source(shared_data / "laser" / "intel-corrected-abstime.log.gz", "intel")
    log = tmp_path / "intel4.log"
    make_variant(source, Variant(stride=4), 0).write(log)
    import_carmen(log, tmp_path / "run.mcap")
    with capture_logs() as logs:
        build_maps(tmp_path / "run.mcap", tmp_path / "maps")
    events = {e["event"]: e for e in logs}
    assert "part of the run is placed by odometry across a gap alone" not in events
    said = events["part of the run is placed by odometry across a long step alone"]
    assert said["log_level"] == "info"
    assert all(text.startswith("a step of ") for text in said["evidence"])
    building = yaml.safe_load((tmp_path / "maps" / "building.yaml").read_text())
    assert building["untied"]
    assert all("in the scans' usual time" in s["cut_by"] for s in building["untied"])
