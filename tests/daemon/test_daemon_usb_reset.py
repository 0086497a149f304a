"""A wedged USB serial adapter reset through pyusb (``usb_reset``), and permission errors that
say which udev rules to install.

pyusb's ``find`` is replaced by a fake that lists USB devices with the attributes pyusb gives
(bus, port path, serial number) and records resets: no test here needs a USB device.
"""

from __future__ import annotations

import errno
import os
import time
from dataclasses import dataclass, field
from typing import Any

import pytest
import serial

from baromap import discovery
from baromap.cli.main import main
from baromap.discovery import SerialDevice, UsbIdentity, reset_usb_adapter
from baromap.errors import DeviceError
from baromap.messages import DeviceState
from baromapd.clock import HostClock
from baromapd.config import Retry, parse_config
from baromapd.session import DeviceSession

LASER = SerialDevice("/dev/ttyUSB0", usb=UsbIdentity(0x0403, 0x6001, "A1LASER1"), location="1-1.2")
BASE = SerialDevice("/dev/ttyUSB1", usb=UsbIdentity(0x0403, 0x6001, "A1BASE01"), location="1-1.3")
ONBOARD = SerialDevice("/dev/ttyS0")


@dataclass
class FakeUsbDevice:
    bus: int
    port_numbers: tuple[int, ...]
    serial_number: str
    error: Exception | None = None
    resets: list[float] = field(default_factory=list)

    def reset(self) -> None:
        if self.error is not None:
            raise self.error
        self.resets.append(time.monotonic())


class FakeFind:
    def __init__(self, *devices: FakeUsbDevice) -> None:
        self.devices = devices

    def __call__(self, **match: Any) -> list[FakeUsbDevice]:
        assert match == {"find_all": True, "idVendor": 0x0403, "idProduct": 0x6001}
        return list(self.devices)


def test_the_adapter_at_the_ports_usb_location_is_reset() -> None:
    laser, base = FakeUsbDevice(1, (1, 2), "A1LASER1"), FakeUsbDevice(1, (1, 3), "A1BASE01")
    found = reset_usb_adapter("/dev/ttyUSB1", [LASER, BASE], FakeFind(laser, base))
    assert found is BASE
    assert len(base.resets) == 1 and not laser.resets


def test_without_a_location_the_serial_number_decides() -> None:
    laser, base = FakeUsbDevice(1, (1, 2), "A1LASER1"), FakeUsbDevice(1, (1, 3), "A1BASE01")
    unplaced = SerialDevice("/dev/ttyUSB0", usb=LASER.usb)
    reset_usb_adapter("/dev/ttyUSB0", [unplaced], FakeFind(laser, base))
    assert len(laser.resets) == 1 and not base.resets


def test_nothing_is_reset_when_the_port_is_no_usb_device_or_the_match_is_unclear() -> None:
    twins = FakeUsbDevice(1, (1, 2), "X"), FakeUsbDevice(1, (1, 3), "X")
    with pytest.raises(DeviceError, match="not a USB serial adapter"):
        reset_usb_adapter("/dev/ttyS0", [ONBOARD], FakeFind(*twins))
    with pytest.raises(DeviceError, match="2 USB devices match"):
        anonymous = SerialDevice("/dev/ttyUSB0", usb=UsbIdentity(0x0403, 0x6001))
        reset_usb_adapter("/dev/ttyUSB0", [anonymous], FakeFind(*twins))
    assert not any(d.resets for d in twins)


def test_a_permission_error_names_the_udev_rules() -> None:
    denied = FakeUsbDevice(1, (1, 2), "A1LASER1", error=OSError(errno.EACCES, "Access denied"))
    with pytest.raises(DeviceError, match=r"baromap devices --udev-rules"):
        reset_usb_adapter("/dev/ttyUSB0", [LASER], FakeFind(denied))
    assert discovery.permission_hint(OSError(errno.EIO, "I/O error")) == ""


class Flaky(DeviceSession):
    """Answers its handshake ``answers`` times, then never again (a wedged adapter); no data
    ever comes, so each connection ends by silence."""

    def __init__(self, answers: int, **kwargs: Any) -> None:
        self.master, self.slave = os.openpty()
        super().__init__("flaky", port=os.ttyname(self.slave), baud=9600, clock=HostClock(),
                         publish=lambda m, ns: None, resolve=lambda p: p,
                         retry=Retry(initial_s=0.05, max_s=0.1, silence_s=0.2, garbage_s=0.2),
                         **kwargs)  # fmt: skip
        self.answers = answers

    def handshake(self) -> None:
        if self.answers <= 0:
            raise DeviceError("no answer")
        self.answers -= 1

    def handle(self, data: bytes, read_ns: int) -> None:
        pass

    def close_pty(self) -> None:
        os.close(self.master)
        os.close(self.slave)


def _run(session: Flaky, until: str) -> dict[str, int]:
    session.start()
    try:
        deadline = time.monotonic() + 5
        while session.health(0).counters.get(until, 0) < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        session.stop()
        session.close_pty()
    return session.health(0).counters


@pytest.mark.parametrize("enabled", [True, False])
def test_a_device_that_stops_answering_after_a_reconnect_gets_its_adapter_reset(
    enabled: bool,
) -> None:
    resets: list[str] = []
    session = Flaky(1, usb_reset=enabled, reset_adapter=resets.append)
    path = session.port_spec
    counters = _run(session, "failures")
    assert counters["connects"] == 1 and counters["failures"] >= 2
    if enabled:  # the first failure was the silence of a device that had answered: no reset
        assert resets and set(resets) == {path}
        assert counters["usb_resets"] == len(resets) == counters["failures"] - 1
    else:
        assert not resets and "usb_resets" not in counters


def test_a_device_that_never_answered_is_not_reset() -> None:
    resets: list[str] = []
    counters = _run(Flaky(0, usb_reset=True, reset_adapter=resets.append), "failures")
    assert counters["failures"] >= 2 and not resets


def test_a_failed_reset_is_counted_and_the_session_goes_on() -> None:
    def fail(path: str) -> None:
        raise DeviceError(f"cannot reset {path}: permission denied")

    counters = _run(Flaky(1, usb_reset=True, reset_adapter=fail), "usb_reset_failed")
    assert counters["usb_reset_failed"] >= 2 and "usb_resets" not in counters


def test_a_port_without_permission_says_which_udev_rules(monkeypatch: pytest.MonkeyPatch) -> None:
    def denied(url: str, **kwargs: Any) -> None:
        raise serial.SerialException(errno.EACCES, f"could not open port {url}: Permission denied")

    monkeypatch.setattr(serial, "serial_for_url", denied)
    session = Flaky(1)
    session.start()
    try:
        deadline = time.monotonic() + 5
        while session.state is not DeviceState.DOWN and time.monotonic() < deadline:
            time.sleep(0.02)
        detail = session.health(0).detail
    finally:
        session.stop()
        session.close_pty()
    assert "permission denied" in detail and "baromap devices --udev-rules" in detail


def test_usb_reset_is_a_device_setting_off_by_default() -> None:
    config = parse_config(
        'robot = "r"\n[laser]\nport = "/dev/x"\nusb_reset = true\n[base]\nport = "/dev/y"\n'
    )
    assert config.laser is not None and config.laser.usb_reset
    assert config.base is not None and not config.base.usb_reset


def test_the_udev_rules_let_the_daemon_reset_each_adapter(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(discovery, "list_serial_devices", lambda: [LASER, ONBOARD])
    assert main(["devices", "--udev-rules", "--name", "laser=/dev/ttyUSB0"]) == 0
    out = capsys.readouterr().out
    assert (
        'SUBSYSTEM=="usb", ENV{DEVTYPE}=="usb_device", ATTR{idVendor}=="0403", '
        'ATTR{idProduct}=="6001", ATTR{serial}=="A1LASER1", GROUP="dialout", MODE="0660"'
    ) in out
