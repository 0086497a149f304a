"""``baromapd-bench``: devices on real ports through the daemon's own sessions, a report each.

    baromapd-bench [--laser PORT] [--base PORT] [--barometer PORT] [--seconds 30]
                   [--laser-baud 38400] [-o DIR] [--json]

Any subset of the three ports (paths, pyserial URLs or USB identities ``vid:pid[:serial]``).
The daemon runs as ``baromapd`` would (recording included: the MCAP goes to ``-o DIR``) for
the given time, with live publishing off; then one report per device:

- rate: messages per second from the device's first message on, against what it should
  give (the laser: as fast as its line and mirror allow; the base: its SIP cycle; the
  barometer: the configured rate);
- gaps: the longest silence, and the intervals longer than 1.5 expected periods;
- errors by reason: the session's bad-frame counters (``bad_crc``, ``bad_garbage``, ...), and
  the device's own (the laser's status byte, the barometer board's STATUS counters);
- clock offset and jitter: each message's stamp minus the instant its last byte was read, the
  median and the spread (95th minus 5th percentile); the barometer board's clock rate against
  the host's in ppm;
- reconnects: connections after the first, failures, restarts announced by the device.

Exit status 0 when every device came up and streamed, 1 otherwise.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np

from baromap import logs
from baromap.messages import DeviceHealth, LaserScan, Message, Odometry, PressureSample
from baromapd.barometer import BarometerSession
from baromapd.clock import HostClock
from baromapd.config import DaemonConfig, LaserConfig, parse_config
from baromapd.session import DeviceSession

#: Device name -> the message type its rate is measured on.
STREAMS: Final = {"laser": LaserScan, "base": Odometry, "barometer": PressureSample}
MIRROR_HZ: Final = 75.0
INTERLACE: Final = {100: 1, 50: 2, 25: 4}


@dataclasses.dataclass(frozen=True, slots=True)
class StreamFigures:
    """One stream over a window: rate and gaps from read instants, offset and jitter of the
    stamps against them."""

    messages: int
    seconds: float
    rate_hz: float
    expected_hz: float
    longest_gap_s: float
    late_intervals: int
    offset_ms: float
    jitter_ms: float

    def line(self) -> str:
        return (
            f"{self.messages} messages in {self.seconds:.1f} s: {self.rate_hz:.2f} Hz "
            f"(expected {self.expected_hz:.2f}), longest gap {self.longest_gap_s * 1000:.0f} ms, "
            f"{self.late_intervals} intervals > 1.5 periods; stamp - read "
            f"{self.offset_ms:+.2f} ms, spread (p95-p5) {self.jitter_ms:.2f} ms"
        )


def stream_figures(
    stamps_ns: Sequence[int],
    reads_ns: Sequence[int],
    clock: HostClock,
    window: tuple[int, int],
    expected_hz: float,
) -> StreamFigures:
    """Figures of the messages read within ``window`` (monotonic ns, start and end).

    ``stamps_ns`` are the messages' Unix-time stamps, ``reads_ns`` the host monotonic instants
    their last bytes were read. The offset includes the frame's own line time for a device
    stamped at the start of its frame (the laser, the base).
    """
    start, end = window
    seconds = max((end - start) / 1e9, 1e-9)
    reads = np.asarray(reads_ns, dtype=np.int64)
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    inside = (reads >= start) & (reads <= end)
    reads, stamps = reads[inside], stamps[inside]
    if reads.size < 2:
        nan = float("nan")
        return StreamFigures(int(reads.size), seconds, reads.size / seconds, expected_hz,
                             seconds, 0, nan, nan)  # fmt: skip
    intervals = np.diff(reads) / 1e9
    edges = max((reads[0] - start) / 1e9, (end - reads[-1]) / 1e9)
    offset = (stamps - (reads + clock.unix_ns(0))) / 1e6  # the clock's mapping is one offset
    p5, p50, p95 = np.percentile(offset, [5, 50, 95])
    return StreamFigures(
        messages=int(reads.size),
        seconds=seconds,
        rate_hz=float((reads.size - 1) / ((reads[-1] - reads[0]) / 1e9)),
        expected_hz=expected_hz,
        longest_gap_s=float(max(intervals.max(), edges)),
        late_intervals=int(np.count_nonzero(intervals > 1.5 / expected_hz)),
        offset_ms=float(p50),
        jitter_ms=float(p95 - p5),
    )


def laser_hz(baud: int, angle_deg: int, resolution_cdeg: int) -> float:
    """Scans per second: as fast as both the line (10 bits a byte) and the mirror (75 turns a
    second, 2 or 4 of them interlaced at 0.5 and 0.25 deg) allow."""
    beams = angle_deg * 100 // resolution_cdeg + 1
    telegram = 4 + 1 + 2 + 2 * beams + 1 + 2  # header, B0, count, ranges, status, CRC
    return min(baud / 10 / telegram, MIRROR_HZ / INTERLACE[resolution_cdeg])


def expected_hz(session: DeviceSession) -> float:
    config: Any = getattr(session, "config", None)
    if isinstance(config, LaserConfig):
        return laser_hz(config.baud, config.angle_deg, config.resolution_cdeg)
    if session.name == "base":
        return 1000.0 / float(session.identity.get("sip_cycle_ms", 100))
    return float(getattr(config, "rate_hz", 1.0))


class StreamLog:
    """A fanout consumer that keeps each stream's stamps and read instants (never blocks)."""

    accepts = tuple(STREAMS.values())

    def __init__(self) -> None:
        self.stamps: dict[type, list[int]] = {kind: [] for kind in self.accepts}
        self.reads: dict[type, list[int]] = {kind: [] for kind in self.accepts}
        self._lock = threading.Lock()

    def offer(self, message: Message) -> None:
        self.offer_received(message, time.monotonic_ns())

    def offer_received(self, message: Message, received_ns: int) -> None:
        kind = type(message)
        with self._lock:
            if kind in self.stamps:
                self.stamps[kind].append(int(getattr(message, "t_ns", 0)))
                self.reads[kind].append(received_ns)

    def close(self) -> None:
        """Nothing to finish: the lists are read after the run."""

    def of(self, kind: type) -> tuple[list[int], list[int]]:
        with self._lock:
            return list(self.stamps[kind]), list(self.reads[kind])


@dataclasses.dataclass(frozen=True, slots=True)
class DeviceReport:
    device: str
    port: str
    up: bool
    identity: dict[str, str]
    figures: StreamFigures | None
    errors: dict[str, int]
    device_counters: dict[str, int]
    reconnects: int
    failures: int
    restarts: int
    clock_skew_ppm: float | None
    state: str

    def text(self) -> str:
        lines = [f"{self.device} on {self.port}: {self.state}"]
        if self.identity:
            lines.append("  identity: " + ", ".join(f"{k}={v}" for k, v in self.identity.items()))
        if self.figures is not None:
            lines.append("  " + self.figures.line())
        errors = ", ".join(f"{k}={v}" for k, v in sorted(self.errors.items())) or "none"
        lines.append(f"  errors by reason: {errors}")
        if self.device_counters:
            device = ", ".join(f"{k}={v}" for k, v in sorted(self.device_counters.items()))
            lines.append(f"  device counters: {device}")
        if self.clock_skew_ppm is not None:
            lines.append(f"  device clock against the host's: {self.clock_skew_ppm:+.0f} ppm")
        lines.append(
            f"  reconnects {self.reconnects}, failures {self.failures}, restarts {self.restarts}"
        )
        return "\n".join(lines)


@dataclasses.dataclass(frozen=True, slots=True)
class BenchReport:
    seconds: float
    devices: list[DeviceReport]
    recordings: list[Path]

    @property
    def ok(self) -> bool:
        return all(d.up for d in self.devices)


def _config(args: argparse.Namespace, directory: Path) -> DaemonConfig:
    lines = ['robot = "bench"', "[zenoh]", "enabled = false", "[recording]"]
    lines += [f"directory = {json.dumps(str(directory))}", "min_free_mb = 0"]
    if args.laser:
        lines += ["[laser]", f"port = {json.dumps(args.laser)}", f"baud = {args.laser_baud}"]
    if args.base:
        lines += ["[base]", f"port = {json.dumps(args.base)}"]
    if args.barometer:
        lines += ["[barometer]", f"port = {json.dumps(args.barometer)}"]
    return parse_config("\n".join(lines) + "\n", source="baromapd-bench")


_DEVICE_COUNTERS: Final = ("status_not_ok", "samples_lost", "battery_dv", "motors_off_failed")


def _report(
    session: DeviceSession, health: DeviceHealth, log: StreamLog, window: tuple[int, int]
) -> DeviceReport:
    counters = health.counters
    stamps, reads = log.of(STREAMS[session.name])
    figures = None
    if reads:  # from the device's first message: the time it took to come up is no gap
        since = (max(window[0], min(reads)), window[1])
        figures = stream_figures(stamps, reads, session.clock, since, expected_hz(session))
    device = {k: v for k, v in counters.items() if k.startswith("board_") or k in _DEVICE_COUNTERS}
    skew = session.fit.skew_ppm if isinstance(session, BarometerSession) else None
    return DeviceReport(
        device=session.name,
        port=session.port_spec,
        up=bool(counters.get("connects")) and figures is not None and figures.messages > 1,
        identity=dict(session.identity),
        figures=figures,
        errors={k: v for k, v in counters.items() if k.startswith("bad_") and v},
        device_counters=device,
        reconnects=max(0, counters.get("connects", 0) - 1),
        failures=counters.get("failures", 0),
        restarts=counters.get("restarts", 0),
        clock_skew_ppm=skew,
        state=f"{health.state.value} ({health.detail})",
    )


def run_bench(args: argparse.Namespace, directory: Path) -> BenchReport:
    """The daemon on the given ports for ``args.seconds``; the report of each device."""
    from baromapd.app import Daemon  # the whole daemon; the figures above need none of it

    daemon = Daemon(_config(args, directory), live=False)
    log = StreamLog()
    daemon.fanout.subscribe(log)
    thread = threading.Thread(target=daemon.run, name="baromapd-bench")
    thread.start()
    start = time.monotonic_ns()
    try:
        time.sleep(args.seconds)
    finally:
        end = time.monotonic_ns()
        health = {h.device: h for h in daemon.health()}
        daemon.request_stop()
        thread.join()
    reports = [_report(s, health[s.name], log, (start, end)) for s in daemon.sessions]
    return BenchReport(args.seconds, reports, list(daemon.recorder.files))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="baromapd-bench",
        description="Run devices on real ports through baromapd's sessions for a while and "
        "report each one (rate, gaps, errors by reason, clock offset and jitter, reconnects).",
    )
    parser.add_argument("--laser", metavar="PORT", help="the SICK LMS200's port")
    parser.add_argument("--base", metavar="PORT", help="the Pioneer's port")
    parser.add_argument("--barometer", metavar="PORT", help="the barometer board's port")
    parser.add_argument("--seconds", type=float, default=30.0, help="how long (default 30)")
    parser.add_argument(
        "--laser-baud", type=int, default=38400, help="38400 on RS-232, 500000 on RS-422"
    )
    parser.add_argument(
        "-o", "--output", metavar="DIR", help="where the MCAP goes (default: a new temp dir)"
    )
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.add_argument("--log-level", default="warning", help="the daemon's log level")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not (args.laser or args.base or args.barometer):
        print("baromapd-bench: give at least one of --laser, --base, --barometer", file=sys.stderr)
        return 2
    if not 0 < args.seconds <= 24 * 3600:
        print("baromapd-bench: --seconds must be in (0, 86400]", file=sys.stderr)
        return 2
    logs.configure("console", args.log_level)
    directory = Path(args.output or tempfile.mkdtemp(prefix="baromapd-bench-"))
    report = run_bench(args, directory)
    if args.json:
        print(json.dumps(dataclasses.asdict(report), default=str, indent=1))
    else:
        print(f"baromapd-bench: {report.seconds:g} s")
        for device in report.devices:
            print(device.text())
        for path in report.recordings:
            print(f"recording: {path}")
    return 0 if report.ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
