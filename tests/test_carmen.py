"""CARMEN import: parsing, the odometry error model, and the recording it writes."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from baromap.errors import ConfigError, InputFormatError
from baromap.mapping import se2
from baromap.messages import BeamFlag, LaserScan, Odometry
from baromap.odometry.errors import OdometryErrorModel
from baromap.odometry.synthesis import synthesize_odometry
from baromap.recording import read_messages, read_metadata
from baromap.recording.carmen import flaser_geometry, parse_lines, parse_time_ns, read_carmen
from baromap.recording.carmen_import import (
    check_mount,
    declared_mount,
    import_carmen,
    laser_offset,
    to_laser_scan,
)

RANGES = " ".join(["1.5"] * 178 + ["81.83", "2.25"])
FLASER = f"FLASER 180 {RANGES} 1.0 2.0 0.5 1.1 2.1 0.5 976052890.244111 pippo 976052890.244111"
ROBOTLASER1 = (
    "ROBOTLASER1 0 -1.5708 3.14159 0.0174533 81.9 0.01 0 3 1.0 2.0 3.0 0 "
    "0.1 0.2 0.3 0.0 0.0 0.3 0.5 0.1 0.5 0.5 0.5 12.5 host 12.5"
)
ODOM = "ODOM 1.5 -2.5 0.25 0.3 0.1 0 10.000001 host 10.000001"


@pytest.mark.parametrize(
    ("text", "ns"),
    [
        ("976052890.244111", 976052890_244111000),
        ("0.000246", 246000),
        ("12", 12_000_000_000),
        ("1.1234567891", 1_123456789),
        ("-0.5", -500_000_000),
    ],
)
def test_parse_time_is_exact(text: str, ns: int) -> None:
    assert parse_time_ns(text) == ns


@pytest.mark.parametrize(
    ("text", "ns"),
    [
        ("1.01893e+09", 1_018_930_000 * 10**9),  # CARMEN's %g, as three public logs print
        ("4.29497e+09", 4_294_970_000 * 10**9),
        ("2.5E-3", 2_500_000),
        ("1.08e-42", 0),
    ],
)
def test_parse_time_reads_exponent_notation_exactly(text: str, ns: int) -> None:
    assert parse_time_ns(text) == ns


@pytest.mark.parametrize("text", ["abc", "1.2.3", "1.x", "nan", "inf", "1_0", "9" * 30])
def test_parse_time_rejects_what_is_no_time(text: str) -> None:
    with pytest.raises(ValueError):
        parse_time_ns(text)


def test_flaser_fields() -> None:
    log = parse_lines([FLASER])
    (scan,) = log.scans
    assert scan.t_ns == 976052890_244111000
    assert scan.laser_pose == (1.0, 2.0, 0.5)
    assert scan.robot_pose == (1.1, 2.1, 0.5)
    assert scan.angle_min_rad == pytest.approx(-math.pi / 2)
    assert scan.angle_increment_rad == pytest.approx(math.radians(1.0))
    assert len(scan.ranges_m) == 180
    assert scan.ranges_m[-1] == 2.25


def test_robotlaser1_fields() -> None:
    (scan,) = parse_lines([ROBOTLASER1]).scans
    assert scan.angle_min_rad == pytest.approx(-1.5708)
    assert scan.angle_increment_rad == pytest.approx(0.0174533)
    np.testing.assert_allclose(scan.ranges_m, [1.0, 2.0, 3.0])
    assert scan.laser_pose == (0.1, 0.2, 0.3)
    assert scan.robot_pose == (0.0, 0.0, 0.3)
    assert scan.t_ns == 12_500_000_000


def test_odom_fields() -> None:
    (odom,) = parse_lines([ODOM]).odometry
    assert (odom.x_m, odom.y_m, odom.theta_rad) == (1.5, -2.5, 0.25)
    assert odom.t_ns == 10_000_001_000


@pytest.mark.parametrize(
    "line",
    [
        "FLASER 180 1 2 3",  # shorter than its beam count
        "FLASER 99999 1 2",  # beam count out of bounds
        "FLASER x",
        "ODOM 1 2",
        "ROBOTLASER1 0 -1.5 3.1 0.01 81 0.01 0 2 1 2 1",
        ROBOTLASER1.replace("0.0174533", "0"),  # no angular step
        FLASER.replace("1.1 2.1 0.5", "nan 2.1 0.5"),  # a pose that would poison odometry
        "ODOM 1.5 inf 0.25 0.3 0.1 0 10.000001 host 10.000001",
    ],
)
def test_malformed_lines_are_counted_not_fatal(line: str) -> None:
    log = parse_lines([line, FLASER, "# comment", "", "NEFF 15"])
    assert len(log.scans) == 1
    assert sum(v for k, v in log.skipped.items() if k.startswith("malformed")) == 1
    assert log.skipped["unused NEFF"] == 1


def test_a_log_with_both_laser_lines_keeps_each_scan_once() -> None:
    log = parse_lines([FLASER, ROBOTLASER1])
    (scan,) = log.scans
    assert len(scan.ranges_m) == 3  # the ROBOTLASER1 line, which states its geometry
    assert log.skipped["FLASER beside ROBOTLASER1"] == 1


def test_no_return_becomes_flagged_nan() -> None:
    (scan,) = parse_lines([FLASER]).scans
    msg = to_laser_scan(scan, 0)
    assert np.isnan(msg.ranges_m[178])
    assert msg.flags[178] & BeamFlag.OVER_RANGE
    assert msg.valid().sum() == 179


@pytest.mark.parametrize(
    ("n", "first_deg", "step_deg"),
    [(180, -90.0, 1.0), (181, -90.0, 1.0), (361, -90.0, 0.5), (401, -50.0, 0.25), (91, -90.0, 2.0)],
)
def test_flaser_geometry_is_carmens_guess_for_a_sick(
    n: int, first_deg: float, step_deg: float
) -> None:
    first, step = flaser_geometry(n)
    assert math.degrees(first) == pytest.approx(first_deg)
    assert math.degrees(step) == pytest.approx(step_deg)


@pytest.mark.parametrize(
    ("n", "param", "first_deg", "step_deg"),
    [
        (201, "0.5", -50.0, 0.5),  # an LMS over 100 deg at half a degree, as the log says
        (201, None, -90.0, 0.9),  # unsaid: CARMEN's guess, 180 deg
        (181, "0.5", -90.0, 1.0),  # a count CARMEN knows keeps CARMEN's geometry
        (201, "junk", -90.0, 0.9),
    ],
)
def test_a_flaser_beam_count_carmen_cannot_place_takes_the_logs_resolution(
    n: int, param: str | None, first_deg: float, step_deg: float
) -> None:
    lines = [] if param is None else [f"PARAM laser_front_laser_resolution {param} host 0"]
    lines.append(_flaser_line(np.full(n, 2.0), 10.0))
    (scan,) = parse_lines(lines).scans
    assert math.degrees(scan.angle_min_rad) == pytest.approx(first_deg)
    assert math.degrees(scan.angle_increment_rad) == pytest.approx(step_deg)


def _flaser_line(ranges: np.ndarray, t: float) -> str:
    text = " ".join(f"{r:.3f}" for r in ranges)
    return f"FLASER {len(ranges)} {text} 0 0 0 0 0 0 {t:.6f} host {t:.6f}"


def _short_range_log(code: float | None, n_scans: int = 60) -> list[str]:
    """A room of walls 2-12 m away seen by a laser whose readings stop at 8 m."""
    rng = np.random.default_rng(1)
    lines = []
    for k in range(n_scans):
        ranges = rng.uniform(2.0, 12.0, 181) + rng.normal(0.0, 0.01, 181)
        if code is not None:
            ranges = np.where(ranges >= code, code, ranges)
            if k == 3:
                ranges[7] = 9.5  # a glitch past the code
        lines.append(_flaser_line(ranges, 10.0 + k))
    return lines


def test_a_short_range_no_return_code_is_found_and_flagged() -> None:
    log = parse_lines(_short_range_log(8.183))
    assert log.range_limit_m == pytest.approx(8.178)
    coded = np.concatenate([s.ranges_m for s in log.scans]) == 8.183
    flagged = np.concatenate([to_laser_scan(s, 0).flags for s in log.scans]) != 0
    assert coded.sum() > 0.3 * coded.size  # the room reaches past 8 m often
    assert np.all(flagged[coded])
    assert np.count_nonzero(flagged & ~coded) < 0.001 * coded.size  # walls in the code's bin


def test_readings_that_merely_end_somewhere_keep_their_limit() -> None:
    log = parse_lines(_short_range_log(None))
    assert log.range_limit_m is None
    assert all(s.range_max_m == 80.0 for s in log.scans)


def test_the_declared_front_laser_maximum_limits_the_ranges() -> None:
    lines = ["PARAM robot_front_laser_max 7.5 host 0", *_short_range_log(None, 5)]
    log = parse_lines(lines)
    assert log.range_limit_m == 7.5
    far = np.concatenate([s.ranges_m for s in log.scans]) >= 7.5
    flagged = np.concatenate([to_laser_scan(s, 0).flags for s in log.scans]) != 0
    assert np.array_equal(far, flagged)


def test_file_without_laser_is_an_input_error(tmp_path: Path) -> None:
    path = tmp_path / "odom.log"
    path.write_text(ODOM + "\n")
    with pytest.raises(InputFormatError, match="no FLASER or ROBOTLASER1 line"):
        read_carmen(path)


def test_a_file_whose_laser_lines_are_all_malformed_says_which_line_and_why(
    tmp_path: Path,
) -> None:
    path = tmp_path / "short.log"
    path.write_text("# a comment\n" + ODOM + "\n" + "\n".join(["FLASER 180 1 2 3"] * 3) + "\n")
    with pytest.raises(
        InputFormatError,
        match=r"no usable laser line; 3 FLASER lines malformed, the first at line 3: line "
        r"shorter than its beam count",
    ):
        read_carmen(path)


def _line(kind: str, k: int, stamp: str) -> str:
    """Line ``k`` of a small log: an FLASER a metre on from the last, or an ODOM."""
    pose = f"{k:.1f} 0.0 0.0"
    if kind == "FLASER":
        return f"FLASER 3 1.0 2.0 3.0 {pose} {pose} {stamp} host {stamp}"
    return f"ODOM {pose} 0 0 0 {stamp} host {stamp}"


@pytest.mark.parametrize(
    "stamp",
    ["1.01893e+09", "0", "4.29497e+09", "-1.5", "3.65796e-86"],
    ids=["one value", "zeros", "wrapped", "negative", "denormal"],
)
def test_stamps_that_cannot_order_the_scans_are_replaced_by_the_scan_order(stamp: str) -> None:
    """Three public logs of one collection: every stamp one value, zeros, or negative and then
    wrapped at 32 bits. Each line is timed by its place in the file, a scan a second, the
    odometry between its scans; the repair says what it found."""
    lines = []
    for k in range(6):
        lines += [_line("ODOM", k, stamp), _line("ODOM", k, stamp), _line("FLASER", k, stamp)]
    log = parse_lines(lines)
    assert log.scan_times_ns().tolist() == [(k + 1) * 10**9 for k in range(6)]
    odom = [o.t_ns for o in log.odometry]
    assert odom[:4] == [333_333_333, 666_666_667, 1_333_333_333, 1_666_666_667]
    assert log.stamps is not None and log.stamps.from_order
    assert (log.stamps.scans, log.stamps.odometry) == (6, 12)
    assert sum(log.stamps.faults.values()) == 18
    assert log.stamps.summary()["timed_by"] == "scan order, a scan every 1 s"


@pytest.mark.parametrize("odometry_first", [True, False], ids=["before", "after"])
def test_a_pose_written_with_each_scan_is_timed_with_its_scan(odometry_first: bool) -> None:
    """A log timed by its scan order that writes one pose beside each scan: the pose is the
    robot's at that scan (timed between two scans, every scan's odometry would be half a step
    off)."""
    lines = []
    for k in range(6):
        pair = [_line("ODOM", k, "0"), _line("FLASER", k, "0")]
        lines += pair if odometry_first else pair[::-1]
    log = parse_lines(lines)
    assert log.stamps is not None and log.stamps.from_order
    assert [o.t_ns for o in log.odometry] == log.scan_times_ns().tolist()
    assert [o.x_m for o in log.odometry] == [float(k) for k in range(6)]


def test_a_few_broken_stamps_take_times_between_their_neighbours() -> None:
    """Acapulco's kind: a zero, a negative and a stray stamp among good ones. Those lines are
    timed between their neighbours in the file; the good ones keep theirs, an odometry line a
    little behind the one before it too (a clock's jitter, sorted afterwards)."""
    stamps = ["10.0", "10.1", "0", "10.3", "-18.77", "999.5", "10.6", "10.7", "10.65", "10.9"]
    lines = [_line("FLASER" if k % 3 == 0 else "ODOM", k, t) for k, t in enumerate(stamps)]
    log = parse_lines(lines)
    scans = [10_000_000_000, 10_300_000_000, 10_600_000_000, 10_900_000_000]
    assert log.scan_times_ns().tolist() == scans
    odom = [o.t_ns for o in log.odometry]
    assert odom == [10_100_000_000, 10_200_000_000, 10_400_000_000, 10_500_000_000,
                    10_650_000_000, 10_700_000_000]  # fmt: skip
    assert log.stamps is not None and not log.stamps.from_order
    assert log.stamps.faults == {"zero": 1, "negative": 1, "out of order": 1}
    assert (log.stamps.scans, log.stamps.odometry) == (0, 3)


def test_a_stamp_broken_in_one_field_is_read_from_the_other() -> None:
    line = FLASER.replace("976052890.244111 pippo", "0 pippo")
    (scan,) = parse_lines([line]).scans
    assert scan.t_ns == 976052890_244111000


def test_good_stamps_are_left_as_they_are(shared_data: Path) -> None:
    assert parse_lines([FLASER, ODOM]).stamps is None


def test_the_public_logs_with_broken_stamps_are_read_whole(shared_data: Path) -> None:
    """Belgioioso (one stamp for the whole log), the Infinite Corridor (negative, then
    wrapped at 32 bits) and the Freiburg campus (zeros): every scan read, in file order, a
    second apart."""
    for name, scans in (
        ("belgioioso", 395),
        ("infinite-corridor", 1941),
        ("freiburg-campus", 2008),
    ):
        log = read_carmen(shared_data / "laser" / f"{name}-corrected.log.gz")
        assert len(log.scans) == scans, name
        assert not {k for k in log.skipped if k.startswith("malformed")}, name
        assert np.array_equal(np.diff(log.scan_times_ns()), np.full(scans - 1, 10**9))
        assert log.stamps is not None and log.stamps.from_order


def test_broken_gzip_is_an_input_error(tmp_path: Path) -> None:
    import gzip

    whole = gzip.compress(("\n".join([FLASER] * 200) + "\n").encode())
    truncated = tmp_path / "truncated.log.gz"
    truncated.write_bytes(whole[: len(whole) // 2])
    corrupt = tmp_path / "corrupt.log.gz"
    corrupt.write_bytes(whole[:20] + bytes(b ^ 0x55 for b in whole[20:200]) + whole[200:])
    for path in (truncated, corrupt, tmp_path):
        with pytest.raises(InputFormatError, match="cannot read CARMEN log"):
            read_carmen(path)


def _reference_path(n: int = 400) -> np.ndarray:
    rng = np.random.default_rng(5)
    poses = [np.zeros(3)]
    for _ in range(n):
        step = np.array([rng.uniform(0.2, 0.8), 0.0, rng.uniform(-0.4, 0.4)])
        poses.append(se2.compose(poses[-1], step))
    return np.array(poses)


def test_synth_odometry_error_model_statistics() -> None:
    ref = _reference_path()
    odo = synthesize_odometry(ref, seed=3)
    step_ref = se2.between(ref[:-1], ref[1:])
    step_odo = se2.between(odo[:-1], odo[1:])
    dist = np.hypot(step_ref[:, 0], step_ref[:, 1])
    scale = np.hypot(step_odo[:, 0], step_odo[:, 1]).sum() / dist.sum()
    drift = se2.wrap(step_odo[:, 2] - step_ref[:, 2]).sum() / dist.sum()
    assert scale == pytest.approx(1.05, abs=0.005)
    assert math.degrees(drift) == pytest.approx(2.0, abs=0.25)
    residual = (
        se2.wrap(step_odo[:, 2] - step_ref[:, 2]) - OdometryErrorModel().drift_rad_per_m * dist
    )
    assert residual.std() > 0  # there is random noise on top of the systematic error
    np.testing.assert_array_equal(odo[0], ref[0])


def test_synth_odometry_is_seeded() -> None:
    ref = _reference_path(50)
    np.testing.assert_array_equal(synthesize_odometry(ref, 7), synthesize_odometry(ref, 7))
    assert not np.array_equal(synthesize_odometry(ref, 7), synthesize_odometry(ref, 8))
    with pytest.raises(ConfigError, match="must not be negative"):
        synthesize_odometry(ref, -1)  # numpy would raise a bare ValueError


@given(st.integers(0, 2**32 - 1))
def test_synth_odometry_without_error_is_the_reference(seed: int) -> None:
    ref = _reference_path(20)
    np.testing.assert_allclose(
        synthesize_odometry(ref, seed, OdometryErrorModel.exact()), ref, atol=1e-9
    )


def _moving_log(path: Path, pose: str) -> Path:
    """Five FLASER lines a second apart, the robot's pose ``pose`` with ``{k}`` the line's
    number, and no ODOM line."""
    lines = [
        FLASER.replace("976052890.244111", f"{100 + k}.5").replace("1.1 2.1 0.5", pose.format(k=k))
        for k in range(5)
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_import_writes_scans_and_odometry(tmp_path: Path) -> None:
    log = _moving_log(tmp_path / "run.log", "{k} 0 0")
    out = tmp_path / "run.mcap"
    with pytest.raises(ConfigError):
        import_carmen(log, out)  # no odometry and none asked for
    counts = import_carmen(log, out, synth_seed=1)
    assert counts["scans"] == 5
    records = list(read_messages(out))
    scans = [r.message for r in records if isinstance(r.message, LaserScan)]
    odom = [r.message for r in records if isinstance(r.message, Odometry)]
    assert [s.t_ns for s in scans] == [(100 + k) * 10**9 + 500_000_000 for k in range(5)]
    assert len(odom) == 5
    assert odom[-1].x_m == pytest.approx(4 * 1.05, abs=0.3)
    assert read_metadata(out)["baromap.carmen"]["odometry"] == "synthesised"


def test_a_failed_import_leaves_nothing_and_an_existing_output_is_refused(
    tmp_path: Path,
) -> None:
    log = _moving_log(tmp_path / "run.log", "{k} 0 0")
    out = tmp_path / "run.mcap"
    with pytest.raises(ConfigError):
        import_carmen(log, out)  # no odometry and none asked for
    assert list(tmp_path.iterdir()) == [log]
    import_carmen(log, out, synth_seed=1)
    assert sorted(tmp_path.iterdir()) == [log, out]
    with pytest.raises(ConfigError, match="exists"):
        import_carmen(log, out, synth_seed=1)


def test_import_records_where_the_times_came_from(tmp_path: Path) -> None:
    log = tmp_path / "broken.log"
    log.write_text("\n".join(_line("FLASER", k, "0") for k in range(5)) + "\n")
    counts = import_carmen(log, tmp_path / "run.mcap", synth_seed=0)
    assert counts["stamps"]["scans"] == 5
    header = read_metadata(tmp_path / "run.mcap")["baromap.carmen"]
    assert header["stamps"] == "scan order" and header["stamps_replaced"] == "5"
    good = _moving_log(tmp_path / "good.log", "{k} 0 0")
    assert import_carmen(good, tmp_path / "good.mcap", synth_seed=0)["stamps"] is None
    assert read_metadata(tmp_path / "good.mcap")["baromap.carmen"]["stamps"] == "logged"


def test_a_raw_log_s_laser_lines_are_its_odometry_when_asked(tmp_path: Path) -> None:
    """A raw log (the pose on its laser lines is the wheels' own) with no ODOM lines: imported
    as it is when asked, never degraded a second time, and refused with both ways out named
    when not asked."""
    log = _moving_log(tmp_path / "raw.log", "{k} 0.5 0.1")
    out = tmp_path / "raw.mcap"
    with pytest.raises(ConfigError, match=r"--odometry-from laser.*--synth-odometry"):
        import_carmen(log, out)
    with pytest.raises(ConfigError, match="one or the other"):
        import_carmen(log, out, synth_seed=0, odometry_from="laser")
    with pytest.raises(ConfigError, match="odometry source"):
        import_carmen(log, out, odometry_from="wheels")
    counts = import_carmen(log, out, odometry_from="laser")
    assert counts["odometry"] == 5
    odom = [r.message for r in read_messages(out) if isinstance(r.message, Odometry)]
    got = [(o.x_m, o.y_m, o.theta_rad) for o in odom]
    assert np.allclose(got, [(k, 0.5, 0.1) for k in range(5)], atol=1e-9)
    assert read_metadata(out)["baromap.carmen"]["odometry"] == "laser lines"


def test_intel_log_parses(shared_data: Path) -> None:
    log = read_carmen(shared_data / "laser" / "intel-corrected-abstime.log.gz")
    assert len(log.scans) == 910
    assert not log.skipped
    assert log.range_limit_m is None  # its 81.83 m code is past the 80 m every FLASER line has
    assert all(len(s.ranges_m) == 180 for s in log.scans)
    times = log.scan_times_ns()
    assert np.all(np.diff(times) > 0)


def test_a_backward_facing_laser_mounting_is_read_whole() -> None:
    """Turns of the laser against the robot near 180 deg print as +-180: read about their mean."""
    rng = np.random.default_rng(4)
    lines = []
    for k in range(40):
        robot = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-3, 3)])
        mount = np.array([-0.25, 0.02, math.pi + rng.normal(0.0, 1e-3)])
        laser = se2.compose(robot, mount)
        poses = " ".join(f"{v:.6f}" for v in (*laser, *robot))
        lines.append(f"FLASER 3 1.0 1.0 1.0 {poses} {10.0 + k:.6f} host {10.0 + k:.6f}")
    x, y, turn = laser_offset(parse_lines(lines))
    assert (x, y) == pytest.approx((-0.25, 0.02), abs=1e-5)
    assert abs(math.remainder(turn - math.pi, math.tau)) < 1e-3


def _mounted_lines(mount: tuple[float, float, float], declared: str) -> list[str]:
    """A log whose laser lines carry ``mount`` and whose PARAM lines say ``declared``."""
    rng = np.random.default_rng(7)
    lines = [f"PARAM robot_frontlaser_offset {declared} host 0"]
    for k in range(20):
        robot = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-3, 3)])
        laser = se2.compose(robot, np.array(mount))
        poses = " ".join(f"{v:.6f}" for v in (*laser, *robot))
        lines.append(f"FLASER 3 1.0 1.0 1.0 {poses} {10.0 + k:.6f} host {10.0 + k:.6f}")
    return lines


def test_a_mount_the_lines_carry_as_declared_says_nothing() -> None:
    """A raw log prints the laser's pose as the robot's moved by the mount its PARAM declares."""
    from structlog.testing import capture_logs

    carmen = parse_lines(_mounted_lines((0.2, 0.0, 0.0), "0.2"))
    with capture_logs() as logs:
        assert not check_mount(carmen, laser_offset(carmen), "raw.log")
    assert declared_mount(carmen) == (0.2, 0.0, 0.0)
    assert not logs


def test_a_declared_mount_the_lines_do_not_show_is_said(shared_data: Path) -> None:
    """Freiburg 079's corrected log declares its laser 4 cm behind the robot's centre and
    prints one pose for both: the trajectory is then the laser's, and the user is told."""
    from structlog.testing import capture_logs

    carmen = read_carmen(shared_data / "laser" / "freiburg-079-corrected.log.gz")
    assert declared_mount(carmen) == (-0.04, 0.0, 0.0)
    offset = laser_offset(carmen)
    assert offset == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)
    with capture_logs() as logs:
        assert check_mount(carmen, offset, "fr079")
    assert [e["declared"] for e in logs] == ["-0.040 0.000 0.000"]
    assert logs[0]["lines"] == "0.000 0.000 0.000"
    assert logs[0]["log_level"] == "warning"


def test_a_mount_param_that_is_no_number_is_no_mount() -> None:
    carmen = parse_lines(_mounted_lines((0.0, 0.0, 0.0), "front"))
    assert declared_mount(carmen) is None
    assert not check_mount(carmen, laser_offset(carmen), "odd.log")


def test_import_records_the_no_return_code_it_found(tmp_path: Path) -> None:
    log = tmp_path / "short.log"
    log.write_text("\n".join(_short_range_log(8.183, 10)) + "\n")
    out = tmp_path / "run.mcap"
    counts = import_carmen(log, out, synth_seed=0)
    assert counts["range_limit_m"] == pytest.approx(8.178)
    assert read_metadata(out)["baromap.carmen"]["range_limit_m"] == "8.178"
    scans = [r.message for r in read_messages(out) if isinstance(r.message, LaserScan)]
    assert all(s.range_max_m == pytest.approx(8.178) for s in scans)
