"""Firmware in the loop: the real ELF in simavr (or a real board with --baro-port), read by the
Python codec. Timing is judged on the board's own clock, never the host's."""

from __future__ import annotations

import itertools
import random
import statistics
from collections.abc import Callable
from pathlib import Path

import pytest
from firmware_board import (
    BoardLink,
    SimulatedBoard,
    TrajectoryRow,
    frames_of,
    interpolate,
)

from baromap.protocols import baro

# The boards take the simulator harness through ``request.getfixturevalue`` (a real board needs
# none), so the suite's grouping cannot see it: named here, one worker builds it once.
pytestmark = [pytest.mark.firmware, pytest.mark.xdist_group("shared:tests/firmware")]

SimBoardFactory = Callable[..., SimulatedBoard]
PA_PER_M = 12.0
STOREY_M = 3.0


def assert_contiguous(samples: list[baro.SampleFrame]) -> None:
    gaps = [(a.seq, b.seq) for a, b in itertools.pairwise(samples) if baro.seq_gap(a.seq, b.seq)]
    assert not gaps, f"sequence gaps: {gaps[:10]}"


def mean_interval_us(samples: list[baro.SampleFrame]) -> float:
    steps = [baro.time_delta_us(a.time_us, b.time_us) for a, b in itertools.pairwise(samples)]
    return statistics.fmean(steps)


def status_after(link: BoardLink) -> baro.StatusFrame:
    """The next STATUS frame (they come every second of board time)."""
    return link.wait_type(baro.StatusFrame, device_s=2.5)


# --- any board ------------------------------------------------------------------------------


def test_identify_is_acknowledged_and_answered_with_hello(board: BoardLink) -> None:
    seq = board.next_seq()
    ack = board.command(baro.IdentifyCommand(seq, 0))
    assert (ack.command, ack.command_seq, ack.result) == (baro.FrameType.IDENTIFY, seq, 0)
    hello = board.wait_type(baro.HelloFrame)
    # The HELLO comes right after its ACK, before anything else the board sends.
    after_ack = board.frames[board.frames.index(ack) + 1 :]
    assert after_ack and after_ack[0] == hello
    assert hello.protocol_minor == 0
    assert hello.firmware_version == "1.0.0"
    assert hello.sensor in (baro.SensorModel.BMP280, baro.SensorModel.BME280)
    assert hello.i2c_address in (0x76, 0x77)
    assert (hello.rate_hz, hello.osrs_p, hello.osrs_t, hello.iir_filter) == (25, 16, 2, 16)
    if board.simulated:
        assert (hello.chip_id, hello.i2c_address) == (0x58, 0x76)


def test_sequence_numbers_have_no_gaps_at_25_and_50_hz(board: BoardLink) -> None:
    board.wait_type(baro.SampleFrame)
    at_25 = frames_of(board.run_for(20.0), baro.SampleFrame)
    assert_contiguous(at_25)
    assert len(at_25) >= 20 * 25 - 2
    assert mean_interval_us(at_25) == pytest.approx(40_000, rel=0.01)

    ack = board.set_rate(50)
    assert ack.result == baro.AckResult.OK
    board.run_for(0.2)  # let the samples already on their way go by
    at_50 = frames_of(board.run_for(20.0), baro.SampleFrame)
    assert_contiguous(at_50)
    assert len(at_50) >= 20 * 50 - 2
    assert mean_interval_us(at_50) == pytest.approx(20_000, rel=0.01)
    # And across the change of rate: not one sample lost.
    assert_contiguous(frames_of(board.frames, baro.SampleFrame))
    print(f"25 Hz: {len(at_25)} samples, 50 Hz: {len(at_50)} samples, no gaps")


@pytest.mark.parametrize("rate_hz", [1, 10, 50])
def test_set_rate_takes_effect(board: BoardLink, rate_hz: int) -> None:
    ack = board.set_rate(rate_hz)
    assert ack.result == baro.AckResult.OK
    board.run_for(1.2)
    samples = frames_of(board.run_for(max(3.0, 6.0 / rate_hz)), baro.SampleFrame)
    assert len(samples) >= 3
    assert mean_interval_us(samples) == pytest.approx(1e6 / rate_hz, rel=0.02)
    assert board.identify().rate_hz == rate_hz


@pytest.mark.parametrize("rate_hz", [0, 51, 255])
def test_out_of_range_rate_is_refused_and_changes_nothing(board: BoardLink, rate_hz: int) -> None:
    ack = board.set_rate(rate_hz)
    assert ack.result == baro.AckResult.BAD_VALUE
    assert board.identify().rate_hz == 25


def test_set_oversampling_is_acknowledged_and_applied(board: BoardLink) -> None:
    ack = board.command(baro.SetOversamplingCommand(board.next_seq(), 0, 4, 1, 0))
    assert ack.result == baro.AckResult.OK
    hello = board.identify()
    assert (hello.osrs_p, hello.osrs_t, hello.iir_filter) == (4, 1, 0)
    samples = frames_of(board.run_for(2.0), baro.SampleFrame)
    assert len(samples) >= 45  # the stream goes on through the reconfiguration
    bad = board.command(baro.SetOversamplingCommand(board.next_seq(), 0, 3, 1, 0))
    assert bad.result == baro.AckResult.BAD_VALUE
    assert board.identify().osrs_p == 4


def test_unknown_commands_and_short_payloads_are_answered(board: BoardLink) -> None:
    def raw(frame_type: int, seq: int, payload: bytes) -> bytes:
        body = baro.HEADER.pack(baro.PROTOCOL_VERSION, frame_type, seq, 0) + payload
        return b"\x00" + baro.cobs_encode(body + baro.CRC.pack(baro.crc16(body))) + b"\x00"

    board.send(raw(0x90, 4001, b"\x01"))
    assert board.wait_ack(0x90, 4001).result == baro.AckResult.UNKNOWN_COMMAND
    board.send(raw(baro.FrameType.SAMPLE, 4002, bytes(6)))  # a device frame sent to the device
    assert board.wait_ack(baro.FrameType.SAMPLE, 4002).result == baro.AckResult.UNKNOWN_COMMAND
    board.send(raw(baro.FrameType.SET_RATE, 4003, b""))
    assert board.wait_ack(baro.FrameType.SET_RATE, 4003).result == baro.AckResult.BAD_LENGTH


def test_random_bytes_never_stop_the_stream_and_are_counted(board: BoardLink) -> None:
    board.wait_type(baro.SampleFrame)
    before = status_after(board)
    rng = random.Random(3)
    sent = 0
    for _ in range(40):
        chunk = rng.randbytes(rng.randrange(20, 200))
        if rng.random() < 0.3:
            chunk = chunk.replace(b"\x00", b"\x01")  # long runs without a delimiter too
        board.send(chunk)
        sent += len(chunk)
        board.run_for(0.05)
    board.send(b"\x00")
    sent += 1
    # The board still understands a command after the noise...
    hello = board.identify()
    assert hello.sensor != baro.SensorModel.NONE
    after = status_after(board)
    # ...never stopped streaming...
    assert_contiguous(frames_of(board.frames, baro.SampleFrame))
    # ...and counted what it threw away.
    identify_bytes = len(b"\x00" + baro.encode(baro.IdentifyCommand(1, 0)))
    received = after.rx_bytes - before.rx_bytes
    if board.simulated:
        assert received == sent + identify_bytes
    else:
        assert received >= sent
    rejected = (
        after.rx_crc_errors
        - before.rx_crc_errors
        + after.rx_bad_frames
        - before.rx_bad_frames
        + after.rx_overflows
        - before.rx_overflows
    )
    assert rejected >= 10
    assert after.rx_overflows > before.rx_overflows  # the runs without 0x00 were oversized
    print(f"sent {sent} random bytes: {received} received, {rejected} frames rejected")


# --- simulated board only -------------------------------------------------------------------


def test_boot_sends_hello_first(sim_board: SimBoardFactory) -> None:
    link = sim_board().link
    first = link.wait_for(lambda f: True, 2.0, "any frame")
    assert isinstance(first, baro.HelloFrame)
    assert first.seq == 0
    assert first.reset_cause & baro.ResetCause.POWER_ON
    assert link.bad == []  # the lone 0x00 before it is an empty frame, not an error


def _elevator(t0: float, z0: float, rise_m: float, v_max: float = 1.5, accel: float = 0.75):
    """Height of a car leaving z0 at t0 with a trapezoidal speed profile: (duration, z(t))."""
    t_acc = v_max / accel
    d_acc = 0.5 * accel * t_acc**2
    cruise = (abs(rise_m) - 2 * d_acc) / v_max
    sign = 1.0 if rise_m > 0 else -1.0

    def z(t: float) -> float:
        s = t - t0
        if s <= 0:
            return z0
        if s < t_acc:
            return z0 + sign * 0.5 * accel * s**2
        if s < t_acc + cruise:
            return z0 + sign * (d_acc + v_max * (s - t_acc))
        if s < 2 * t_acc + cruise:
            r = 2 * t_acc + cruise - s
            return z0 + sign * (abs(rise_m) - 0.5 * accel * r**2)
        return z0 + rise_m

    return 2 * t_acc + cruise, z


def _step_and_elevator_trajectory() -> list[TrajectoryRow]:
    p0 = 101325.0
    rows = [TrajectoryRow(0.0, p0, 21.5)]
    # One storey up, as a step: the sharpest change the sensor could ever see.
    rows += [
        TrajectoryRow(5.0, p0, 21.5),
        TrajectoryRow(5.0 + 1e-6, p0 - STOREY_M * PA_PER_M, 21.5),
    ]
    z = STOREY_M
    t = 10.0
    rows.append(TrajectoryRow(t, p0 - z * PA_PER_M, 21.6))
    for rise in (4 * STOREY_M, -5 * STOREY_M):  # up four floors, then down to the ground
        duration, height = _elevator(t, z, rise)
        steps = 200
        for i in range(1, steps + 1):
            ti = t + duration * i / steps
            rows.append(TrajectoryRow(ti, p0 - height(ti) * PA_PER_M, 21.6 + 0.02 * (ti - 10)))
        t += duration
        z += rise
        t += 4.0
        rows.append(TrajectoryRow(t, p0 - z * PA_PER_M, 21.6 + 0.02 * (t - 10)))
    return rows


def test_injected_pressure_is_recovered_within_1_pa(sim_board: SimBoardFactory) -> None:
    """Through a one-storey step and an elevator ride up and down, every SAMPLE the codec decodes
    matches the pressure the virtual sensor measured, as the trajectory gives it, within 1 Pa."""
    rows = _step_and_elevator_trajectory()
    sim = sim_board(trajectory=rows)
    link = sim.link
    frames = link.run_for(rows[-1].t_s + 1.0)
    samples = frames_of(frames, baro.SampleFrame)
    assert_contiguous(samples)
    truth = [r for r in sim.truth() if r["meas_us"] >= 0]
    # Pair each sample with the read that produced it: the board stamps the start of its read,
    # the harness the moment the read reached the sensor (micros() starts a little after reset).
    by_read = sorted(truth, key=lambda r: r["read_us"])
    errors, temperature_errors = [], []
    j = 0
    for sample in samples:
        while j < len(by_read) and by_read[j]["read_us"] < sample.time_us:
            j += 1
        assert j < len(by_read), f"no sensor read for sample {sample.seq}"
        read = by_read[j]
        assert read["read_us"] - sample.time_us < 2000
        expected_p, expected_t = interpolate(rows, read["meas_us"] / 1e6)
        assert read["pressure_pa"] == pytest.approx(expected_p, abs=1e-3)
        errors.append(sample.pressure_pa - expected_p)
        temperature_errors.append(sample.temperature_c - expected_t)
    worst = max(abs(e) for e in errors)
    span = max(s.pressure_pa for s in samples) - min(s.pressure_pa for s in samples)
    print(
        f"{len(samples)} samples over {span:.1f} Pa of change: max |error| {worst:.3f} Pa, "
        f"mean {statistics.fmean(errors):+.3f} Pa, "
        f"max |temperature error| {max(map(abs, temperature_errors)):.3f} degC"
    )
    assert span > 4 * STOREY_M * PA_PER_M
    assert worst <= 1.0
    assert max(map(abs, temperature_errors)) <= 0.011


def test_no_sensor_gives_errors_then_the_stream_starts_when_it_appears(
    sim_board: SimBoardFactory,
) -> None:
    rows = [TrajectoryRow(0.0, 100000.0, present=False), TrajectoryRow(3.0, 100000.0, present=True)]
    link = sim_board(trajectory=rows).link
    first = link.wait_type(baro.HelloFrame)
    assert (first.sensor, first.chip_id, first.i2c_address) == (baro.SensorModel.NONE, 0, 0)
    frames = link.run_for(2.5)
    errors = frames_of(frames, baro.ErrorFrame)
    assert len(errors) >= 4
    assert {e.code for e in errors} == {baro.ErrorCode.SENSOR_NOT_FOUND}
    assert [e.count for e in errors] == sorted(e.count for e in errors)  # consecutive count grows
    assert all(
        s.sensor_state == baro.SensorState.SEARCHING for s in frames_of(frames, baro.StatusFrame)
    )
    assert not frames_of(frames, baro.SampleFrame)
    hello = link.wait_type(baro.HelloFrame, device_s=2.0)
    assert hello.sensor == baro.SensorModel.BMP280
    samples = frames_of(link.run_for(3.0), baro.SampleFrame)
    assert len(samples) >= 70
    assert_contiguous(samples)
    assert samples[0].pressure_pa == pytest.approx(100000.0, abs=1.0)
    assert status_after(link).sensor_state == baro.SensorState.RUNNING


def test_sensor_lost_mid_stream_is_reported_and_the_stream_resumes(
    sim_board: SimBoardFactory,
) -> None:
    rows = [
        TrajectoryRow(0.0, 99000.0),
        TrajectoryRow(4.0, 99000.0, present=False),
        TrajectoryRow(7.0, 99000.0, present=True),
    ]
    link = sim_board(trajectory=rows).link
    before = frames_of(link.run_for(3.5), baro.SampleFrame)
    assert len(before) >= 80
    lost = link.wait_for(
        lambda f: isinstance(f, baro.ErrorFrame) and f.code == baro.ErrorCode.SENSOR_LOST,
        2.0,
        "SENSOR_LOST",
    )
    assert isinstance(lost, baro.ErrorFrame)
    # TWI status of the failure: address not acknowledged (0x20 write, 0x48 read; simavr 1.6
    # reports an unanswered write address as 0x30, "data not acknowledged").
    assert lost.detail in (0x20, 0x30, 0x48)
    hello = link.wait_type(baro.HelloFrame, device_s=4.0)
    assert hello.sensor == baro.SensorModel.BMP280
    after = frames_of(link.run_for(3.0), baro.SampleFrame)
    assert len(after) >= 70
    assert_contiguous(frames_of(link.frames, baro.SampleFrame))
    status = status_after(link)
    assert status.i2c_errors >= 3
    assert status.samples_missed >= 25 * 2  # about three seconds without a sensor
    assert frames_of(link.frames, baro.ErrorFrame)[1:]  # NOT_FOUND while it was away


def test_sensor_at_the_other_address_is_found(sim_board: SimBoardFactory) -> None:
    link = sim_board(address=0x77).link
    hello = link.wait_type(baro.HelloFrame)
    assert (hello.sensor, hello.i2c_address) == (baro.SensorModel.BMP280, 0x77)
    assert len(frames_of(link.run_for(1.0), baro.SampleFrame)) >= 20


def test_real_time_pacing_keeps_the_stream_whole(sim_board: SimBoardFactory) -> None:
    """At speed 1 the host reads as a daemon would; the board's clock runs at wall speed."""
    link = sim_board(speed=1.0).link
    samples = frames_of(link.run_for(2.0), baro.SampleFrame)
    assert len(samples) >= 45
    assert_contiguous(samples)


def test_watchdog_resets_a_stuck_loop(sim_board: SimBoardFactory, hooks_elf: Path) -> None:
    """A test build hangs its loop on command; the watchdog must bring the board back."""
    link = sim_board(elf=hooks_elf).link
    assert link.wait_type(baro.HelloFrame).reset_cause & baro.ResetCause.POWER_ON
    before = frames_of(link.run_for(1.0), baro.SampleFrame)
    assert len(before) >= 20
    body = baro.HEADER.pack(baro.PROTOCOL_VERSION, 0xF0, 1, 0)  # TEST_HANG
    link.send(b"\x00" + baro.cobs_encode(body + baro.CRC.pack(baro.crc16(body))) + b"\x00")
    hello = link.wait_type(baro.HelloFrame, device_s=None)  # an answer to the host's command
    assert hello.reset_cause & baro.ResetCause.WATCHDOG
    assert hello.seq == 0  # a fresh start
    after = frames_of(link.run_for(1.0), baro.SampleFrame)
    assert len(after) >= 20
    assert after[0].seq == 0
    assert_contiguous(after)


def test_ms5611_is_found_by_probing_and_read_within_1_pa(sim_board: SimBoardFactory) -> None:
    """The second sensor: an MS5611 at 0x77 is recognised by its PROM CRC and streamed."""
    p0 = 101000.0
    rows = [
        TrajectoryRow(0.0, p0, 18.0),
        TrajectoryRow(3.0, p0, 18.0),
        TrajectoryRow(3.0 + 1e-6, p0 - STOREY_M * PA_PER_M, 18.0),  # one storey, as a step
        TrajectoryRow(6.0, p0 - STOREY_M * PA_PER_M, 18.0),
        TrajectoryRow(9.0, p0 - 2 * STOREY_M * PA_PER_M, 18.0),  # another, at 12 Pa/s
        TrajectoryRow(12.0, p0 - 2 * STOREY_M * PA_PER_M, 18.0),
    ]
    link = sim_board(trajectory=rows, sensor="ms5611", address=0x77).link
    hello = link.wait_type(baro.HelloFrame)
    assert (hello.sensor, hello.chip_id, hello.i2c_address) == (baro.SensorModel.MS5611, 0, 0x77)
    samples = frames_of(link.run_for(12.0), baro.SampleFrame)
    assert len(samples) >= 12 * 25 - 3
    assert_contiguous(samples)
    # The board reports its latest conversion pair: at most one D1+D2 cycle (about 19 ms at
    # OSR 4096) plus a loop pass old. Away from the step, that is within 1 Pa of the truth.
    errors = []
    for sample in samples:
        t = sample.time_us / 1e6
        if abs(t - 3.0) < 0.1:
            continue
        expected, _ = interpolate(rows, t - 0.010)
        errors.append(sample.pressure_pa - expected)
        assert sample.temperature_c == pytest.approx(18.0, abs=0.015)
    print(f"MS5611: {len(errors)} samples, max |error| {max(map(abs, errors)):.3f} Pa")
    assert max(map(abs, errors)) <= 1.0
    ack = link.command(baro.SetOversamplingCommand(link.next_seq(), 0, 1, 1, 0))
    assert ack.result == baro.AckResult.OK
    link.set_rate(50)
    fast = frames_of(link.run_for(2.0), baro.SampleFrame)
    assert len(fast) >= 95
    assert_contiguous(fast)
