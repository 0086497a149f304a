"""Serial devices attached to this machine, and USB identities resolved to their ports.

A USB serial adapter gets whatever ``/dev/ttyUSBn`` is free when it is plugged in, so the
daemon's configuration can name a device by its USB identity ``vid:pid[:serial]`` instead, and
udev rules can give each a stable name. Both need the same facts: which tty belongs to which
USB device. pyserial's port list reads them from sysfs (``idVendor``, ``idProduct``,
``serial``) without opening any device, which also works inside the daemon's hardened unit
(``DevicePolicy=closed`` allows the tty classes, not ``/dev/bus/usb``), where libusb could not
open the raw USB devices.

The one thing that needs the raw USB device is a reset: a USB serial adapter that stops
answering after its port was closed and opened again (a wedged FTDI or CH340) comes back as
if replugged after a USB port reset, which pyusb (libusb) asks of the kernel. It needs write
access to ``/dev/bus/usb/...``, which the rules ``baromap devices --udev-rules`` prints give.
"""

from __future__ import annotations

import errno
import os
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Final

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


#: What to do about a permission error on a device (its tty or its USB device node).
UDEV_HINT: Final = (
    "install baromap's udev rules: `baromap devices --udev-rules --name ROLE=PORT > "
    "/etc/udev/rules.d/99-baromap.rules`, then `udevadm control --reload && udevadm trigger`, "
    "and be in the group dialout"
)


def permission_hint(error: BaseException) -> str:
    """The udev advice when ``error`` is a permission error (EACCES/EPERM), else ''."""
    code = getattr(error, "errno", None)
    if code in (errno.EACCES, errno.EPERM) or "Permission denied" in str(error):
        return f"permission denied: {UDEV_HINT}"
    return ""


def serial_device_at(
    path: str, devices: Iterable[SerialDevice] | None = None
) -> SerialDevice | None:
    """The attached serial device whose port is ``path`` (a udev symlink is followed)."""
    real = os.path.realpath(path)
    found = list_serial_devices() if devices is None else devices
    return next((d for d in found if os.path.realpath(d.path) == real), None)


def _bus_and_ports(location: str | None) -> tuple[int, tuple[int, ...]] | None:
    """sysfs' USB location ``1-1.2`` (or ``1-1.2:1.0``) as (bus 1, port path (1, 2))."""
    if not location:
        return None
    match = re.fullmatch(r"(\d+)-([\d.]+)(?::[\d.]+)?", location)
    if match is None:
        return None
    return int(match[1]), tuple(int(p) for p in match[2].split("."))


def reset_usb_adapter(
    path: str,
    devices: Iterable[SerialDevice] | None = None,
    find: Callable[..., Any] | None = None,
) -> SerialDevice:
    """Reset the USB device behind the serial port ``path``, as if it had been replugged.

    The device is the one at the port's USB location (bus and port path) when sysfs gives
    it, else the only one with the port's vendor, product and serial number. Raises
    :class:`DeviceError` when ``path`` is no USB device, none or several match, or the reset
    fails (a permission error names the udev rules to install). ``find`` is pyusb's
    ``usb.core.find`` unless given (tests).
    """
    device = serial_device_at(path, devices)
    if device is None or device.usb is None:
        raise DeviceError(f"{path} is not a USB serial adapter: there is nothing to reset")
    identity = device.usb
    if find is None:
        import usb.core

        find = usb.core.find
    place = _bus_and_ports(device.location)
    try:
        candidates = list(find(find_all=True, idVendor=identity.vid, idProduct=identity.pid))
        if place is not None:
            candidates = [c for c in candidates if (c.bus, tuple(c.port_numbers or ())) == place]
        elif identity.serial is not None:
            candidates = [c for c in candidates if c.serial_number == identity.serial]
        if len(candidates) != 1:
            raise DeviceError(
                f"{len(candidates)} USB devices match {identity} at {device.location or '?'}: "
                "not resetting"
            )
        candidates[0].reset()
    except DeviceError:
        raise
    except Exception as exc:  # pyusb's USBError, NoBackendError, or sysfs going away meanwhile
        hint = permission_hint(exc)
        if not hint and type(exc).__name__ == "NoBackendError":
            hint = "pyusb finds no libusb: install libusb-1.0-0"
        detail = f"; {hint}" if hint else ""
        raise DeviceError(f"cannot reset {identity} ({path}): {exc}{detail}") from exc
    return device


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


def usb_reset_rule(device: SerialDevice) -> str:
    """The udev rule that lets group dialout reset ``device`` (its ``/dev/bus/usb`` node)."""
    if device.usb is None:
        raise DeviceError(f"{device.path} is not a USB device")
    match = f'ATTR{{idVendor}}=="{device.usb.vid:04x}", ATTR{{idProduct}}=="{device.usb.pid:04x}"'
    if device.usb.serial:
        match += f', ATTR{{serial}}=="{device.usb.serial}"'
    return f'SUBSYSTEM=="usb", ENV{{DEVTYPE}}=="usb_device", {match}, GROUP="dialout", MODE="0660"'
