"""The LMS200 twin: telegrams in, ACK/NAK and replies out, scans streamed when asked.

It powers up at 9600 baud in "request" mode, 180 deg at 1 deg, mm units, 8 m measuring mode,
like the real sensor. What real drivers rely on, and the twin does:

- Baud: the line runs at the twin's speed; a host whose termios speed differs reads garbage
  and is read as garbage (:mod:`baromap.sim.twins.pty_port`), so a baud search must search.
  The switch commands (20 40/41/42/48) are answered at the old speed, then the twin runs at
  the new one.
- Reset ``10``: ACK and ``91``; the sensor restarts at 9600 baud and, after the boot time of
  the scenario's :class:`~baromap.sim.scenario.TwinSettings`, sends the power-on telegram
  ``90``. A power cycle (scheduled or :meth:`Twin.power_cycle`) ends the same way. The sensor
  is already up when the twin starts (it was powered long before the host opened the port).
- Continuous modes: ``20 24`` every scan (B0), ``20 26 n`` the mean of n scans (B6),
  ``20 27 first last`` a subrange (B7), ``20 28 n first last`` the mean over a subrange (BF);
  ``20 25`` stops. Bad parameters are answered ``A0 01``.
- Configuration ``77`` (in installation mode): a 32- to 34-byte block updates the fields it
  carries (ARIA sends 32 bytes, sicktoolbox and MRPT 34); the measuring mode and units
  acknowledged in ``F7 01`` are the ones the scans then use (a 32 m mode sends 15-bit ranges,
  so walls beyond 8.19 m come through), and the availability bit 1 adds the real-time scan
  index byte to every scan.
- Timing: the mirror turns at 75 Hz; at 0.5 and 0.25 deg the sensor interlaces 2 or 4 turns
  into one scan, and a mean of n scans takes n scans' time, so a telegram goes out when both
  the line is free and the scan is complete.
- Status ``31``: a full-length ``B1`` (152 data bytes, as far as sicktoolbox reads).
"""

from __future__ import annotations

import struct
import time
from typing import Final

import numpy as np
import numpy.typing as npt

from baromap.protocols import lms200
from baromap.protocols.framing import BadFrame
from baromap.sim.laser import LaserConfig, Lms200Model, cast
from baromap.sim.record import CAR_DOOR_SEGMENT, doors_closed, scan_floors
from baromap.sim.scenario import STREAM_LASER
from baromap.sim.twins.base import Twin

#: The sensor's reply delay after a command (it answers well within the 60 ms drivers wait).
REPLY_DELAY_S: Final = 0.01
#: Silence after which a partial telegram from the host is given up.
RX_IDLE_S: Final = 0.03
#: Mirror turns per second.
MIRROR_HZ: Final = 75.0
#: Mirror turns interlaced into one full scan, by resolution in 0.01 deg.
INTERLACE: Final = {100: 1, 50: 2, 25: 4}
SOFTWARE_VERSION: Final = "V02.10 "
_STREAMING: Final = frozenset(
    {lms200.Mode.CONTINUOUS, lms200.Mode.MEAN, lms200.Mode.SUBRANGE, lms200.Mode.MEAN_SUBRANGE}
)
_SUBRANGE: Final = struct.Struct("<HH")


class Lms200Twin(Twin):
    name = "lms200"
    initial_baud = 9600

    def setup(self) -> None:
        self.decoder = lms200.Decoder()
        self.model = Lms200Model(LaserConfig(), self.clock.scenario.rng(STREAM_LASER))
        self.scans_sent = 0
        self.commands = 0
        self.resets = 0
        self._last_scan = 0.0
        self._ready_at: float | None = None  # booting until then; None: up

    # ---- power --------------------------------------------------------------------------------
    def power_on(self) -> None:
        self.port.set_baud(9600)
        self.decoder = lms200.Decoder()
        self.mode = lms200.Mode.REQUEST
        self.variant = (180, 100)
        self.config = lms200.LmsConfig()
        self.mean_samples = 0
        self.subrange: tuple[int, int] | None = None
        self._pending_baud: int | None = None
        self._restart_pending = False
        self._last_rx = 0.0
        if self.boot > 0:  # a power cycle: the sensor boots, then says so
            self._ready_at = time.monotonic() + self.clock.real_delay(self.settings.laser_boot_s)

    @property
    def units(self) -> lms200.Units:
        return "mm" if self.config.units == 1 else "cm"

    @property
    def booting(self) -> bool:
        return self._ready_at is not None

    def _restart(self) -> None:
        """After a reset: back to 9600 baud and the power-on defaults, then boot."""
        self.resets += 1
        self.boot += 1
        self.power_on()

    # ---- host -> sensor -----------------------------------------------------------------------
    def _reply(self, data: bytes, ack: bool = True) -> None:
        time.sleep(REPLY_DELAY_S / 2)
        self.port.send((b"\x06" if ack else b"") + data)

    def on_bytes(self, data: bytes) -> None:
        if self.booting or self._restart_pending:
            return  # a booting sensor hears nothing
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
            self._reply(lms200.status_reply(self._status()))
        elif cmd == lms200.Command.TYPE:
            self._reply(lms200.type_reply(self.settings.laser_type))
        elif cmd == lms200.Command.RESET:
            self._reply(lms200.reset_reply())
            self._restart_pending = True
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
            self._write_config(data)
        else:
            self._reply(lms200.encode_reply(lms200.Reply.INVALID_COMMAND, bytes((cmd,))))

    def _write_config(self, block: bytes) -> None:
        updated = self.config.updated(block)
        ok = (
            updated is not None
            and self.mode == lms200.Mode.INSTALLATION
            and updated.units in (0, 1)
            and updated.measuring_mode in lms200.RANGE_BITS
        )
        if ok and updated is not None:
            self.config = updated
        self._reply(lms200.config_write_reply(ok, self.config))

    def _status(self) -> lms200.StatusReport:
        return lms200.StatusReport(
            software_version=SOFTWARE_VERSION,
            operating_mode=int(self.mode),
            measuring_mode=self.config.measuring_mode,
            angle_deg=self.variant[0],
            resolution_cdeg=self.variant[1],
            units=self.config.units,
        )

    def _set_mode(self, data: bytes) -> None:
        mode, args = data[0], data[1:]
        if mode in lms200.MODE_BAUDS:
            self._reply(lms200.mode_reply())
            self._pending_baud = lms200.MODE_BAUDS[mode]
        elif mode == lms200.Mode.INSTALLATION:
            ok = args == lms200.INSTALLATION_PASSWORD
            if ok:
                self.mode = lms200.Mode.INSTALLATION
            result = lms200.ModeResult.OK if ok else lms200.ModeResult.WRONG_PASSWORD
            self._reply(lms200.mode_reply(result))
        elif mode in (lms200.Mode.CONTINUOUS, lms200.Mode.REQUEST) and not args:
            self._enter(lms200.Mode(mode), 0, None)
        elif mode == lms200.Mode.MEAN and len(args) == 1:
            self._enter(lms200.Mode.MEAN, args[0], None)
        elif mode == lms200.Mode.SUBRANGE and len(args) == _SUBRANGE.size:
            self._enter(lms200.Mode.SUBRANGE, 0, _SUBRANGE.unpack(args))
        elif mode == lms200.Mode.MEAN_SUBRANGE and len(args) == 1 + _SUBRANGE.size:
            self._enter(lms200.Mode.MEAN_SUBRANGE, args[0], _SUBRANGE.unpack(args[1:]))
        else:
            self._reply(lms200.encode_reply(lms200.Reply.INVALID_COMMAND, bytes((0x20,))))

    def _enter(self, mode: lms200.Mode, samples: int, subrange: tuple[int, int] | None) -> None:
        beams = self.variant[0] * 100 // self.variant[1] + 1
        mean = mode in (lms200.Mode.MEAN, lms200.Mode.MEAN_SUBRANGE)
        if (mean and samples not in lms200.MEAN_SAMPLES) or (
            subrange is not None and not 1 <= subrange[0] <= subrange[1] <= beams
        ):
            self._reply(lms200.mode_reply(lms200.ModeResult.WRONG_PASSWORD))  # A0 01: refused
            return
        self.mode = mode
        self.mean_samples = samples
        self.subrange = subrange
        self._reply(lms200.mode_reply())

    # ---- sensor -> host -----------------------------------------------------------------------
    def tick(self) -> None:
        now = time.monotonic()
        if self._ready_at is not None:
            if now < self._ready_at:
                return
            self._ready_at = None
            self.port.send(lms200.power_on_telegram(f"{SOFTWARE_VERSION}LMS ready"))
            return
        if self._last_rx and now - self._last_rx > RX_IDLE_S:
            # The receiver's inter-character timeout: a telegram that did not complete or
            # failed its CRC is settled now, and answered with NAK.
            self._last_rx = 0.0
            self._handle(self.decoder.flush())
        if self.port.pending:
            return  # replies go out at the speed they were asked at
        if self._restart_pending:
            self._restart_pending = False
            self._restart()
            return
        if self._pending_baud is not None:
            # The reply went out at the old speed; from now on the line runs at the new one.
            self.port.set_baud(self._pending_baud)
            self._pending_baud = None
        if self.mode not in _STREAMING or self.port.stalled:
            return
        if now - self._last_scan < self.clock.real_delay(self.scan_period_s):
            return
        self._last_scan = now
        # The scan is taken now and starts on the line now: the sensor sends a telegram as
        # soon as it has it. The twin's own time to compute it (about a millisecond) delays
        # only when its bytes are written, never when they count as sent.
        taken_ns = time.monotonic_ns()
        taken_s = self.clock.robot_time()
        if self.port.send(self.scan_telegram(taken_s), at=taken_ns / 1e9):
            self.truth.record(taken_ns, taken_s, boot=self.boot)
            self.scans_sent += 1

    @property
    def scan_period_s(self) -> float:
        """Shortest time between two telegrams of the current mode (the mirror's limit)."""
        turns = INTERLACE[self.variant[1]] * max(self.mean_samples, 1)
        return turns / MIRROR_HZ

    def _laser_config(self) -> LaserConfig:
        bits = lms200.range_bits(self.config.measuring_mode)
        return LaserConfig(self.variant[0], self.variant[1], self.units, self.port.baud, bits)

    def _words(self, samples: int, robot_s: float | None = None) -> npt.NDArray[np.uint16]:
        """Range words of the scan at the robot's pose at route time ``robot_s`` (default now);
        the mean of ``samples`` scans."""
        sc = self.clock.scenario
        t = np.array([self.clock.robot_time() if robot_s is None else robot_s])
        truth = sc.truth(t)
        floor = int(scan_floors(truth, sc)[0])
        walls = sc.building.floors[floor].walls_m
        if doors_closed(sc, t)[0]:
            walls = np.concatenate([walls, CAR_DOOR_SEGMENT])
        cfg = self._laser_config()
        if cfg != self.model.config:
            self.model = Lms200Model(cfg, sc.rng(STREAM_LASER))
        origins = np.column_stack([truth.x, truth.y])
        true, cosines = cast(walls, origins, truth.theta, cfg.angles_rad, cfg.range_max_m + 0.5)
        if samples <= 1:
            single: npt.NDArray[np.uint16] = self.model.words(true, cosines)[0]
            return single
        scans = self.model.words(np.repeat(true, samples, 0), np.repeat(cosines, samples, 0))
        return _mean_words(scans, cfg.range_bits)

    def scan_telegram(self, robot_s: float | None = None) -> bytes:
        """The telegram of the current streaming mode, for what the sensor sees at route time
        ``robot_s`` (default now)."""
        mean = self.mode in (lms200.Mode.MEAN, lms200.Mode.MEAN_SUBRANGE)
        words = self._words(self.mean_samples if mean else 1, robot_s)
        subrange = self.subrange
        if subrange is not None:
            words = words[subrange[0] - 1 : subrange[1]]
        extra = b""
        if self.config.availability & lms200.AVAILABILITY_SCAN_INDEX:
            extra = bytes((self.scans_sent & 0xFF,))
        return lms200.encode_scan(
            words,
            units=self.units,
            extra=extra,
            sample_size=self.mean_samples if mean else None,
            subrange=subrange,
        )


def _mean_words(scans: npt.NDArray[np.uint16], bits: int) -> npt.NDArray[np.uint16]:
    """Per beam, the mean range of the scans that measured one; else the first error code."""
    mask = (1 << bits) - 1
    first_error = mask - (0x1FFF - lms200.FIRST_ERROR_CODE)
    ranges = scans.astype(np.int64) & mask
    valid = ranges < first_error
    counts = valid.sum(axis=0)
    sums = np.where(valid, ranges, 0).sum(axis=0)
    mean = np.rint(sums / np.maximum(counts, 1)).astype(np.int64)
    out = np.where(counts > 0, mean, scans[0] & mask)
    return np.asarray(out, dtype=np.uint16)
