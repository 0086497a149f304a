"""The SICK LMS200 session: baud search, set-up, continuous scans, and back to 9600 on stop.

The init sequence is the one mature drivers use (SICK's LMS2xx toolbox, Player's sicklms200):
find the sensor's current baud by asking for its status at each speed (a sensor left
streaming by an earlier run is found too: any telegram with a good CRC proves the speed),
switch to the configured baud, stop streaming, read type and status, set units through the
configuration block if they differ, set the variant, start continuous output.

A scan's time is the receive time of its telegram's last byte minus the telegram's line time
at the current baud: the sensor sends a scan as soon as the mirror has swept it. The sensor
announces a power cycle with the power-on telegram ``90`` (it is back at 9600 baud, with its
defaults); the session then sets it up again on the same port while the other devices keep
recording.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Final

import structlog

from baromap.errors import DeviceError
from baromap.protocols import lms200
from baromap.protocols.framing import BadFrame
from baromapd.clock import LinePosition, transmission_ns
from baromapd.config import LaserConfig
from baromapd.session import DeviceRestarted, DeviceSession

log = structlog.get_logger(__name__)

#: The sensor's power-on telegram ("LMS ready" after a reset or a power cycle).
POWER_ON: Final = 0x90
#: Speeds tried when looking for the sensor, after the configured one.
SEARCH_BAUDS: Final = (9600, 38400, 19200, 500000)
#: Longest reply of the init sequence (a status reply, with room), bytes.
LONGEST_REPLY: Final = 900
#: The sensor answers within about 60 ms; a telegram in flight may delay it by its own length.
REPLY_WAIT_S: Final = 0.3
#: After a baud switch the sensor needs a moment on the new speed (drivers wait 250 ms).
BAUD_SETTLE_S: Final = 0.25
#: Re-initialisations in place after scans stopped, before the port is closed and retried.
MAX_IN_PLACE: Final = 2
#: Most of a tap's records decoded in one call: a scan is a few packets (eight from a USB
#: adapter), and ``LinePosition`` keeps the last 64 reads for a frame in progress.
READS_PER_FEED: Final = LinePosition.READS_KEPT // 2


class Lms200Session(DeviceSession):
    #: Scans are stamped from the host's clock alone, at 75 Hz to within a millisecond, and
    #: 50 kB/s of line overflow a tty's buffer in a third of a second: read through a tap.
    tapped = True

    def __init__(self, config: LaserConfig, **kwargs: Any) -> None:
        super().__init__(
            "laser",
            port=config.port,
            baud=config.baud,
            retry=config.retry,
            usb_reset=config.usb_reset,
            **kwargs,
        )
        self.config = config
        self.decoder = lms200.Decoder(at_boundary=False)
        self.line = LinePosition()
        self.streaming = False
        self._in_place = 0
        self._scan_bytes = 0  # the last scan's size on the line: what a scan in progress needs
        self._status_healthy: dict[int, bool] = {}

    # ---- handshake ----------------------------------------------------------------------------
    def handshake(self) -> None:
        self.streaming = False
        self._find_baud()
        # Switch even when the sensor answered at the configured speed: a sensor already there
        # just confirms, and a line that carries any speed (a pty) is told the speed for sure.
        self._switch_baud(self.config.baud)
        self._mode(lms200.Mode.REQUEST, "stop continuous output")
        type_string = lms200.parse_type_reply(self._request(lms200.type_request(), "type"))
        status = lms200.parse_status_reply(self._request(lms200.status_request(), "status"))
        if status is None:
            raise DeviceError("status reply too short")
        wanted_units = 1 if self.config.units == "mm" else 0
        if status.units != wanted_units:
            self._set_units(wanted_units)
        reply = lms200.parse_variant_reply(
            self._request(
                lms200.set_variant(self.config.angle_deg, self.config.resolution_cdeg), "variant"
            )
        )
        if reply is None or not reply.accepted:
            raise DeviceError(
                f"variant {self.config.angle_deg} deg / {self.config.resolution_cdeg / 100} deg "
                "refused"
            )
        self._mode(lms200.Mode.CONTINUOUS, "start continuous output")
        self.identity = {
            "device": "SICK LMS200",
            "type": type_string or "",
            "software_version": status.software_version.strip(),
            "prom_version": status.prom_version.strip(),
            "baud": str(self.baud),
            "variant": f"{self.config.angle_deg}deg/{self.config.resolution_cdeg / 100}deg",
            "units": self.config.units,
            "port": self.path,
        }
        self.streaming = True
        self.line.reset()  # the decoder stays: in sync, and the first scan may be half in it

    def _fresh_decoder(self) -> None:
        self.decoder = lms200.Decoder(at_boundary=False)
        self.line.reset()

    def _find_baud(self) -> int:
        order = [self.config.baud] + [b for b in SEARCH_BAUDS if b != self.config.baud]
        for baud in order:
            self.set_baud(baud)
            self.discard_input()
            self._fresh_decoder()
            self.write(lms200.status_request())
            wait = REPLY_WAIT_S + 2 * transmission_ns(LONGEST_REPLY, baud) / 1e9
            # any telegram with a good CRC proves the speed, a scan of a streaming sensor too
            telegram = (lms200.Telegram, lms200.ScanTelegram)
            if self.wait_for(self._decode_raw, telegram, wait) is not None:
                log.info("laser found", baud=baud, port=self.path)
                return baud
        raise DeviceError(f"no LMS200 answers at {', '.join(map(str, order))} baud")

    def _decode_raw(self, data: bytes, read_ns: int) -> list[lms200.LmsMessage]:
        """The baud search's telegrams (nothing is set up yet: nothing is recorded)."""
        return self.decoder.feed(data)

    def _switch_baud(self, baud: int) -> None:
        self._mode(lms200.BAUD_MODES[baud], f"switch to {baud} baud")
        self.set_baud(baud)
        self.sleep(BAUD_SETTLE_S)
        self.discard_input()
        self._fresh_decoder()
        self.set_counter("baud", baud)

    def _mode(self, mode: int, what: str, data: bytes = b"") -> None:
        starts = mode == lms200.Mode.CONTINUOUS
        reply = self._request(lms200.set_mode(mode, data), what, then_streaming=starts)
        result = lms200.mode_result(reply)
        if result != lms200.ModeResult.OK:
            raise DeviceError(f"{what}: the sensor answered {result}")

    def _set_units(self, units: int) -> None:
        self._mode(lms200.Mode.INSTALLATION, "installation mode", lms200.INSTALLATION_PASSWORD)
        current = lms200.LmsConfig.unpack(
            self._request(lms200.config_request(), "read configuration").data
        )
        block = dataclasses.replace(current or lms200.LmsConfig(), units=units)
        written = lms200.parse_config_write_reply(
            self._request(lms200.set_config(block), "write configuration")
        )
        if written is None or not written[0]:
            raise DeviceError("the sensor refused the units setting")

    def _request(
        self, telegram: bytes, what: str, attempts: int = 3, *, then_streaming: bool = False
    ) -> lms200.Telegram:
        """Send a command; its reply (command + 0x80), resending after a NAK or silence.

        Scans around the reply (the last ones before a stop, the first ones after a start)
        are recorded like any other while streaming: ``then_streaming`` starts that at once.
        """
        expected = telegram[lms200.HEADER_BYTES] | 0x80
        wait = REPLY_WAIT_S + 2 * transmission_ns(LONGEST_REPLY, self.baud) / 1e9

        def decode(data: bytes, read_ns: int) -> list[lms200.LmsMessage]:
            return self._decode_reply(data, read_ns, expected, then_streaming)

        def answers(message: object) -> bool:
            return _answers(message, expected)

        for _ in range(attempts):
            self.write(telegram)
            reply = self.wait_for(decode, (lms200.Telegram, lms200.Nak), wait, answers)
            if isinstance(reply, lms200.Telegram):  # else a NAK: the command again
                if reply.command != expected:
                    raise DeviceError(f"the sensor rejected command 0x{expected & 0x7F:02x}")
                return reply
        raise DeviceError(f"{what}: no reply at {self.baud} baud")

    def _decode_reply(
        self, data: bytes, read_ns: int, expected: int, then_streaming: bool
    ) -> list[lms200.LmsMessage]:
        """A command's wait: every telegram placed on the line, and scans recorded while the
        sensor streams (from the reply on, when the command starts streaming)."""
        self.line.chunk(len(data), read_ns)
        messages = self.decoder.feed(data)
        answered = False
        for message in messages:
            if isinstance(message, lms200.ScanTelegram) and self.streaming:
                self._scan(message, read_ns)
                continue
            self.line.skip(message.wire_size)
            if not answered and _answers(message, expected):
                answered = True  # the first answer of a read is the one the wait takes
                replied = isinstance(message, lms200.Telegram) and message.command == expected
                self.streaming = self.streaming or (then_streaming and replied)
        return messages

    # ---- streaming ----------------------------------------------------------------------------
    def handle(self, data: bytes, read_ns: int) -> None:
        self.line.chunk(len(data), read_ns)
        self._decode(data, read_ns)

    def handle_reads(self, reads: list[tuple[bytes, int]]) -> None:
        """A tap's records (a scan's packets, handed over together) in one decoder call.

        Each read still bounds the frames' ends (``LinePosition`` is told of all of them
        before the bytes are decoded, which gives the same stamps as one at a time). At most
        :data:`READS_PER_FEED` reads go into one call: a backlog (a daemon held up for
        seconds) must not push a frame's reads out of what ``LinePosition`` keeps.
        """
        line = self.line
        for start in range(0, len(reads), READS_PER_FEED):
            part = reads[start : start + READS_PER_FEED]
            for data, read_ns in part:
                line.chunk(len(data), read_ns)
            # the last read brought the bytes that completed the batch: a tap hands over as
            # soon as it has a frame's worth, so that is the read of the scan's last bytes
            # (joining one read returns it as it is: no copy)
            self._decode(b"".join([d for d, _ in part]), read_ns)

    def _decode(self, data: bytes, read_ns: int) -> None:
        for message in self.decoder.feed(data):
            if isinstance(message, lms200.ScanTelegram):
                self._scan(message, read_ns)
                continue
            self.line.skip(message.wire_size)
            if isinstance(message, lms200.Telegram) and message.command == POWER_ON:
                log.warning("laser power-on telegram: it was power-cycled", port=self.path)
                raise DeviceRestarted("the sensor sent its power-on telegram (power cycle)")
            elif isinstance(message, BadFrame):
                self.bad_frame(message)
            else:
                self.good_frame()

    def _scan(self, message: lms200.ScanTelegram, read_ns: int) -> None:
        self.good_frame()
        self._in_place = 0
        size = self._scan_bytes = message.wire_size
        start_ns = self.line.end_ns(size, self.baud) - transmission_ns(size, self.baud)
        self.publish(message.to_laser_scan(self.clock.unix_ns(start_ns)), read_ns)
        # The status byte hardly ever changes: decode each value once, not 75 times a second.
        healthy = self._status_healthy.get(message.status)
        if healthy is None:
            healthy = self._status_healthy[message.status] = message.sensor_status().healthy
        if not healthy:
            self.count("status_not_ok")

    def up_detail(self) -> str:
        return f"streaming at {self.baud} baud, {self.identity.get('variant', '')}"

    def read_pause_ns(self) -> int:
        """The rest of a scan in progress, taken to be as long as the last one."""
        remaining = self._scan_bytes - self.line.pending
        return transmission_ns(remaining, self.baud) if self.line.pending and remaining > 0 else 0

    def frame_bytes(self) -> int:
        return self._scan_bytes

    def reinitialise_note(self, reason: str) -> str | None:
        """Scans stopped: a power cycle puts the sensor back at 9600 baud, where its power-on
        telegram cannot be read at a higher speed; so search and set it up again in place,
        a few times, before giving the port up."""
        if not self.streaming or self._in_place >= MAX_IN_PLACE:
            return None
        self._in_place += 1
        return "in place: a power cycle restarts an LMS200 at 9600 baud"

    def shutdown(self) -> None:
        """Stop streaming and put the sensor back to 9600 baud, where it powers up."""
        if self.streaming:
            self._mode(lms200.Mode.REQUEST, "stop continuous output")
        if self.config.restore_9600 and self.baud != 9600:
            self._mode(lms200.Mode.BAUD_9600, "switch to 9600 baud")
            self.set_baud(9600)
        self.streaming = False


def _answers(message: object, expected: int) -> bool:
    """Whether ``message`` answers a command whose reply is ``expected``: the reply, the
    sensor's "invalid command", or a NAK (the command was garbled on its way)."""
    if isinstance(message, lms200.Telegram):
        return message.from_sensor and message.command in (
            expected,
            lms200.Reply.INVALID_COMMAND,
        )
    return isinstance(message, lms200.Nak)
