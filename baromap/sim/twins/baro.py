"""The barometer-board twin: our firmware's COBS frames at 115200 baud, from the scenario.

Like the firmware it sends a lone 0x00 and a HELLO at power-up, a SAMPLE every 1/rate s of
its own clock (default 25 Hz), a STATUS every second, and answers every well-formed host frame
with an ACK (IDENTIFY then with a HELLO; unknown types UNKNOWN_COMMAND, short payloads
BAD_LENGTH). Each frame type has its own sequence counter, as PROTOCOL.md specifies, so a gap
in SAMPLE numbers means lost samples and nothing else. Readings come from
the same atmosphere and BMP280 models as ``pressure_run``, evaluated at the robot's route
time (which stops while the base's watchdog holds the robot) and the weather's own time.
"""

from __future__ import annotations

import time

import numpy as np

from baromap.protocols import baro
from baromap.protocols.framing import BadFrame
from baromap.sim.bmp280 import Bmp280
from baromap.sim.scenario import STREAM_ROBOT_BARO
from baromap.sim.twins.base import Twin
from baromap.sim.twins.uart import line_seconds

BAUD = 115200
FIRMWARE = (1, 0, 0)
DEVICE_FRAME_TYPES = (
    baro.FrameType.HELLO,
    baro.FrameType.SAMPLE,
    baro.FrameType.STATUS,
    baro.FrameType.ERROR,
    baro.FrameType.ACK,
)


class BaroTwin(Twin):
    name = "baro"
    initial_baud = BAUD

    def setup(self) -> None:
        self.default_rate = self.settings.baro_rate_hz
        self.samples_sent = 0

    def power_on(self) -> None:
        self.decoder = baro.Decoder()
        self.rate_hz = self.default_rate
        self.osrs = (16, 2, 16)
        self.seq = dict.fromkeys(DEVICE_FRAME_TYPES, 0)
        self.counters = dict.fromkeys(
            ("frames_sent", "frames_dropped", "i2c_errors", "samples_missed", "rx_bytes"), 0
        )
        self.rx_frames = self.rx_crc = self.rx_bad = self.rx_overflows = 0
        self.sensor = Bmp280.random(self.clock.scenario.rng(STREAM_ROBOT_BARO), float(self.rate_hz))
        self._boot = time.monotonic()
        self._next_sample = self._boot + self.clock.real_delay(1.0 / self.rate_hz)
        self._next_status = self._boot + self.clock.real_delay(1.0)
        greeting = b"\x00" + baro.encode(self._hello())
        self.counters["frames_sent"] += 1
        # At the twin's start the board has been up a moment already (a host opens the port of
        # a running twin): its greeting is on the line by now, not still going out while the
        # host sets its speed. After a replug or a power cycle it goes out from now.
        at = None if self.boot else time.monotonic() - line_seconds(len(greeting), BAUD)
        self.port.send(greeting, at=at)

    def _time_us(self, at: float | None = None) -> int:
        """The board's micros() at monotonic instant ``at`` (default now)."""
        t = time.monotonic() if at is None else at
        return round((t - self._boot) * self.clock.speed * 1e6) % baro.TIME_MODULO

    def _next_seq(self, frame_type: baro.FrameType) -> int:
        seq = self.seq[frame_type]
        self.seq[frame_type] = (seq + 1) % baro.SEQ_MODULO
        return seq

    def _send(self, frame: baro.Frame) -> bool:
        self.counters["frames_sent"] += 1
        return self.port.send(baro.encode(frame))

    def _hello(self) -> baro.HelloFrame:
        return baro.HelloFrame(
            self._next_seq(baro.FrameType.HELLO),
            self._time_us(),
            0,
            *FIRMWARE,
            baro.SensorModel.BMP280,
            0x58,
            0x76,
            self.rate_hz,
            *self.osrs,
            int(baro.ResetCause.POWER_ON),
        )

    def on_bytes(self, data: bytes) -> None:
        self.counters["rx_bytes"] += len(data)
        for frame in self.decoder.feed(data):
            if not isinstance(frame, BadFrame):
                self.rx_frames += 1
                self._command(frame)
            elif frame.reason in ("type", "length"):
                # CRC and version good: the firmware counts it as received and answers it.
                self.rx_frames += 1
                self._refuse(frame)
            elif frame.reason == "crc":
                self.rx_crc += 1
            elif frame.reason == "oversized":
                self.rx_overflows += 1
            else:
                self.rx_bad += 1

    def _refuse(self, bad: BadFrame) -> None:
        """ACK UNKNOWN_COMMAND or BAD_LENGTH for a well-formed frame the codec cannot decode."""
        raw = baro.cobs_decode(bad.sample)  # the whole frame: at most MAX_ENCODED bytes
        if raw is None or len(raw) < baro.MIN_FRAME:
            return
        _, frame_type, seq, _ = baro.HEADER.unpack_from(raw)
        known = frame_type in (baro.FrameType.SET_RATE, baro.FrameType.SET_OVERSAMPLING)
        result = baro.AckResult.BAD_LENGTH if known else baro.AckResult.UNKNOWN_COMMAND
        self._ack(frame_type, seq, result)

    def _ack(self, command: int, command_seq: int, result: baro.AckResult) -> None:
        seq = self._next_seq(baro.FrameType.ACK)
        self._send(baro.AckFrame(seq, self._time_us(), command, command_seq, result))

    def _command(self, frame: object) -> None:
        result = baro.AckResult.OK
        if isinstance(frame, baro.SetRateCommand):
            if 1 <= frame.rate_hz <= baro.MAX_RATE_HZ:
                self.rate_hz = frame.rate_hz
                self._next_sample = time.monotonic() + self.clock.real_delay(1.0 / self.rate_hz)
            else:
                result = baro.AckResult.BAD_VALUE
        elif isinstance(frame, baro.SetOversamplingCommand):
            ok = (
                frame.osrs_p in baro.OVERSAMPLING_VALUES
                and frame.osrs_t in baro.OVERSAMPLING_VALUES
                and frame.iir_filter in baro.IIR_FILTER_VALUES
            )
            if ok:
                self.osrs = (frame.osrs_p, frame.osrs_t, frame.iir_filter)
            else:
                result = baro.AckResult.BAD_VALUE
        elif not isinstance(frame, baro.IdentifyCommand):
            result = baro.AckResult.UNKNOWN_COMMAND
        self._ack(int(getattr(frame, "TYPE", 0)), getattr(frame, "seq", 0), result)
        if isinstance(frame, baro.IdentifyCommand):
            self._send(self._hello())

    def tick(self) -> None:
        now = time.monotonic()
        if now >= self._next_status:
            self._next_status += self.clock.real_delay(1.0)
            self._send(
                baro.StatusFrame(
                    seq=self._next_seq(baro.FrameType.STATUS),
                    time_us=self._time_us(),
                    frames_sent=self.counters["frames_sent"],
                    frames_dropped=self.counters["frames_dropped"],
                    i2c_errors=self.counters["i2c_errors"],
                    samples_missed=self.counters["samples_missed"],
                    rx_bytes=self.counters["rx_bytes"],
                    rx_frames=self.rx_frames,
                    rx_crc_errors=self.rx_crc,
                    rx_bad_frames=self.rx_bad,
                    rx_overflows=self.rx_overflows,
                    sensor_state=baro.SensorState.RUNNING,
                )
            )
        if now < self._next_sample:
            return
        self._next_sample += self.clock.real_delay(1.0 / self.rate_hz)
        if self._next_sample < now:  # fell behind (a stall, a slow machine): count and skip
            missed = int((now - self._next_sample) / self.clock.real_delay(1.0 / self.rate_hz))
            self.counters["samples_missed"] += missed
            self._next_sample = now + self.clock.real_delay(1.0 / self.rate_hz)
        # Like the firmware: time_us is the instant the sensor's registers are read, and the
        # frame goes out once the reading is computed (the twin's computing stands for the
        # board's I2C read and compensation). The truth is that same instant.
        measured_ns = time.monotonic_ns()
        measured_s = self.clock.now()
        time_us = self._time_us(measured_ns / 1e9)
        pressure, temperature = self.reading()
        seq = self._next_seq(baro.FrameType.SAMPLE)
        if self._send(baro.SampleFrame.from_values(seq, time_us, pressure, temperature)):
            self.truth.record(measured_ns, measured_s, boot=self.boot, seq=seq)
        self.samples_sent += 1

    def reading(self) -> tuple[float, float]:
        sc = self.clock.scenario
        t_robot = np.array([self.clock.robot_time()])
        truth = sc.truth(t_robot)
        weather_t = np.array([self.clock.now()])
        p_true = sc.true_pressure_pa(weather_t, truth)
        # Ventilation follows the car, i.e. route time; weather follows the clock.
        p_true += sc.ventilation.pa(t_robot, truth.vz) - sc.ventilation.pa(weather_t, truth.vz)
        p, t = self.sensor.measure(p_true, sc.air.at(truth.z))
        return float(p[0]), float(t[0])
