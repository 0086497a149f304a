"""``baromap devices [--udev-rules]``: what serial devices are attached, and stable names.

The listing shows each port with its USB identity ``vid:pid:serial``, which the daemon's
configuration accepts in place of a path. ``--udev-rules`` prints rules giving devices stable
names: ``--name laser=/dev/ttyUSB0`` says which attached device plays which role (laser, base,
barometer); without names, a rule is printed for each USB serial device with a name made of
its identity, to be renamed by hand. Each tty rule comes with one for the USB device itself,
which lets the daemon reset a wedged adapter (``usb_reset = true`` in a device's table).
"""

from __future__ import annotations

import argparse
from typing import Any


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "devices", help="list attached serial/USB devices; print udev rules for stable names"
    )
    parser.add_argument(
        "--udev-rules", action="store_true", help="print udev rules instead of the listing"
    )
    parser.add_argument(
        "--name",
        action="append",
        default=[],
        metavar="ROLE=PORT",
        help="with --udev-rules: the device at PORT is the laser, base or barometer",
    )
    parser.set_defaults(run=run)


def _assignments(pairs: list[str]) -> dict[str, str]:
    from baromap.discovery import STABLE_NAMES
    from baromap.errors import ConfigError

    out: dict[str, str] = {}
    for pair in pairs:
        role, sep, port = pair.partition("=")
        if not sep or role not in STABLE_NAMES or not port:
            roles = ", ".join(STABLE_NAMES)
            raise ConfigError(f"--name {pair!r}: expected ROLE=PORT with ROLE one of {roles}")
        out[port] = role
    return out


def run(args: argparse.Namespace) -> int:
    from baromap.discovery import STABLE_NAMES, list_serial_devices, udev_rule, usb_reset_rule
    from baromap.errors import ConfigError

    devices = list_serial_devices()
    if not args.udev_rules:
        if args.name:
            raise ConfigError("--name only goes with --udev-rules")
        if not devices:
            print("no serial devices attached")
            return 0
        for device in devices:
            identity = str(device.usb) if device.usb else "-"
            what = " ".join(p for p in (device.manufacturer, device.product) if p)
            print(f"{device.path:16s} {identity:28s} {what or device.description}")
        return 0
    roles = _assignments(args.name)
    by_path = {d.path: d for d in devices}
    unknown = sorted(set(roles) - set(by_path))
    if unknown:
        raise ConfigError(f"not an attached serial device: {', '.join(unknown)}")
    usb = [d for d in devices if d.usb is not None]
    if not usb:
        print("# no USB serial devices attached: nothing to name")
        return 0
    print("# baromap udev rules: install as /etc/udev/rules.d/99-baromap.rules")
    for device in usb:
        role = roles.get(device.path)
        assert device.usb is not None
        name = STABLE_NAMES[role] if role else f"baromap-{device.usb.vid:04x}-{device.usb.pid:04x}"
        if role is None and device.usb.serial:
            name += f"-{device.usb.serial}"
        print(f"# {device.path}: {role or 'unassigned (rename, or pass --name ROLE=PATH)'}")
        print(udev_rule(device, name))
        print(usb_reset_rule(device))  # the daemon's usb_reset (a wedged adapter)
    return 0
