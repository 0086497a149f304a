"""The hardware tests' pytest options, as a plugin pytest loads before it reads the command line.

``pytest -m hardware --lms-port /dev/ttyUSB0`` needs ``--lms-port`` known when pytest first
splits its arguments: an option declared in a conftest is not, so its value is taken for a
test path and pytest stops with "unrecognized arguments". The package's ``pytest11`` entry
point loads this module before the final parse (the root ``conftest.py`` names it too, for a
checkout whose environment was installed without the entry point).

pytest also picks its rootdir and ini file from the paths on the command line before any
plugin is loaded, so an existing port path outside the checkout (``/dev/ttyUSB0``) roots the
run at ``/dev`` with no ini file: no ``addopts``, markers, ``testpaths`` or timeout. When a
port option's value is what misled it, :func:`pytest_load_initial_conftests` decides them
again from the arguments as now parsed (pytest-dev/pytest#8846 is the upstream report).
"""

from __future__ import annotations

from typing import Final

import pytest

#: Option -> what it names. The device tests skip, saying which option to pass, without it.
HARDWARE_OPTIONS: Final = {
    "--baro-port": "serial port (or URL) of a real barometer board",
    "--lms-port": "serial port of a real SICK LMS200",
    "--p2os-port": "serial port of a real Pioneer base",
}


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("baromap hardware", "opt-in tests against real devices")
    for option, help_text in HARDWARE_OPTIONS.items():
        group.addoption(option, default=None, metavar="PATH", help=help_text)
    group.addoption(
        "--allow-motion",
        action="store_true",
        default=False,
        help="let the Pioneer tests move the base (10 cm at 100 mm/s, bounded by a timeout)",
    )
    group.addoption(
        "--hil-seconds",
        type=float,
        default=3.0,
        metavar="S",
        help="how long each hardware test streams (default 3 s)",
    )
    group.addoption(
        "--lms-baud",
        type=int,
        default=38400,
        help="the LMS200 speed the tests configure (38400 on RS-232, 500000 on RS-422)",
    )


def _port_values(config: pytest.Config) -> list[str]:
    namespace = config.known_args_namespace
    names = [option.lstrip("-").replace("-", "_") for option in HARDWARE_OPTIONS]
    return [str(v) for v in (getattr(namespace, name, None) for name in names) if v]


@pytest.hookimpl(tryfirst=True)
def pytest_load_initial_conftests(
    early_config: pytest.Config, parser: pytest.Parser, args: list[str]
) -> None:
    """Root the run where pytest would have without the port paths (see the module's doc)."""
    if early_config.inipath is not None or not _port_values(early_config):
        return
    try:
        from _pytest.config.findpaths import determine_setup

        namespace = early_config.known_args_namespace
        rootpath, inipath, inicfg, _ = determine_setup(
            inifile=namespace.inifilename,
            override_ini=namespace.override_ini,
            args=namespace.file_or_dir,
            rootdir_cmd_arg=namespace.rootdir or None,
            invocation_dir=early_config.invocation_params.dir,
        )
    except (ImportError, TypeError, ValueError, AttributeError):
        return  # another pytest: the options still parse, the rootdir stays as pytest chose
    if inipath is None:
        return
    early_config._rootpath = rootpath
    early_config._inipath = inipath
    early_config._inicfg = inicfg
    early_config._inicache.clear()
    parser.extra_info["rootdir"] = str(rootpath)
    parser.extra_info["inifile"] = str(inipath)
    namespace.confcutdir = str(inipath.parent)
    args[:] = [*early_config.getini("addopts"), *args]
