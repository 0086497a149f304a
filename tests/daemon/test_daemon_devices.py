"""Device discovery: USB identities resolved to ports, and udev rules for stable names."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from baromap import discovery
from baromap.cli.main import main
from baromap.discovery import SerialDevice, UsbIdentity, parse_usb_identity, resolve_port
from baromap.errors import DeviceError

FTDI_A = SerialDevice("/dev/ttyUSB0", usb=UsbIdentity(0x0403, 0x6001, "A1LASER1"))
FTDI_B = SerialDevice("/dev/ttyUSB1", usb=UsbIdentity(0x0403, 0x6001, "A1BASE01"))
UNO = SerialDevice("/dev/ttyACM0", usb=UsbIdentity(0x2341, 0x0043, "8503"))
ONBOARD = SerialDevice("/dev/ttyS0")


def test_identities_parse() -> None:
    assert parse_usb_identity("0403:6001:A1LASER1") == UsbIdentity(0x0403, 0x6001, "A1LASER1")
    assert parse_usb_identity("2341:0043") == UsbIdentity(0x2341, 0x0043, None)
    assert parse_usb_identity("/dev/ttyUSB0") is None
    assert str(UsbIdentity(0x403, 0x6001, "X")) == "0403:6001:X"


def test_paths_pass_and_identities_resolve() -> None:
    attached = [FTDI_A, FTDI_B, UNO, ONBOARD]
    assert resolve_port("/dev/baromap-laser", attached) == "/dev/baromap-laser"
    assert resolve_port("loop://", attached) == "loop://"
    assert resolve_port("0403:6001:A1BASE01", attached) == "/dev/ttyUSB1"
    assert resolve_port("2341:0043", attached) == "/dev/ttyACM0"
    with pytest.raises(DeviceError, match="matches 2 devices"):
        resolve_port("0403:6001", attached)
    with pytest.raises(DeviceError, match="no serial device"):
        resolve_port("0403:6001:GONE", attached)


def test_a_udev_rule_names_the_device_by_identity() -> None:
    rule = discovery.udev_rule(FTDI_A, "baromap-laser")
    assert rule == (
        'SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", ATTRS{idProduct}=="6001", '
        'ATTRS{serial}=="A1LASER1", SYMLINK+="baromap-laser", GROUP="dialout", MODE="0660"'
    )
    with pytest.raises(DeviceError):
        discovery.udev_rule(ONBOARD, "baromap-base")


@pytest.fixture
def attached(monkeypatch: pytest.MonkeyPatch) -> None:
    ports = [
        SimpleNamespace(device="/dev/ttyUSB0", vid=0x0403, pid=0x6001, serial_number="A1LASER1",
                        description="FT232R", manufacturer="FTDI", product="FT232R USB UART",
                        location="1-1"),
        SimpleNamespace(device="/dev/ttyACM0", vid=0x2341, pid=0x0043, serial_number="8503",
                        description="Uno", manufacturer="Arduino", product="Uno", location="1-2"),
        SimpleNamespace(device="/dev/ttyS0", vid=None, pid=None, serial_number=None,
                        description="n/a", manufacturer=None, product=None, location=None),
    ]  # fmt: skip
    monkeypatch.setattr(discovery.list_ports, "comports", lambda: ports)


def test_baromap_devices_lists_identities(
    attached: None, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["devices"]) == 0
    out = capsys.readouterr().out
    assert "/dev/ttyUSB0" in out and "0403:6001:A1LASER1" in out and "FTDI" in out
    assert "/dev/ttyS0" in out


def test_baromap_devices_prints_udev_rules(
    attached: None, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["devices", "--udev-rules", "--name", "laser=/dev/ttyUSB0"]) == 0
    out = capsys.readouterr().out
    assert 'SYMLINK+="baromap-laser"' in out
    assert 'ATTRS{serial}=="A1LASER1"' in out
    assert 'SYMLINK+="baromap-2341-0043-8503"' in out  # unassigned: named by identity
    assert "ttyS0" not in out  # not USB: udev cannot match it by identity


def test_a_bad_name_is_one_error_line(attached: None, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["devices", "--udev-rules", "--name", "laser=/dev/ttyUSB9"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "/dev/ttyUSB9" in err
