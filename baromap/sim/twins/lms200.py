"""The LMS200 twin: telegrams in, ACK/NAK and replies out, B0 scans streamed when asked.

It powers up at 9600 baud in "request" mode, 180 deg at 1 deg, mm units, like the real
sensor. Baud search on a pty: a pty cannot carry a baud rate, so the twin answers a status
request whatever speed the host believes it uses, at the rate the twin is paced at; a driver
that tries 9600 first finds it at once. The switch commands (20 40/41/42/48) are acknowledged
at the old speed, then the twin paces at the new one. In continuous mode it sends a B0
telegram of the scan at the robot's current pose whenever the line is free, as the real
sensor does (its mirror turns at 75 Hz, the line is the bottleneck).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from baromap.protocols import lms200
from baromap.protocols.framing import BadFrame
from baromap.sim.laser import LaserConfig, Lms200Model
from baromap.sim.record import CAR_DOOR_SEGMENT, doors_closed, scan_floors
from baromap.sim.scenario import STREAM_LASER
from baromap.sim.twins.base import SimClock, Twin

TYPE_STRING = "LMS200;30106"
#: The sensor's reply delay after a command (it answers well within the 60 ms drivers wait).
REPLY_DELAY_S = 0.01
#: Silence after which a partial telegram from the host is given up.
RX_IDLE_S = 0.03


class Lms200Twin(Twin):
    name = "lms200"
    initial_baud = 9600

    def __init__(self, clock: SimClock, link: str | Path | None = None) -> None:
        super().__init__(clock, link)
        self.decoder = lms200.Decoder()
        self.model = Lms200Model(LaserConfig(), clock.scenario.rng(STREAM_LASER))
        self.scans_sent = 0
        self.commands = 0
        self._last_scan = 0.0

    def power_on(self) -> None:
        self.port.set_baud(9600)
        self.decoder = lms200.Decoder()
        self.mode = lms200.Mode.REQUEST
        self.variant = (180, 100)
        self.units: lms200.Units = "mm"
        self.config = lms200.LmsConfig()
        self._pending_baud: int | None = None
        self._last_rx = 0.0

    def _reply(self, data: bytes, ack: bool = True) -> None:
        time.sleep(REPLY_DELAY_S / 2)
        self.port.send((b"\x06" if ack else b"") + data)

    def on_bytes(self, data: bytes) -> None:
        self._last_rx = time.monotonic()
        self._handle(self.decoder.feed(data))

    def _handle(self, messages: list[lms200.LmsMessage]) -> None:
        for msg in messages:
            if isinstance(msg, BadFrame):
                if msg.reason in ("crc", "length", "truncated"):
                    self.port.send(bytes((lms200.NAK,)))
                continue
            if isinstance(msg, lms200.Telegram) and not msg.from_sensor:
                self.commands += 1
                self._command(msg)

    def _command(self, t: lms200.Telegram) -> None:
        cmd, data = t.command, t.data
        if cmd == lms200.Command.STATUS:
            report = lms200.StatusReport(
                operating_mode=int(self.mode),
                angle_deg=self.variant[0],
                resolution_cdeg=self.variant[1],
                units=1 if self.units == "mm" else 0,
            )
            self._reply(lms200.status_reply(report))
        elif cmd == lms200.Command.TYPE:
            self._reply(lms200.type_reply(TYPE_STRING))
        elif cmd == lms200.Command.SET_MODE and data:
            self._set_mode(data)
        elif cmd == lms200.Command.VARIANT and len(data) == 4:
            angle = int.from_bytes(data[:2], "little")
            res = int.from_bytes(data[2:], "little")
            ok = (angle, res) in lms200.VARIANTS
            if ok:
                self.variant = (angle, res)
            reply = lms200.VariantReply(ok, *self.variant)
            self._reply(lms200.variant_reply(reply))
        elif cmd == lms200.Command.READ_CONFIG:
            self._reply(lms200.config_reply(self.config))
        elif cmd == lms200.Command.WRITE_CONFIG:
            block = lms200.LmsConfig.unpack(data)
            ok = block is not None and self.mode == lms200.Mode.INSTALLATION
            if ok and block is not None:
                self.config = block
                self.units = "mm" if block.units == 1 else "cm"
            self._reply(lms200.config_write_reply(ok, self.config))
        else:
            self._reply(lms200.encode_reply(lms200.Reply.INVALID_COMMAND, bytes((cmd,))))

    def _set_mode(self, data: bytes) -> None:
        mode = data[0]
        bauds = {int(m): b for b, m in lms200.BAUD_MODES.items()}
        if mode in bauds:
            self._reply(lms200.mode_reply())
            self._pending_baud = bauds[mode]
        elif mode == lms200.Mode.INSTALLATION:
            ok = data[1:] == lms200.INSTALLATION_PASSWORD
            if ok:
                self.mode = lms200.Mode.INSTALLATION
            self._reply(
                lms200.mode_reply(lms200.ModeResult.OK if ok else lms200.ModeResult.WRONG_PASSWORD)
            )
        elif mode in (lms200.Mode.CONTINUOUS, lms200.Mode.REQUEST):
            self.mode = lms200.Mode(mode)
            self._reply(lms200.mode_reply())
        else:
            self._reply(lms200.encode_reply(lms200.Reply.INVALID_COMMAND, bytes((0x20,))))

    def tick(self) -> None:
        if self._last_rx and time.monotonic() - self._last_rx > RX_IDLE_S:
            # The receiver's inter-character timeout: a telegram that did not complete or
            # failed its CRC is settled now, and answered with NAK.
            self._last_rx = 0.0
            self._handle(self.decoder.flush())
        if self._pending_baud is not None and self.port.pending == 0:
            # The reply went out at the old speed; from now on the line runs at the new one.
            self.port.set_baud(self._pending_baud)
            self._pending_baud = None
        if self.mode != lms200.Mode.CONTINUOUS or self.port.pending or self.port.stalled:
            return
        now = time.monotonic()
        if now - self._last_scan < 1.0 / 75.0 / self.clock.speed:
            return
        self._last_scan = now
        self.port.send(self.scan_telegram())
        self.scans_sent += 1

    def scan_telegram(self) -> bytes:
        """A B0 telegram of what the sensor sees at the robot's pose right now."""
        sc = self.clock.scenario
        t = np.array([self.clock.robot_time()])
        truth = sc.truth(t)
        floor = int(scan_floors(truth, sc)[0])
        walls = sc.building.floors[floor].walls_m
        if doors_closed(sc, t)[0]:
            walls = np.concatenate([walls, CAR_DOOR_SEGMENT])
        cfg = LaserConfig(self.variant[0], self.variant[1], self.units, self.port.baud)
        if cfg != self.model.config:
            self.model = Lms200Model(cfg, sc.rng(STREAM_LASER))
        words = self.model.scans(walls, truth.x, truth.y, truth.theta)[0]
        return lms200.encode_scan(words, units=self.units)
