"""Serial devices attached to this machine, and USB identities resolved to their ports.

A USB serial adapter gets whatever ``/dev/ttyUSBn`` is free when it is plugged in, so the
daemon's configuration can name a device by its USB identity ``vid:pid[:serial]`` instead, and
udev rules can give each a stable name. Both need the same facts: which tty belongs to which
USB device. pyserial's port list reads them from sysfs (``idVendor``, ``idProduct``,
``serial``) without opening any device, which also works inside the daemon's hardened unit
(``DevicePolicy=closed`` allows the tty classes, not ``/dev/bus/usb``), where libusb could not
open the raw USB devices.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Final

from serial.tools import list_ports

from baromap.errors import ConfigError, DeviceError

USB_IDENTITY: Final = re.compile(
    r"^(?P<vid>[0-9a-fA-F]{4}):(?P<pid>[0-9a-fA-F]{4})(?::(?P<serial>.+))?$"
)
#: Names the udev rules give, by the role a device plays for baromap.
STABLE_NAMES: Final = {
    "laser": "baromap-laser",
    "base": "baromap-base",
    "barometer": "baromap-baro",
}


@dataclass(frozen=True, slots=True)
class UsbIdentity:
    vid: int
    pid: int
    serial: str | None = None

    def __str__(self) -> str:
        text = f"{self.vid:04x}:{self.pid:04x}"
        return f"{text}:{self.serial}" if self.serial else text


@dataclass(frozen=True, slots=True)
class SerialDevice:
    """One serial port; the USB fields are None for ports that are not USB devices."""

    path: str
    description: str = ""
    usb: UsbIdentity | None = None
    manufacturer: str | None = None
    product: str | None = None
    location: str | None = None


def parse_usb_identity(text: str) -> UsbIdentity | None:
    """``vid:pid[:serial]`` (hex) as a :class:`UsbIdentity`, or None if ``text`` is not one."""
    match = USB_IDENTITY.match(text.strip())
    if match is None:
        return None
    return UsbIdentity(int(match["vid"], 16), int(match["pid"], 16), match["serial"])


def list_serial_devices() -> list[SerialDevice]:
    """Serial ports of this machine (USB adapters with their identity), sorted by path."""
    out = []
    for port in list_ports.comports():
        usb = None
        if port.vid is not None and port.pid is not None:
            usb = UsbIdentity(port.vid, port.pid, port.serial_number or None)
        out.append(
            SerialDevice(
                path=port.device,
                description=port.description if port.description != "n/a" else "",
                usb=usb,
                manufacturer=port.manufacturer,
                product=port.product,
                location=port.location,
            )
        )
    return sorted(out, key=lambda d: d.path)


def matching(identity: UsbIdentity, devices: list[SerialDevice]) -> list[SerialDevice]:
    return [
        d
        for d in devices
        if d.usb is not None
        and d.usb.vid == identity.vid
        and d.usb.pid == identity.pid
        and (identity.serial is None or d.usb.serial == identity.serial)
    ]


def resolve_port(spec: str, devices: list[SerialDevice] | None = None) -> str:
    """Where to open ``spec``: a path or pyserial URL as given; a USB identity looked up now.

    Looked up at every (re)connection, so a device replugged into another USB socket, which
    comes back as another ``/dev/ttyUSBn``, is found again. Raises :class:`DeviceError` when
    no attached device matches, and when several do (add the serial number to tell them apart).
    """
    identity = parse_usb_identity(spec)
    if identity is None:
        if not spec.strip():
            raise ConfigError("empty port")
        return spec
    found = matching(identity, list_serial_devices() if devices is None else devices)
    if not found:
        raise DeviceError(f"no serial device with USB identity {identity} is attached")
    if len(found) > 1:
        paths = ", ".join(d.path for d in found)
        raise DeviceError(
            f"USB identity {identity} matches {len(found)} devices ({paths}); "
            "add the serial number: vid:pid:serial"
        )
    return found[0].path


def udev_rule(device: SerialDevice, name: str) -> str:
    """One udev rule giving ``device`` the stable name ``/dev/<name>`` (group dialout)."""
    if device.usb is None:
        raise DeviceError(f"{device.path} is not a USB device: udev cannot match it by identity")
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
        raise ConfigError(f"{name!r} is not a usable device name")
    match = f'ATTRS{{idVendor}}=="{device.usb.vid:04x}", ATTRS{{idProduct}}=="{device.usb.pid:04x}"'
    if device.usb.serial:
        match += f', ATTRS{{serial}}=="{device.usb.serial}"'
    return f'SUBSYSTEM=="tty", {match}, SYMLINK+="{name}", GROUP="dialout", MODE="0660"'
