"""The Pioneer (P2OS / ARCOS) session: SYNC0-2, model check, OPEN, PULSE, SIPs to odometry.

The robot names itself in the SYNC2 echo (name, class, subclass) and the subclass decides the
conversion factors, as ARIA and p2os_driver do: a P3-AT with an ARCOS controller (``p3at-sh``)
counts millimetres, an old P2OS one (``p3at``) counts 0.465 mm, and the wrong set silently
scales every map. So by default the model is taken from the subclass; a model pinned in the
configuration that differs from what the robot reports is refused naming both, unless
``allow_model_mismatch`` says it is deliberate.

Motors are never enabled unless configured: the daemon records, the operator drives. A robot
still open from a client that died answers SYNC0 with SIPs; the session then sends CLOSE and
syncs again (p2os_driver's way). PULSE goes out after 500 ms without another command, well
inside the robot's 2 s watchdog.

However a connection ends (a stop, SIGTERM, a failure, an exception in the session), a session
that enabled the motors sends STOP and ENABLE 0, waits briefly for a SIP that says the motors
are off, then CLOSE: disabling the motors is the last command before the session closes. A
port that is gone takes no command; that is counted (``motors_off_failed``) and logged, and
the robot's own watchdog (``watchdog_ms`` of its CONFIG) stops it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Final

import serial
import structlog

from baromap.errors import ConfigError, DeviceError
from baromap.odometry.integrator import OdometryIntegrator
from baromap.odometry.robot_metadata import ROBOT_METADATA, robot_metadata
from baromap.protocols import p2os
from baromap.protocols.framing import BadFrame
from baromap.protocols.robot_models import RobotModel, find_model, select_model
from baromapd.clock import LinePosition, transmission_ns
from baromapd.config import BaseConfig
from baromapd.session import DeviceRefused, DeviceSession

log = structlog.get_logger(__name__)

PULSE_EVERY_S: Final = 0.5
ECHO_WAIT_S: Final = 0.6
SYNC_ATTEMPTS: Final = 4
#: Drivers give the robot this long to answer CONFIG; older firmware may not.
CONFIG_WAIT_S: Final = 1.0
FIRST_SIP_WAIT_S: Final = 1.5
#: After ENABLE 0, how long to wait for a SIP that says the motors are off (two SIP cycles).
MOTORS_OFF_WAIT_S: Final = 0.3


def choose_model(subclass: str, configured: str, allow_mismatch: bool) -> tuple[RobotModel, str]:
    """The model to integrate odometry with, and a note for health and metadata.

    ``configured`` is "auto" (the robot's subclass decides, as in ARIA) or a model name.
    :func:`~baromap.protocols.robot_models.select_model` makes the choice; its refusals (a
    pinned model the robot contradicts, a subclass without a parameter set) become
    :class:`DeviceRefused`, retried at the longest delay: restarting cannot change them.
    """
    pinned = None if configured == "auto" else configured
    try:
        model = select_model(subclass, pinned, allow_mismatch=allow_mismatch)
    except ConfigError as exc:
        raise DeviceRefused(f"{exc} (base.model, base.allow_model_mismatch)") from None
    reported = find_model(subclass)
    if pinned is None:
        return model, f"model {model.name} from the robot's subclass {subclass!r}"
    if reported is model:
        return model, f"model {model.name}, as configured and reported"
    note = f"configured model {model.name} overrides the reported subclass {subclass!r}"
    log.warning("robot model mismatch allowed by configuration", detail=note)
    return model, note


def model_source(model: RobotModel, subclass: str, configured: str) -> str:
    """Where the model came from, as the ``baromap.robot`` record says it: the robot's own
    subclass, a configuration the robot agrees with, or a configuration overriding it."""
    if configured == "auto":
        return "reported"
    return "configured" if find_model(subclass) is model else "override"


class PioneerSession(DeviceSession):
    shutdown_on_every_end = True  # the motors are disabled however the connection ends

    def __init__(self, config: BaseConfig, **kwargs: Any) -> None:
        super().__init__(
            "base",
            port=config.port,
            baud=config.baud,
            retry=config.retry,
            usb_reset=config.usb_reset,
            **kwargs,
        )
        self.config = config
        self.decoder = p2os.Decoder()
        self.integrator: OdometryIntegrator | None = None
        self.model: RobotModel | None = None
        self.line = LinePosition()
        self._session_open = False
        self._sips_seen = 0
        self._sip_bytes = 0  # the last SIP's size on the line: what a SIP in progress needs

    # ---- handshake ----------------------------------------------------------------------------
    def handshake(self) -> None:
        self._session_open = False
        self._sips_seen = 0
        self.set_baud(self.config.baud)
        self.discard_input()
        self.decoder = p2os.Decoder()
        info = self._sync()
        model, note = choose_model(
            info.subclass, self.config.model, self.config.allow_model_mismatch
        )
        self.model = model
        if self.integrator is None:
            self.integrator = OdometryIntegrator(model)
        else:
            # one odom frame across reconnects: the counters go on, or are joined at the last
            # pose if the robot counts from zero again (power-cycled)
            self.integrator.resume(model)
        self.records[ROBOT_METADATA] = robot_metadata(
            model,
            (info.name, info.robot_class, info.subclass),
            model_source(model, info.subclass, self.config.model),
        )
        self.line.reset()
        self.write(p2os.open_controller())
        self._session_open = True
        self.write(p2os.pulse())
        self.write(p2os.config_request())
        config = self.wait_for(self._packets, p2os.ConfigPacket, CONFIG_WAIT_S)
        if self.config.enable_motors:
            self.write(p2os.enable_motors(True))
        if (
            not self._sips_seen
            and self.wait_for(self._packets, p2os.StandardSip, FIRST_SIP_WAIT_S) is None
        ):
            raise DeviceError("no SIP after OPEN")
        self.identity = {
            "device": "Pioneer (P2OS/ARCOS)",
            "name": info.name,
            "class": info.robot_class,
            "subclass": info.subclass,
            "model": model.name,
            "dist_conv_factor": repr(model.dist_conv_factor),
            "model_note": note,
            "motors_enabled": str(self.config.enable_motors).lower(),
            "port": self.path,
        }
        if config is not None:
            for key in ("serial_number", "firmware_version", "watchdog_ms", "sip_cycle_ms"):
                value = config.get(key)
                if value is not None:
                    self.identity[key] = str(value)
        self.line.reset()  # the decoder stays: in sync, and the next SIP may be half in it

    def _sync(self) -> p2os.Sync2Info:
        for _ in range(SYNC_ATTEMPTS):
            self.write(p2os.sync(0))
            # an open robot streams SIPs instead of echoing
            answer = self.wait_for(
                self._decode, (p2os.SyncEcho, p2os.StandardSip), ECHO_WAIT_S, _echo_of(0)
            )
            if isinstance(answer, p2os.StandardSip):
                log.info("robot still open from an earlier client: closing it", port=self.path)
                self.write(p2os.close_controller())
                self.sleep(0.3)
                self.discard_input()
                self.decoder = p2os.Decoder()
                continue
            if answer is None:
                continue
            self.write(p2os.sync(1))
            if self.wait_for(self._decode, p2os.SyncEcho, ECHO_WAIT_S, _echo_of(1)) is None:
                continue
            self.write(p2os.sync(2))
            # a robot with strings answers SYNC2 with them, one without echoes it
            info = self.wait_for(
                self._decode, (p2os.Sync2Info, p2os.SyncEcho), ECHO_WAIT_S, _echo_of(2)
            )
            if isinstance(info, p2os.Sync2Info):
                return info
        raise DeviceError(f"no SYNC handshake at {self.baud} baud")

    def _decode(self, data: bytes, read_ns: int) -> list[p2os.P2osMessage]:
        """The SYNC handshake's packets (a SIP there is not odometry: no session is open)."""
        return self.decoder.feed(data)

    def _packets(self, data: bytes, read_ns: int) -> list[p2os.P2osMessage]:
        """Decode, count, and publish the SIPs as odometry stamped when they were sent."""
        self.line.chunk(len(data), read_ns)
        out: list[p2os.P2osMessage] = []
        for message in self.decoder.feed(data):
            size = message.wire_size
            if isinstance(message, BadFrame):
                self.line.skip(size)
                self.bad_frame(message)
                continue
            self.good_frame()
            out.append(message)
            if not isinstance(message, p2os.StandardSip):
                self.line.skip(size)
                continue
            # The robot sends its pose as it takes it; at 9600 baud a SIP is ~40 ms of line.
            self._sip_bytes = size
            end = self.line.end_ns(size, self.baud)
            self._odometry(message, end - transmission_ns(size, self.baud), read_ns)
        return out

    # ---- streaming ----------------------------------------------------------------------------
    def handle(self, data: bytes, read_ns: int) -> None:
        self._packets(data, read_ns)

    def _odometry(self, sip: p2os.StandardSip, sent_ns: int, read_ns: int) -> None:
        if self.integrator is None:
            return
        self.good_frame()
        self._sips_seen += 1
        self.set_counter("battery_dv", round(sip.battery_v * 10))
        odometry = self.integrator.update(sip, self.clock.unix_ns(sent_ns))
        self.set_counter("odometry_tracks_joined", self.integrator.tracks_joined)
        self.publish(odometry, read_ns)

    def up_detail(self) -> str:
        info = self.identity
        return f"streaming; {info.get('model_note', '')} (robot {info.get('name', '?')!r})"

    def read_pause_ns(self) -> int:
        """The rest of a SIP in progress, taken to be as long as the last one."""
        remaining = self._sip_bytes - self.line.pending
        return transmission_ns(remaining, self.baud) if self.line.pending and remaining > 0 else 0

    def keepalive(self) -> None:
        if self._session_open and self.since_write_s() >= PULSE_EVERY_S:
            self.write(p2os.pulse())

    def shutdown(self) -> None:
        """STOP, ENABLE 0 and a SIP that confirms it (motors enabled by this session), CLOSE."""
        if not self._session_open:
            return
        self._session_open = False
        try:
            if self.config.enable_motors:
                self.write(p2os.stop())
                self.write(p2os.enable_motors(False))
                off = self.wait_for(self._packets, p2os.StandardSip, MOTORS_OFF_WAIT_S, _motors_off)
                confirmed = off is not None
                self.count("motors_off")
                if confirmed:
                    self.count("motors_off_confirmed")
                log.info("motors disabled", device=self.name, confirmed_by_robot=confirmed)
            self.write(p2os.close_controller())
        except (serial.SerialException, OSError, DeviceError) as exc:
            if self.config.enable_motors:
                self.count("motors_off_failed")
                log.warning(
                    "cannot disable the motors: the port is gone; the robot's watchdog stops it",
                    device=self.name,
                    error=str(exc),
                    watchdog_ms=self.identity.get("watchdog_ms", "?"),
                )
            else:
                log.debug("cannot close the robot's session", device=self.name, error=str(exc))


def _motors_off(sip: p2os.StandardSip) -> bool:
    return not sip.motors_enabled


def _echo_of(step: int) -> Callable[[object], bool]:
    """Accepts the echo of SYNC``step`` and any packet that is not an echo."""
    return lambda packet: not isinstance(packet, p2os.SyncEcho) or packet.step == step
