"""The barometer board session: IDENTIFY/HELLO, version check, rate and oversampling, samples.

Opening an Uno's port resets the board (DTR), which then spends up to ~1.5 s in its
bootloader and sends a HELLO nobody may see (pyserial flushes input on open), so the session
asks with IDENTIFY until a HELLO answers (``firmware/PROTOCOL.md`` section 1). Settings are
not stored on the board: after a reset (an unasked HELLO with sequence 0) the session sets
the board up again. Each sample is stamped from the board's microsecond clock through
:class:`~baromapd.clock.DeviceClockFit`; STATUS counters and ERROR frames go into health.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Final

import structlog

from baromap.errors import DeviceError
from baromap.protocols import baro
from baromap.protocols.framing import BadFrame
from baromapd.clock import DeviceClockFit, LinePosition, transmission_ns
from baromapd.config import BarometerConfig
from baromapd.session import DeviceRestarted, DeviceSession

log = structlog.get_logger(__name__)

HELLO_ATTEMPTS: Final = 10
HELLO_WAIT_S: Final = 0.5
ACK_WAIT_S: Final = 0.5


class BarometerSession(DeviceSession):
    def __init__(self, config: BarometerConfig, **kwargs: Any) -> None:
        super().__init__(
            "barometer",
            port=config.port,
            baud=config.baud,
            retry=config.retry,
            usb_reset=config.usb_reset,
            **kwargs,
        )
        self.config = config
        self.decoder = baro.Decoder()
        self.fit = DeviceClockFit()
        self._command_seq = 0
        self._last_sample_seq: int | None = None
        self.line = LinePosition()

    def _next_seq(self) -> int:
        self._command_seq = (self._command_seq + 1) % baro.SEQ_MODULO
        return self._command_seq

    # ---- handshake ----------------------------------------------------------------------------
    def handshake(self) -> None:
        self.set_baud(self.config.baud)
        self.decoder = baro.Decoder()
        hello = None
        for _ in range(HELLO_ATTEMPTS):
            self.write(baro.identify(self._next_seq()))
            hello = self.wait_for(self._decode, baro.HelloFrame, HELLO_WAIT_S)
            if hello is not None:
                break
        if hello is None:
            raise DeviceError(f"no HELLO from the barometer board at {self.baud} baud")
        if hello.sensor == baro.SensorModel.NONE:
            log.warning("barometer board has no sensor yet", port=self.path)
        c = self.config
        self._command(lambda seq: baro.set_rate(c.rate_hz, seq), baro.FrameType.SET_RATE)
        self._command(
            lambda seq: baro.set_oversampling(
                c.oversampling, c.temperature_oversampling, c.iir_filter, seq
            ),
            baro.FrameType.SET_OVERSAMPLING,
        )
        try:
            sensor = baro.SensorModel(hello.sensor).name
        except ValueError:
            sensor = str(hello.sensor)
        self.identity = {
            "device": "baromap barometer board",
            "protocol": f"{baro.PROTOCOL_VERSION}.{hello.protocol_minor}",
            "firmware_version": hello.firmware_version,
            "sensor": sensor,
            "chip_id": f"0x{hello.chip_id:02x}",
            "i2c_address": f"0x{hello.i2c_address:02x}",
            "rate_hz": str(self.config.rate_hz),
            "oversampling": f"p{self.config.oversampling}/t{self.config.temperature_oversampling}"
            f"/iir{self.config.iir_filter}",
            "port": self.path,
        }
        self.fit.reset()
        self._last_sample_seq = None
        self.line.reset()

    def up_detail(self) -> str:
        info = self.identity
        return (
            f"streaming at {self.config.rate_hz} Hz, firmware {info.get('firmware_version')}, "
            f"{info.get('sensor')}"
        )

    def _command(self, build: Callable[[int], bytes], frame_type: baro.FrameType) -> None:
        seq = self._next_seq()
        self.write(build(seq))
        ack = self.wait_for(
            self._decode, baro.AckFrame, ACK_WAIT_S, lambda ack: ack.command_seq == seq
        )
        if ack is None:
            raise DeviceError(f"no ACK for {frame_type.name}")
        if ack.result != baro.AckResult.OK:
            raise DeviceError(f"{frame_type.name} refused: {baro.AckResult(ack.result).name}")

    def _decode(self, data: bytes, read_ns: int) -> list[baro.DecodedItem]:
        """The handshake's frames (its samples are not recorded: the board is not set up)."""
        return self.decoder.feed(data)

    # ---- streaming ----------------------------------------------------------------------------
    def handle(self, data: bytes, read_ns: int) -> None:
        self.line.chunk(len(data), read_ns)
        for frame in self.decoder.feed(data):
            size = frame.wire_size
            if isinstance(frame, BadFrame):
                self.line.skip(size)
                self.bad_frame(frame)
                continue
            self.good_frame()
            if not isinstance(frame, baro.SampleFrame):
                self.line.skip(size)
            else:
                end = self.line.end_ns(size, self.baud)
                self._sample(frame, end - transmission_ns(size, self.baud), read_ns)
            if isinstance(frame, baro.StatusFrame):
                for key, value in frame.counters().items():
                    self.set_counter(f"board_{key}", value)
                self.set_counter("board_sensor_state", frame.sensor_state)
            elif isinstance(frame, baro.ErrorFrame):
                self.count("board_errors")
                try:
                    code = baro.ErrorCode(frame.code).name
                except ValueError:
                    code = str(frame.code)
                log.warning("barometer board error", code=code, detail=frame.detail)
            elif isinstance(frame, baro.HelloFrame) and frame.seq == 0:
                raise DeviceRestarted("the board reset (HELLO with sequence 0): settings lost")

    def _sample(self, frame: baro.SampleFrame, sent_ns: int, read_ns: int) -> None:
        if self._last_sample_seq is not None:
            lost = baro.seq_gap(self._last_sample_seq, frame.seq)
            if lost:
                self.count("samples_lost", lost)
        self._last_sample_seq = frame.seq
        resets = self.fit.resets
        mono = self.fit.update(frame.time_us, sent_ns)
        if self.fit.resets != resets:
            self.count("clock_resets")
        self.publish(baro.to_pressure_sample(frame, self.clock.unix_ns(mono)), read_ns)
