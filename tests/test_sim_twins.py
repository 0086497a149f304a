"""Twins on pseudo-terminals: real-protocol clients written from protocols.md work unchanged."""

from __future__ import annotations

import contextlib
import itertools
import json
import math
import os
import termios
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import serial

from baromap.cli.main import main
from baromap.odometry.integrator import OdometryIntegrator
from baromap.protocols import baro, lms200, p2os
from baromap.protocols.framing import BadFrame
from baromap.protocols.robot_models import P3AT_SH
from baromap.sim.scenario import make_scenario
from baromap.sim.twins import BaroTwin, Lms200Twin, P2osTwin, SimClock
from baromap.sim.twins.p2os import Session

SCENARIO = make_scenario(2, floors=3, minutes=5.0)


@pytest.fixture
def clock() -> SimClock:
    return SimClock(SCENARIO, speed=1.0)


def read_for(port: serial.Serial, seconds: float) -> bytes:
    out = bytearray()
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        out += port.read(max(1, port.in_waiting))
    return bytes(out)


def join_stream(port: serial.Serial, decoder: baro.Decoder) -> tuple[list[object], int]:
    """Read a barometer stream that was flowing before the port opened, up to its first whole
    frame: the frames so far and what the join cost. Opening a port flushes its input, so the
    frame the board was writing then can arrive cut (a COBS error and its tail as garbage,
    counted and resynced); after the first frame, nothing may be bad."""
    frames: list[object] = []
    deadline = time.monotonic() + 5.0
    while not frames and time.monotonic() < deadline:
        frames += decoder.feed(port.read(max(1, port.in_waiting)))
    return frames, sum(decoder.stats.bad.values())


def read_count(port: serial.Serial, decoder, kind: type, count: int, seconds: float = 10.0) -> list:  # type: ignore[no-untyped-def,type-arg]
    """Every message until ``count`` of ``kind`` arrived (a loaded machine may take a while)."""
    seen: list = []  # type: ignore[type-arg]
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and sum(isinstance(m, kind) for m in seen) < count:
        seen += decoder.feed(port.read(max(1, port.in_waiting)))
    return seen


def read_until(port: serial.Serial, decoder, want, seconds: float = 2.0) -> list:  # type: ignore[no-untyped-def]
    """Feed bytes until a message satisfying ``want`` arrives; returns every message seen."""
    seen: list = []  # type: ignore[type-arg]
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        data = port.read(max(1, port.in_waiting))
        if data:
            seen += decoder.feed(data)
            if any(want(m) for m in seen):
                return seen
    raise AssertionError(f"timed out; got {seen[-5:]}")


@pytest.fixture
def lms(clock: SimClock, tmp_path: Path) -> Iterator[Lms200Twin]:
    with Lms200Twin(clock, tmp_path / "lms200") as twin:
        yield twin  # type: ignore[misc]


def lms_init(port: serial.Serial, decoder: lms200.Decoder) -> None:
    """protocols.md's init sequence, as a driver does it."""

    def telegram(cmd: int):  # type: ignore[no-untyped-def]
        return lambda m: isinstance(m, lms200.Telegram) and m.command == cmd

    # 1. find the baud: status request at 9600
    port.write(lms200.status_request())
    seen = read_until(port, decoder, telegram(lms200.Reply.STATUS))
    assert isinstance(seen[0], lms200.Ack)
    # 2. switch to 38400; on the A0 reply change the host's baud and wait 250 ms
    port.write(lms200.switch_baud(38400))
    seen = read_until(port, decoder, telegram(lms200.Reply.MODE))
    assert lms200.mode_result(seen[-1]) == 0
    port.baudrate = 38400
    time.sleep(0.25)
    # 3. stop streaming, read type and status
    port.write(lms200.stop_continuous())
    read_until(port, decoder, telegram(lms200.Reply.MODE))
    port.write(lms200.type_request())
    seen = read_until(port, decoder, telegram(lms200.Reply.TYPE))
    assert lms200.parse_type_reply(seen[-1]).startswith("LMS200")
    # 4. installation mode and mm units
    port.write(lms200.installation_mode())
    seen = read_until(port, decoder, telegram(lms200.Reply.MODE))
    assert lms200.mode_result(seen[-1]) == 0
    port.write(lms200.set_config(lms200.LmsConfig(units=1)))
    seen = read_until(port, decoder, telegram(lms200.Reply.WRITE_CONFIG))
    assert lms200.parse_config_write_reply(seen[-1])[0]
    # 5. variant 180 deg / 1 deg
    port.write(lms200.set_variant(180, 100))
    seen = read_until(port, decoder, telegram(lms200.Reply.VARIANT))
    assert lms200.parse_variant_reply(seen[-1]).accepted
    # 6. continuous output
    port.write(lms200.start_continuous())
    read_until(port, decoder, telegram(lms200.Reply.MODE))


def test_lms200_init_sequence_and_clean_stream(lms: Lms200Twin) -> None:
    decoder = lms200.Decoder()
    with serial.serial_for_url(lms.path, baudrate=9600, timeout=0.05) as port:
        lms_init(port, decoder)
        messages = read_count(port, decoder, lms200.ScanTelegram, 3)
        port.write(lms200.stop_continuous())
    scans = [m for m in messages if isinstance(m, lms200.ScanTelegram)]
    assert decoder.stats.bad == {}
    assert not [m for m in messages if isinstance(m, BadFrame)]
    assert len(scans) >= 3
    # Paced like the real line: a 372-byte telegram takes 97 ms at 38400 baud, so n scans span
    # at least n - 1 telegram times (less the 50 ms a line may catch up; load only adds).
    taken = [t.t_mono_ns / 1e9 for t in lms.truth.records()]
    assert taken[-1] - taken[0] >= (len(taken) - 1) * 372 * 10 / 38400 - 0.05
    scan = scans[-1].to_laser_scan(0)
    assert scan.beam_count == 181
    assert scan.range_max_m == pytest.approx(8.19)
    assert scan.valid().sum() > 100


def test_lms200_answers_nak_invalid_and_refuses_bad_variants(lms: Lms200Twin) -> None:
    decoder = lms200.Decoder()
    with serial.serial_for_url(lms.path, baudrate=9600, timeout=0.05) as port:
        bad = bytearray(lms200.status_request())
        bad[-1] ^= 0xFF
        port.write(bytes(bad))
        read_until(port, decoder, lambda m: isinstance(m, lms200.Nak))
        port.write(lms200.encode_telegram(0x55))
        seen = read_until(port, decoder, lambda m: isinstance(m, lms200.Telegram))
        assert seen[-1].command == lms200.Reply.INVALID_COMMAND
        port.write(lms200.encode_telegram(lms200.Command.VARIANT, bytes([180, 0, 25, 0])))
        seen = read_until(port, decoder, lambda m: isinstance(m, lms200.Telegram))
        reply = lms200.parse_variant_reply(seen[-1])
        assert not reply.accepted
        assert (reply.angle_deg, reply.resolution_cdeg) == (180, 100)


@pytest.mark.slow
def test_lms200_faults_show_up_as_counted_bad_frames(lms: Lms200Twin) -> None:
    decoder = lms200.Decoder()
    with serial.serial_for_url(lms.path, baudrate=9600, timeout=0.05) as port:
        lms_init(port, decoder)
        read_for(port, 0.3)
        lms.inject_garbage(b"\x02\x80\xff\x00garbage")
        lms.drop_bytes(50)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and sum(decoder.stats.bad.values()) < 2:
            decoder.feed(port.read(max(1, port.in_waiting)))
        assert sum(decoder.stats.bad.values()) >= 2
        frames = decoder.stats.frames
        lms.stall(3.0)
        time.sleep(0.05)
        quiet = read_for(port, 0.4)
        assert len(quiet) < 400  # at most the telegram that was on the line
        read_count(port, decoder, lms200.ScanTelegram, 1)
        assert decoder.stats.frames > frames  # streaming resumed after the stall


@pytest.fixture
def base(clock: SimClock, tmp_path: Path) -> Iterator[P2osTwin]:
    with P2osTwin(clock, tmp_path / "p3at") as twin:
        yield twin  # type: ignore[misc]


def p2os_connect(port: serial.Serial, decoder: p2os.Decoder) -> p2os.Sync2Info:
    """The SYNC handshake as protocols.md describes it (CLOSE and retry if SIPs arrive)."""
    for _attempt in range(3):
        ok = True
        info = None
        for step in range(3):
            port.write(p2os.sync(step))
            seen = read_until(
                port,
                decoder,
                lambda m: isinstance(m, (p2os.SyncEcho, p2os.Sync2Info, p2os.StandardSip)),
            )
            last = [m for m in seen if not isinstance(m, BadFrame)][-1]
            if isinstance(last, p2os.StandardSip):
                port.write(p2os.close_controller())
                time.sleep(0.3)
                port.reset_input_buffer()
                ok = False
                break
            info = last if isinstance(last, p2os.Sync2Info) else None
        if ok and info is not None:
            port.write(p2os.open_controller())
            port.write(p2os.pulse())
            return info
    raise AssertionError("no handshake")


def test_p2os_handshake_sips_and_odometry(base: P2osTwin) -> None:
    decoder = p2os.Decoder()
    with serial.serial_for_url(base.path, baudrate=9600, timeout=0.05) as port:
        info = p2os_connect(port, decoder)
        assert (info.robot_class, info.subclass) == ("Pioneer", "p3at-sh")
        port.write(p2os.config_request())
        port.write(p2os.enable_motors(True))
        messages: list[object] = []
        while sum(isinstance(m, p2os.StandardSip) for m in messages) < 5:
            messages += read_count(port, decoder, p2os.StandardSip, 1, 2.0)
            port.write(p2os.pulse())
        port.write(p2os.stop())
        port.write(p2os.close_controller())
    sips = [m for m in messages if isinstance(m, p2os.StandardSip)]
    assert decoder.stats.bad == {}
    assert len(sips) >= 5
    assert sips[-1].motors_enabled
    # The SIP carries what ARCOS appends after the sonars (ARIA reads it when present).
    assert sips[-1].rot_vel is not None and sips[-1].fault_flags == 0 and sips[-1].extra == b""
    # SIPs every 100 ms of the twin's clock, never faster: n SIPs span n - 1 cycles at least
    # (less how late the first one was; load only adds).
    poses = [t.t_mono_ns / 1e9 for t in base.truth.records()]
    assert poses[-1] - poses[0] >= (len(poses) - 1) * 0.1 - 0.05
    config = next(m for m in messages if isinstance(m, p2os.ConfigPacket))
    assert config.watchdog_ms == 2000
    # The whole CONFIG packet: every field ARIA reads, nothing left over.
    assert set(config.as_dict()) == p2os.CONFIG_FIELD_NAMES and config.extra == b""
    assert config.get("subtype") == "p3at-sh"
    integrator = OdometryIntegrator(P3AT_SH, origin_at_start=True)
    poses = [integrator.update(s, i) for i, s in enumerate(sips)]
    # The route drives at most 0.6 m/s: no step between 100 ms SIPs is longer than 6 cm (plus
    # slip), whatever the 15-bit counters did meanwhile.
    steps = [math.hypot(b.x_m - a.x_m, b.y_m - a.y_m) for a, b in itertools.pairwise(poses)]
    assert max(steps) < 0.1


def test_p2os_client_finds_the_robot_still_open(base: P2osTwin) -> None:
    decoder = p2os.Decoder()
    with serial.serial_for_url(base.path, baudrate=9600, timeout=0.05) as port:
        p2os_connect(port, decoder)
    # The first client vanished without CLOSE: SIPs keep coming, the next client must cope.
    with serial.serial_for_url(base.path, baudrate=9600, timeout=0.05) as port:
        info = p2os_connect(port, p2os.Decoder())
        assert info.name == "baromap-sim"
        port.write(p2os.close_controller())


def test_p2os_watchdog_stops_the_robot(clock: SimClock, base: P2osTwin) -> None:
    decoder = p2os.Decoder()
    with serial.serial_for_url(base.path, baudrate=9600, timeout=0.05) as port:
        p2os_connect(port, decoder)
        read_for(port, 2.4)
        assert clock.halted
        assert base.watchdog_trips == 1
        frozen = clock.robot_time()
        time.sleep(0.2)
        assert clock.robot_time() == frozen
        port.write(p2os.pulse())
        time.sleep(0.2)
        assert not clock.halted
        assert clock.robot_time() > frozen
        port.write(p2os.close_controller())


def test_p2os_host_with_motors_enabled_drives_the_odometry_and_the_route_waits(
    clock: SimClock, base: P2osTwin
) -> None:
    """VEL with the motors enabled: the odometry counts the commanded 200 mm/s, the route
    stands still meanwhile; STOP zeroes the wheels; ENABLE 0 gives the robot back to the
    route. Without ENABLE, VEL moves nothing."""
    decoder = p2os.Decoder()
    with serial.serial_for_url(base.path, baudrate=9600, timeout=0.05) as port:
        p2os_connect(port, decoder)
        port.write(p2os.vel(200))  # motors off: ignored
        read_count(port, decoder, p2os.StandardSip, 3)
        assert not base.host_driving
        port.write(p2os.enable_motors(True))
        port.write(p2os.vel(0))  # the host takes the robot
        read_count(port, decoder, p2os.StandardSip, 2)
        route_s = clock.robot_time()
        start = base.odometry.x_m, base.odometry.y_m
        port.write(p2os.vel(200))
        time.sleep(1.0)
        port.write(p2os.stop())
        read_for(port, 0.3)  # what was sent while driving
        sips = read_count(port, decoder, p2os.StandardSip, 2)
        driven = math.hypot(base.odometry.x_m - start[0], base.odometry.y_m - start[1])
        assert clock.robot_time() == route_s  # the route waited
        port.write(p2os.enable_motors(False))
        read_count(port, decoder, p2os.StandardSip, 3)
        assert not base.host_driving
        port.write(p2os.close_controller())
    assert driven == pytest.approx(0.2, rel=0.15)  # 1 s at 200 mm/s, the error model's few %
    assert sips[-1].left_vel == sips[-1].right_vel == 0


@pytest.fixture
def board(clock: SimClock, tmp_path: Path) -> Iterator[BaroTwin]:
    with BaroTwin(clock, tmp_path / "baro") as twin:
        yield twin  # type: ignore[misc]


def test_baro_frames_are_clean_and_match_the_model(board: BaroTwin, clock: SimClock) -> None:
    decoder = baro.Decoder()
    with serial.serial_for_url(board.path, baudrate=115200, timeout=0.05) as port:
        port.write(baro.identify(seq=7))
        frames = read_count(port, decoder, baro.StatusFrame, 1)
        frames += read_count(port, decoder, baro.SampleFrame, 5)
        port.write(baro.set_rate(99, seq=8))
        frames += decoder.feed(read_for(port, 0.2))
    assert decoder.stats.bad == {}
    acks = [f for f in frames if isinstance(f, baro.AckFrame)]
    assert (acks[0].command, acks[0].command_seq, acks[0].result) == (baro.FrameType.IDENTIFY, 7, 0)
    assert acks[-1].result == baro.AckResult.BAD_VALUE
    hello = next(f for f in frames if isinstance(f, baro.HelloFrame))
    assert (hello.rate_hz, hello.osrs_p, hello.iir_filter) == (25, 16, 16)
    samples = [f for f in frames if isinstance(f, baro.SampleFrame)]
    assert len(samples) >= 5
    assert any(isinstance(f, baro.StatusFrame) for f in frames)
    # Readings agree with the scenario's air pressure within the sensor's offset budget.
    truth = SCENARIO.truth(np.array([clock.robot_time()]))
    expected = SCENARIO.true_pressure_pa(np.array([clock.now()]), truth)[0]
    assert abs(samples[-1].pressure_pa - expected) < 150
    # Exactly: the air pressure plus this chip's offset and temperature error, within noise.
    chip = board.sensor
    die = samples[-1].temperature_c
    modelled = expected + chip.offset_pa + 1.5 * (die - 25.0)
    assert abs(samples[-1].pressure_pa - modelled) < 2.0
    # Each frame type counts on its own from 0 after power-up (PROTOCOL.md), so the SAMPLE
    # numbers run on without a gap across the STATUS, ACK and HELLO frames between them.
    for cls in (baro.SampleFrame, baro.StatusFrame, baro.AckFrame, baro.HelloFrame):
        seqs = [f.seq for f in frames if isinstance(f, cls)]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), cls.__name__
    assert [f.seq for f in acks] == [0, 1]
    hellos = [f for f in frames if isinstance(f, baro.HelloFrame)]
    assert hellos[-1].seq == 1  # IDENTIFY's; the power-up HELLO was number 0


def test_baro_answers_unknown_and_short_commands_like_the_firmware(board: BaroTwin) -> None:
    def raw(frame_type: int, seq: int, payload: bytes) -> bytes:
        body = baro.HEADER.pack(baro.PROTOCOL_VERSION, frame_type, seq, 0) + payload
        return b"\x00" + baro.cobs_encode(body + baro.CRC.pack(baro.crc16(body))) + b"\x00"

    decoder = baro.Decoder()
    with serial.serial_for_url(board.path, baudrate=115200, timeout=0.05) as port:
        port.write(raw(0x90, 11, b"\x01") + raw(baro.FrameType.SET_RATE, 12, b""))
        port.write(raw(baro.FrameType.SAMPLE, 13, bytes(6)) + b"\x55" * 80 + b"\x00")
        acks = read_until(
            port, decoder, lambda f: isinstance(f, baro.AckFrame) and f.command_seq == 13
        )
        # The first STATUS after the last ACK counts all three frames and the oversized run.
        frames = acks + read_until(port, decoder, lambda f: isinstance(f, baro.StatusFrame))
    last_ack = max(i for i, f in enumerate(frames) if isinstance(f, baro.AckFrame))
    status = next(f for f in frames[last_ack:] if isinstance(f, baro.StatusFrame))
    results = {(f.command, f.command_seq): f.result for f in acks if isinstance(f, baro.AckFrame)}
    assert results == {
        (0x90, 11): baro.AckResult.UNKNOWN_COMMAND,
        (baro.FrameType.SET_RATE, 12): baro.AckResult.BAD_LENGTH,
        (baro.FrameType.SAMPLE, 13): baro.AckResult.UNKNOWN_COMMAND,
    }
    assert (status.rx_frames, status.rx_overflows) == (3, 1)


def test_baro_faults_unplug_and_replug(board: BaroTwin) -> None:
    link = Path(board.path)
    decoder = baro.Decoder()
    with serial.serial_for_url(board.path, baudrate=115200, timeout=0.05) as port:
        read_for(port, 0.2)
        board.inject_garbage(b"\x13\x37\xbe\xef\x00")
        board.drop_bytes(3)
        decoder.feed(read_for(port, 0.5))
    assert sum(decoder.stats.bad.values()) >= 2
    # A port the host held open through the unplug fails, as a USB adapter's does, and stays
    # failed after the replug: the device is back on a fresh pty that the host must reopen.
    with serial.serial_for_url(str(link), baudrate=115200, timeout=0.05) as held:
        read_for(held, 0.1)
        board.unplug()
        assert not link.exists()
        with pytest.raises((serial.SerialException, OSError)):
            read_for(held, 0.3)
        board.replug()
        assert link.is_symlink()
        with pytest.raises((serial.SerialException, OSError)):
            read_for(held, 0.3)
    decoder = baro.Decoder()
    with serial.serial_for_url(str(link), baudrate=115200, timeout=0.05) as port:
        frames, joined = join_stream(port, decoder)
        port.write(baro.identify())
        frames += decoder.feed(read_for(port, 0.6))
    assert any(isinstance(f, baro.HelloFrame) for f in frames)
    assert any(isinstance(f, baro.SampleFrame) for f in frames)
    assert joined <= 2
    assert sum(decoder.stats.bad.values()) == joined


def test_faster_than_real_time(tmp_path: Path) -> None:
    fast = SimClock(SCENARIO, speed=8.0)
    with BaroTwin(fast) as twin:
        decoder = baro.Decoder()
        with serial.serial_for_url(twin.path, baudrate=115200, timeout=0.05) as port:
            frames, joined = join_stream(port, decoder)
            deadline = time.monotonic() + 10.0  # a loaded machine may be slow to give 10
            while time.monotonic() < deadline and (
                sum(isinstance(f, baro.SampleFrame) for f in frames) < 10
            ):
                frames += decoder.feed(port.read(max(1, port.in_waiting)))
    samples = [f for f in frames if isinstance(f, baro.SampleFrame)]
    assert len(samples) >= 10
    assert joined <= 2
    assert sum(decoder.stats.bad.values()) == joined
    # The board's clock and the simulated time run 8x the host's: compare the firmware's
    # microsecond stamps of two samples with the true instants they were measured at.
    first, last = samples[0], samples[-1]
    wall_s = (twin.truth.by_seq(last.seq).t_mono_ns - twin.truth.by_seq(first.seq).t_mono_ns) / 1e9
    board_s = (last.time_us - first.time_us) / 1e6
    assert board_s / wall_s == pytest.approx(8.0, rel=0.02)


def test_cli_prints_paths_as_json(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    args = ["sim", "--json", "--duration", "0.3", "--floors", "3", "--minutes", "5"]
    code = main([*args, "--link-dir", str(tmp_path)])
    assert code == 0
    paths = json.loads(capsys.readouterr().out)
    assert set(paths) == {"lms200", "p3at", "baro"}
    assert paths["baro"] == str(tmp_path / "baro")
    assert not (tmp_path / "baro").exists()  # links go when the devices stop


def test_a_link_that_cannot_be_made_is_a_clear_error_and_leaks_no_pty(tmp_path: Path) -> None:
    from baromap.errors import ConfigError
    from baromap.sim.twins import SimDevices

    (tmp_path / "baro").mkdir()  # the third twin's link is taken by a directory
    (tmp_path / "baro" / "x").touch()
    with pytest.raises(ConfigError, match="baro"):
        SimDevices(floors=3, minutes=5.0, link_dir=tmp_path)
    # (the autouse leak check fails this test if the first two twins' ptys stay open)
    assert not (tmp_path / "lms200").exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--speed", "0"], "speed must be positive"),
        (["--link-dir", "/proc/no-such-dir"], "cannot link"),
    ],
)
def test_cli_refuses_bad_arguments_in_one_line(
    args: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["sim", "--duration", "0.1", "--floors", "3", "--minutes", "5", *args])
    assert code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_output_a_line_cannot_carry_is_dropped_whole_not_queued_forever() -> None:
    from baromap.sim.twins.pty_port import QUEUE_S, PtyPort

    port = PtyPort(9600)
    try:
        port.send(b"x" * 2000)  # one message longer than the queue still goes out whole
        assert port.pending == 2000
        port.send(b"y" * 10)
        assert (port.pending, port.bytes_dropped) == (2000, 10)
        port.stall(0.0)  # empties the queue
        for _ in range(1000):
            port.send(b"z" * 31)  # a SIP a thousand times faster than 9600 baud carries
        assert port.pending <= 9600 / 10 * QUEUE_S
        assert port.pending + port.bytes_dropped == 10 + 31_000
    finally:
        port.close()


def test_a_twin_held_up_delivers_its_backlog_at_the_line_rate_not_slower() -> None:
    """A device's UART keeps sending while its twin's thread waits for a core: after a hold-up
    of 0.4 s, a pump writes every byte whose line time is over. A twin that credited only the
    last few tens of milliseconds turned a loaded test machine into a line running at a
    fraction of its baud rate, and a laser that streams into a silence."""
    from baromap.sim.twins.pty_port import PtyPort

    port = PtyPort(38400)
    try:
        assert port.master is not None
        scan = bytes(range(256)) * 3  # about one 0.5-degree scan: 0.2 s at 38400 baud
        assert port.send(scan)
        time.sleep(0.4)  # the twin's thread held up: the whole scan is on the line by now
        port.pump()
        assert port.pending == 0
        slave = os.open(port.slave_path, os.O_RDONLY | os.O_NONBLOCK)
        try:
            assert os.read(slave, 4096) == scan
        finally:
            os.close(slave)
    finally:
        port.close()


def test_a_backlog_larger_than_the_ptys_buffer_waits_for_a_host_that_reads_late() -> None:
    """A twin held up at 500 kbaud owes the host more than a pty holds (a few kilobytes). A
    host that reads, only late, must get every byte, as from a real port's kernel buffer;
    bytes are lost only to a host that has not read for half a second."""
    from baromap.sim.twins.pty_port import PtyPort

    port = PtyPort(500_000)
    slave = os.open(port.slave_path, os.O_RDONLY | os.O_NONBLOCK)
    try:
        attrs = termios.tcgetattr(slave)
        attrs[4] = attrs[5] = termios.B500000  # the host at the twin's speed
        termios.tcsetattr(slave, termios.TCSANOW, attrs)
        sent = bytes(range(256)) * 80  # 20 kB: 0.4 s of line time
        assert port.send(sent)
        time.sleep(0.41)  # all of it due, none of it read
        port.pump()  # fills the pty's buffer
        got = bytearray()
        deadline = time.monotonic() + 2.0
        while port.pending and time.monotonic() < deadline:
            port.pump()
            with contextlib.suppress(BlockingIOError):
                got += os.read(slave, 65536)
        while len(got) < len(sent) and time.monotonic() < deadline:
            with contextlib.suppress(BlockingIOError):
                got += os.read(slave, 65536)
        assert (len(got), port.bytes_unread) == (len(sent), 0)
        assert bytes(got) == sent

        more = sent * 8  # 160 kB: more than a pty holds (64 kB at most), 3.2 s of line
        assert port.send(more)
        deadline = time.monotonic() + 8.0
        while port.pending and time.monotonic() < deadline:  # a host that never reads
            port.pump()
            time.sleep(0.01)
        assert port.pending == 0 and port.bytes_unread > 0
    finally:
        os.close(slave)
        port.close()


def test_p2os_watchdog_judges_the_host_in_wall_time(tmp_path: Path) -> None:
    """Sped up 8x, a host pulsing every 0.5 s (wall) keeps the robot driving."""
    with P2osTwin(SimClock(SCENARIO, speed=8.0), tmp_path / "p3at") as fast:
        with serial.serial_for_url(fast.path, baudrate=9600, timeout=0.05) as port:
            p2os_connect(port, p2os.Decoder())
            for _ in range(4):
                read_for(port, 0.5)
                port.write(p2os.pulse())
            port.write(p2os.close_controller())
        assert fast.watchdog_trips == 0  # type: ignore[attr-defined]


def test_a_twin_says_at_stop_how_late_it_put_its_messages_on_the_line(tmp_path: Path) -> None:
    from structlog.testing import capture_logs

    twin = BaroTwin(SimClock(SCENARIO), tmp_path / "baro")
    twin.port.lateness.extend([0.001] * 97 + [0.025, 0.030, 0.350])  # seconds, as measured
    with capture_logs() as logs:
        twin.stop()
    (line,) = [e for e in logs if e["event"] == "twin stopped"]
    assert line["twin"] == "baro"
    assert line["messages"] == 100
    assert line["late_over_20ms"] == 3
    assert line["late_max_ms"] == 350.0
    assert line["late_p99_ms"] == 30.0  # the 99th of 100, counted from the least


def test_a_sip_holds_the_pose_of_the_instant_its_truth_records(
    base: P2osTwin, monkeypatch: pytest.MonkeyPatch
) -> None:
    # every reading of the clock a second later than the one before: a thread held up between
    # two readings, as on a loaded machine
    readings = itertools.count(50.0)  # the robot drives from 50 s on
    monkeypatch.setattr(base.clock, "robot_time", lambda: float(next(readings)))
    base._stop.set()  # the twin's own loop stays out of the way: this test ticks it
    base.session = Session.OPEN
    base._last_heard = time.monotonic()
    base._next_sip = 0.0
    before = base.truth.count
    base.tick()
    assert base.truth.count == before + 1
    recorded = base.truth.records()[-1].t_sim_s
    pose = SCENARIO.truth(np.array([recorded]))
    assert base._prev == pytest.approx((pose.x[0], pose.y[0], pose.theta[0]))
