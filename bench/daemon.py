"""baromapd against the pty twins for a while: drops, CPU, memory, latency, timestamp error.

The twins run in this process (LMS200 at 500 kbaud, 181 beams at 75 Hz paced at line rate;
SIPs at 10 Hz; the barometer at 50 Hz); ``baromapd`` runs as its own process, so its CPU time
and peak RSS are its own (``getrusage`` of the waited child). Latency (a frame's last byte read
-> its message taken by the recorder thread) is measured inside the daemon and read from its
last ``/diagnostics``. Timestamp errors compare each recorded stamp with the instant the twin
says the frame's content was true (its truth log, on the same CLOCK_MONOTONIC, mapped to Unix
time with the mapping the recording states).

    python bench/daemon.py [--minutes 5] [--load N] [--twins-rt] [--daemon-nice N]
                           [--compression zstd|lz4|none] [--no-zenoh]
                           [--view-clients N [--view-stalled M]] [--view-compare]

The live view is off unless ``--view-clients`` is given: then the daemon serves it on a free
port and N viewers (``@foxglove/ws-protocol``-style clients of the ``websockets`` library, in
a process of their own) subscribe to every channel, M of them never reading; the live view's
process, its map and its viewers' counters are printed. ``--view-compare`` runs the bench
twice, without the view and with three viewers (one never reading), and prints what the view
adds to the daemon's CPU and what each recording kept.

``--load N`` runs N busy processes beside it (the navigation stack of a real laptop) at the
bench's own niceness, so the daemon competes with them at equal priority unless
``--daemon-nice`` gives it the unit's ``Nice=``. ``--twins-rt`` runs the twins' threads
SCHED_FIFO (root only): a real device's timing does not suffer from the host's load, so the
errors then measure the daemon, not the twins' own scheduling (printed either way).
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import itertools
import json
import os
import resource
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from baromap import messages
from baromap.recording import read_messages, read_metadata, topics
from baromap.sim.twins import SimDevices

CONFIG = """robot = "bench"
[recording]
directory = "{rec}"
min_free_mb = 0
compression = "{compression}"
[zenoh]
{zenoh}
[live_view]
{live_view}
[laser]
port = "{laser}"
baud = 500000
[base]
port = "{base}"
[barometer]
port = "{baro}"
rate_hz = 50
"""


def _hwm_kb(pid: int) -> int:
    """Peak resident set of a running process (VmHWM; ru_maxrss of a child also counts the
    parent's pages it shared between fork and exec)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _children(pid: int) -> list[int]:
    """The running child processes of ``pid`` (the daemon's taps, ``baromapd.tap``)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(stat.read_text().rpartition(")")[2].split()[1]) == pid:
                out.append(int(stat.parent.name))
        except (OSError, ValueError, IndexError):
            continue
    return out


def _cpu_s(pid: int) -> float:
    """User + system CPU of a running process so far (all its threads), with its children's
    (running, and ended ones it waited for)."""
    total = 0.0
    for i, proc in enumerate([pid, *_children(pid)]):
        try:
            fields = Path(f"/proc/{proc}/stat").read_text().rpartition(")")[2].split()
        except OSError:
            continue
        total += sum(int(f) for f in fields[11 : 15 if i == 0 else 13])
    return total / os.sysconf("SC_CLK_TCK")


def _threads_cpu(pid: int) -> dict[str, float]:
    """CPU seconds of a running process and its children by thread name (Python's threads all
    carry the interpreter's name; the Zenoh and MCAP runtimes name theirs)."""
    out: dict[str, float] = {}
    for stat in [
        p for proc in (pid, *_children(pid)) for p in Path(f"/proc/{proc}/task").glob("*/stat")
    ]:
        try:
            text = stat.read_text()
        except OSError:
            continue
        name = text[text.index("(") + 1 : text.rindex(")")]
        name = name.rstrip("0123456789").rstrip("-_:") or name
        fields = text.rpartition(")")[2].split()
        cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        out[name] = out.get(name, 0.0) + cpu
    return out


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in procs:
        if p.poll() is None:
            p.kill()
            p.wait()


def _renice(pid: int, niceness: int) -> None:
    """Set every thread of ``pid`` to ``niceness`` (Linux: niceness is per thread)."""
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, int(task.name), niceness)


def _realtime(pid: int, priority: int) -> None:
    """Every thread of ``pid`` SCHED_FIFO at ``priority``, as the unit's
    ``CPUSchedulingPolicy=fifo`` would start it (threads started later inherit it)."""
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):
            os.sched_setscheduler(int(task.name), os.SCHED_FIFO, os.sched_param(priority))


def _twins_realtime(priority: int = 20) -> str:
    """Run the twins' threads SCHED_FIFO, as hardware does not wait for the host's CPU."""
    done = []
    for thread in threading.enumerate():
        if thread.name.startswith("sim-") and thread.native_id is not None:
            try:
                os.sched_setscheduler(thread.native_id, os.SCHED_FIFO, os.sched_param(priority))
            except OSError as exc:
                return f"twins at normal priority ({exc.strerror})"
            done.append(thread.name)
    return f"twins' threads SCHED_FIFO {priority}: {', '.join(sorted(done))}"


def _truth(twin: object) -> list[object] | None:
    log = getattr(twin, "truth", None)
    return None if log is None else log.records()


def _errors_nearest(stamps: list[int], truth_ns: list[int]) -> np.ndarray:
    """Error of each stamp against the nearest true instant (frames far apart: unambiguous)."""
    out = []
    for t in stamps:
        i = bisect.bisect_left(truth_ns, t)
        near = [truth_ns[j] for j in (i - 1, i) if 0 <= j < len(truth_ns)]
        if near:
            out.append(min((t - n for n in near), key=abs))
    return np.array(out, dtype=np.float64) / 1e6


def _describe(name: str, errors_ms: np.ndarray | None, target_ms: float | None) -> str:
    if errors_ms is None or not len(errors_ms):
        return f"  {name:10s} n/a (the twins keep no truth log in this build)"
    p50, p99 = np.percentile(np.abs(errors_ms), [50, 99])
    target = f"  (target p99 <= {target_ms:g} ms)" if target_ms else ""
    return (
        f"  {name:10s} |error| p50 {p50:.3f} ms, p99 {p99:.3f} ms, mean {errors_ms.mean():+.3f} ms"
        f" over {len(errors_ms)} frames{target}"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=5.0)
    parser.add_argument("--load", type=int, default=0, help="busy processes beside the daemon")
    parser.add_argument("--twins-rt", action="store_true", help="twins' threads SCHED_FIFO")
    parser.add_argument("--daemon-nice", type=int, default=None, help="the daemon's niceness")
    parser.add_argument(
        "--tap-fifo",
        type=int,
        default=None,
        help="run the daemon's tap processes SCHED_FIFO at this priority (as the unit's "
        "LimitRTPRIO= lets them; a container's root may not raise that limit)",
    )
    parser.add_argument(
        "--daemon-fifo", type=int, default=None, help="run the daemon SCHED_FIFO at this priority"
    )
    parser.add_argument("--compression", default="zstd", choices=["zstd", "lz4", "none"])
    parser.add_argument("--no-zenoh", action="store_true", help="no live publisher")
    parser.add_argument("--warm-up", type=float, default=10.0, help="s before steady-state CPU")
    parser.add_argument("--view-clients", type=int, default=0, help="live view viewers (0: off)")
    parser.add_argument("--view-stalled", type=int, default=0, help="of them, never reading")
    parser.add_argument(
        "--view-compare",
        action="store_true",
        help="run without the live view, then with 3 viewers (1 never reading); compare",
    )
    parser.add_argument("--viewers", metavar="URL", help=argparse.SUPPRESS)  # the viewers' process
    args = parser.parse_args()
    if args.viewers:
        return _viewers(args.viewers, args.view_clients, args.view_stalled)
    if args.view_compare:
        without = _run(args, 0, 0)
        print()
        with_view = _run(args, 3, 1)
        print()
        _compare(without, with_view)
        return 0 if without["exit"] == with_view["exit"] == 0 else 1
    return 0 if _run(args, args.view_clients, args.view_stalled)["exit"] == 0 else 1


def _run(args: argparse.Namespace, view_clients: int, view_stalled: int) -> dict[str, float]:
    """One bench run; prints its figures and returns the ones a comparison needs."""
    zenoh = (
        "enabled = false"
        if args.no_zenoh
        else f'listen = ["tcp/127.0.0.1:{_free_port()}"]'  # not the default port: others use it
    )
    view_port = _free_port()
    live_view = f"port = {view_port}" if view_clients else "enabled = false"
    with tempfile.TemporaryDirectory(prefix="baromapd-bench-") as tmp:
        work = Path(tmp)
        with SimDevices(link_dir=work / "links", minutes=args.minutes + 5, seed=11) as sim:
            paths = sim.paths()
            config = work / "baromapd.toml"
            config.write_text(
                CONFIG.format(
                    rec=work / "rec",
                    laser=paths["lms200"],
                    base=paths["p3at"],
                    baro=paths["baro"],
                    compression=args.compression,
                    zenoh=zenoh,
                    live_view=live_view,
                )
            )
            twins_note = _twins_realtime() if args.twins_rt else "twins at normal priority"
            busy = [
                subprocess.Popen([sys.executable, "-c", "while True: pass"])
                for _ in range(args.load)
            ]
            daemon_nice = args.daemon_nice
            load_before = os.getloadavg()[0]
            started = time.monotonic()
            try:
                proc = subprocess.Popen(
                    [sys.executable, "-m", "baromapd.main", "--config", str(config)],
                    stderr=(work / "daemon.log").open("wb"),
                    env={**os.environ, "BAROMAPD_BENCH": "1"},
                )
                if daemon_nice is not None:
                    _renice(proc.pid, daemon_nice)  # before its threads start: they inherit it
                if args.daemon_fifo is not None:
                    _realtime(proc.pid, args.daemon_fifo)
                peak_kb = taps_kb = view_kb = 0
                viewers = None
                if view_clients:
                    viewers = _start_viewers(
                        work / "daemon.log", f"ws://127.0.0.1:{view_port}", view_clients,
                        view_stalled,
                    )  # fmt: skip
                view_cpu: list[float] = []
                deadline = started + args.minutes * 60
                warm = (started + args.warm_up, 0.0)
                warm_cpu: tuple[float, float] | None = None
                while time.monotonic() < deadline:
                    time.sleep(min(1.0, max(0.0, deadline - time.monotonic())))
                    peak_kb = max(peak_kb, _hwm_kb(proc.pid))
                    view_pid = _view_process(proc.pid)
                    taps = [c for c in _children(proc.pid) if c != view_pid]
                    taps_kb = max(taps_kb, sum(_hwm_kb(c) for c in taps))
                    if view_pid is not None:
                        view_kb = max(view_kb, _hwm_kb(view_pid))
                    if args.tap_fifo is not None:
                        for tap in taps:
                            _realtime(tap, args.tap_fifo)
                    if warm_cpu is None and time.monotonic() >= warm[0]:
                        warm_cpu = (time.monotonic(), _cpu_s(proc.pid))
                        if view_pid is not None:
                            view_cpu = [_cpu_s(view_pid)]
                        if daemon_nice is not None:
                            _renice(proc.pid, daemon_nice)  # every thread, surely
                        if args.daemon_fifo is not None:
                            _realtime(proc.pid, args.daemon_fifo)
                end_cpu = (time.monotonic(), _cpu_s(proc.pid))
                view_pid = _view_process(proc.pid)
                if view_pid is not None and view_cpu:
                    view_cpu.append(_cpu_s(view_pid))
                threads_cpu = _threads_cpu(proc.pid)
                seen = _stop_viewers(viewers)
                load_end = os.getloadavg()[0]
                _stop(busy)
                before = resource.getrusage(resource.RUSAGE_CHILDREN)  # the busy ones
                proc.send_signal(signal.SIGTERM)
                code = proc.wait(60)
                wall_s = time.monotonic() - started
            finally:
                _stop(busy)
                if viewers is not None and viewers.poll() is None:
                    viewers.kill()
                    viewers.wait()
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            truths = {name: _truth(t) for name, t in (("laser", sim.lms200), ("base", sim.p3at),
                                                      ("baro", sim.baro))}  # fmt: skip
            sent = {"scans": sim.lms200.scans_sent, "sips": sim.p3at.sips_sent,
                    "samples": sim.baro.samples_sent}  # fmt: skip
            lines = {twin.name: (np.array(twin.port.lateness) * 1e3, twin.port.bytes_unread)
                     for twin in sim.twins}  # fmt: skip
        files = sorted((work / "rec").glob("*.mcap"))
        records = [r for path in files for r in read_messages(path)]
        header = read_metadata(files[0])[topics.METADATA_NAME]
    wall0, mono0 = int(header["clock_wall0_ns"]), int(header["clock_mono0_ns"])
    by_topic: dict[str, list[object]] = {}
    for record in records:
        by_topic.setdefault(record.topic, []).append(record.message)
    health = {
        h.device: h
        for h in by_topic.get(topics.DIAGNOSTICS, [])
        if isinstance(h, messages.DeviceHealth)
    }
    rec = health["recorder"].counters
    dropped = sum(v for k, v in rec.items() if k.startswith("dropped_"))
    baro = [m for m in by_topic.get(topics.BARO, []) if isinstance(m, messages.PressureSample)]
    scans = [m for m in by_topic.get(topics.SCAN, []) if isinstance(m, messages.LaserScan)]
    odom = [m for m in by_topic.get(topics.ODOM, []) if isinstance(m, messages.Odometry)]
    scan_gaps = sum(
        1 for a, b in itertools.pairwise(scans) if b.t_ns - a.t_ns > 2.5e9 / 75
    )  # more than two scan periods: a scan missing mid-run
    lost_baro = sum(((b.seq - a.seq - 1) % 65536) for a, b in itertools.pairwise(baro))

    print(f"baromapd on the pty twins for {args.minutes:g} min (exit {code}), {len(files)} file(s)")
    print(
        f"  machine: {os.cpu_count()} cores, load average {load_before:.1f} at start, "
        f"{load_end:.1f} at end (latency tails grow with the load of other processes)"
    )
    print(f"  set-up: {args.load} busy processes beside it at the bench's niceness "
          f"({os.getpriority(os.PRIO_PROCESS, 0)}), daemon niceness "
          f"{os.getpriority(os.PRIO_PROCESS, 0) if daemon_nice is None else daemon_nice}"
          f"{'' if args.daemon_fifo is None else f' and SCHED_FIFO {args.daemon_fifo}'}, "
          f"the laser's tap {'normal' if args.tap_fifo is None else 'SCHED_FIFO'}, "
          f"{twins_note}, compression {args.compression}, "
          f"Zenoh publisher {'off' if args.no_zenoh else 'on'}")  # fmt: skip
    print(
        f"  recorded: {len(scans)} scans of {sent['scans']} sent, {len(odom)} odometry of "
        f"{sent['sips']} SIPs, {len(baro)} pressure samples of {sent['samples']} "
        "(the difference is what was sent before each session was up and after it stopped)"
    )
    print(f"  messages dropped by the daemon: {dropped} (queue and disk guard), "
          f"barometer sequence gaps: {lost_baro}   (must be 0)")  # fmt: skip
    print(f"  laser: {scan_gaps} gaps over two scan periods (with every sent scan recorded, "
          "these are pauses of the twin itself)")  # fmt: skip
    for device in ("laser", "base", "barometer"):
        if device in health:
            counters = health[device].counters
            bad = {k: v for k, v in counters.items() if k.startswith("bad_")}
            reads = counters.get("reads", 0) / max(1, counters.get("messages", 0))
            print(f"  {device}: frames the decoder discarded on the line: {bad or 'none'}; "
                  f"{reads:.1f} reads with data per message")  # fmt: skip
    cpu_s = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    print(f"  daemon CPU: {cpu_s:.1f} s in {wall_s:.0f} s = {100 * cpu_s / wall_s:.2f} % of one "
          "core, start-up and shutdown included (target <= 5 %)")  # fmt: skip
    if warm_cpu is not None and end_cpu[0] > warm_cpu[0]:
        steady = (end_cpu[1] - warm_cpu[1]) / (end_cpu[0] - warm_cpu[0])
        print(f"  daemon CPU, steady state (from {args.warm_up:g} s to the end): "
              f"{100 * steady:.2f} % of one core (target <= 5 %)")  # fmt: skip
    run_s = end_cpu[0] - started
    groups = sorted(threads_cpu.items(), key=lambda kv: -kv[1])
    print("  by thread name over the whole run: " + ", ".join(
        f"{name} {100 * cpu / run_s:.2f} %" for name, cpu in groups if cpu > 0))  # fmt: skip
    print(f"  daemon peak RSS: {peak_kb / 1024:.0f} MB, its tap processes {taps_kb / 1024:.0f} MB "
          "(target <= 150 MB)")  # fmt: skip
    for topic in (topics.SCAN, topics.ODOM, topics.BARO):
        p50 = rec.get(f"latency_p50_us{topic}", 0) / 1000
        p99 = rec.get(f"latency_p99_us{topic}", 0) / 1000
        print(f"  latency last byte -> recorder {topic:6s} p50 {p50:.2f} ms, p99 {p99:.2f} ms "
              "(target p99 <= 5 ms)")  # fmt: skip
    print("the twins' own delivery (in the errors below): a message's last byte written to the "
          "pty - when a line would have delivered it (their threads' scheduling):")  # fmt: skip
    for name, (late_ms, unread) in lines.items():
        if len(late_ms):
            p50, p99 = np.percentile(late_ms, [50, 99])
            print(f"  {name:7s} p50 {p50:.3f} ms, p99 {p99:.3f} ms, max {late_ms.max():.1f} ms; "
                  f"bytes lost to a full pty (the daemon did not read): {unread}")  # fmt: skip
    print("timestamp error against the twins' truth (recorded stamp - true instant):")

    def unix(truth: list[object] | None) -> list[int] | None:
        if truth is None:
            return None
        return sorted(wall0 + int(t.t_mono_ns) - mono0 for t in truth)

    laser_truth = unix(truths["laser"])
    base_truth = unix(truths["base"])
    baro_errors = None
    if truths["baro"] is not None:
        by_seq = {(t.seq): wall0 + int(t.t_mono_ns) - mono0
                  for t in truths["baro"]}  # fmt: skip
        baro_errors = np.array([(m.t_ns - by_seq[m.seq]) / 1e6 for m in baro if m.seq in by_seq])
    print(_describe("laser", None if laser_truth is None else
                    _errors_nearest([m.t_ns for m in scans], laser_truth), 1.0))  # fmt: skip
    print(_describe("barometer", baro_errors, 2.0))
    print(_describe("odometry", None if base_truth is None else
                    _errors_nearest([m.t_ns for m in odom], base_truth), None))  # fmt: skip
    steady_pct = float("nan")
    if warm_cpu is not None and end_cpu[0] > warm_cpu[0]:
        steady_pct = 100 * (end_cpu[1] - warm_cpu[1]) / (end_cpu[0] - warm_cpu[0])
    result = {
        "exit": float(code),
        "steady_pct": steady_pct,
        "scans": len(scans),
        "scans_sent": sent["scans"],
        "odom": len(odom),
        "sips": sent["sips"],
        "baro": len(baro),
        "samples": sent["samples"],
        "dropped": dropped,
        "baro_gaps": lost_baro,
    }
    if view_clients:
        view = health.get("live_view")
        steady_s = end_cpu[0] - warm_cpu[0] if warm_cpu is not None else float("nan")
        view_pct = (
            100 * (view_cpu[1] - view_cpu[0]) / steady_s if len(view_cpu) == 2 else float("nan")
        )
        result["view_pct"] = view_pct
        print(f"live view: {view_clients} viewers subscribed to every channel, {view_stalled} "
              "of them never reading")  # fmt: skip
        print(f"  its process (server, front, live map): {view_pct:.2f} % of one core in the "
              f"steady state (part of the daemon's figure above), peak RSS "
              f"{view_kb / 1024:.0f} MB")  # fmt: skip
        if view is not None:
            c = view.counters
            map_s = c.get("map_cpu_ms", 0) / 1000
            print(f"  live map: {c.get('map_keyframes', 0)} keyframes matched and drawn, "
                  f"{map_s:.1f} s of CPU in {wall_s:.0f} s ({100 * map_s / wall_s:.2f} % of one "
                  f"core), its grids {c.get('map_bytes', 0) / 1e6:.1f} MB; map work dropped "
                  f"{c.get('map_dropped', 0)}")  # fmt: skip
            # each viewer's drops as last reported while it was connected (one that stopped
            # reading is disconnected once it misses a ping)
            per_client: dict[str, int] = {}
            for h in by_topic.get(topics.DIAGNOSTICS, []):
                if isinstance(h, messages.DeviceHealth) and h.device == "live_view":
                    for k, v in h.counters.items():
                        if k.startswith("client_") and k.endswith("_dropped"):
                            per_client[k] = max(per_client.get(k, 0), v)
            print(f"  daemon -> view messages: {c.get('sent', 0)} sent, {c.get('dropped', 0)} "
                  f"dropped; viewers: {c.get('served', 0)} served, {c.get('clients', 0)} still "
                  f"connected at the last report; data messages dropped per viewer "
                  f"{per_client or 'none'}")  # fmt: skip
        for number, counts in sorted(seen.items()):
            never = " (never reading)" if counts["stalled"] else ""
            print(f"  viewer {number}: {counts['messages']} messages, "
                  f"{counts['bytes'] / 1e6:.1f} MB read{never}")  # fmt: skip
    return result


def _compare(without: dict[str, float], with_view: dict[str, float]) -> None:
    print("live view, compared: the same bench without it, then with 3 viewers (1 never reading)")
    extra = with_view["steady_pct"] - without["steady_pct"]
    print(f"  daemon CPU, steady state: {without['steady_pct']:.2f} % without the view, "
          f"{with_view['steady_pct']:.2f} % with it (its process included): "
          f"+{extra:.2f} points of one core")  # fmt: skip
    for name, run in (("without", without), ("with", with_view)):
        print(f"  recorded {name} the view: {run['scans']:.0f}/{run['scans_sent']:.0f} scans, "
              f"{run['odom']:.0f}/{run['sips']:.0f} odometry, {run['baro']:.0f}/"
              f"{run['samples']:.0f} pressure (recorded/sent), {run['dropped']:.0f} dropped, "
              f"{run['baro_gaps']:.0f} barometer sequence gaps")  # fmt: skip


def _view_process(daemon_pid: int) -> int | None:
    for child in _children(daemon_pid):
        try:
            if b"baromapd.liveview_child" in Path(f"/proc/{child}/cmdline").read_bytes():
                return child
        except OSError:
            continue
    return None


def _start_viewers(
    log: Path, url: str, clients: int, stalled: int, timeout_s: float = 120.0
) -> subprocess.Popen[str]:
    """The viewers' process, once the daemon says its live view serves."""
    deadline = time.monotonic() + timeout_s
    while "live view serving" not in log.read_text(errors="replace"):
        if time.monotonic() > deadline:
            raise SystemExit(f"the daemon's live view did not start; see {log}")
        time.sleep(0.2)
    argv = [sys.executable, __file__, "--viewers", url, "--view-clients", str(clients)]
    argv += ["--view-stalled", str(stalled)]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, text=True)


def _stop_viewers(viewers: subprocess.Popen[str] | None) -> dict[int, dict[str, int]]:
    if viewers is None:
        return {}
    viewers.send_signal(signal.SIGTERM)
    out, _ = viewers.communicate(timeout=30)
    return {int(k): v for k, v in json.loads(out or "{}").items()}


def _viewers(url: str, clients: int, stalled: int) -> int:
    """Viewers of the live view until SIGTERM: each subscribes to every channel; the first
    ``stalled`` stop reading once subscribed. Prints what each read, as JSON."""
    import asyncio

    from websockets.asyncio.client import connect

    counts = {i: {"messages": 0, "bytes": 0, "stalled": int(i < stalled)} for i in range(clients)}

    async def viewer(number: int) -> None:
        async with connect(url, subprotocols=["foxglove.websocket.v1"], max_size=None) as ws:
            async for frame in ws:
                if isinstance(frame, str):
                    message = json.loads(frame)
                    if message.get("op") == "advertise":
                        subscriptions = [
                            {"id": c["id"], "channelId": c["id"]} for c in message["channels"]
                        ]
                        await ws.send(
                            json.dumps({"op": "subscribe", "subscriptions": subscriptions})
                        )
                        if counts[number]["stalled"]:
                            ws.transport.pause_reading()
                            await asyncio.Event().wait()
                else:
                    counts[number]["messages"] += 1
                    counts[number]["bytes"] += len(frame)

    async def all_viewers() -> None:
        stop = asyncio.Event()
        asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, stop.set)
        tasks = [asyncio.create_task(viewer(i)) for i in range(clients)]
        await stop.wait()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    asyncio.run(all_viewers())
    print(json.dumps(counts))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
