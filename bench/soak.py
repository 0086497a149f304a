"""A soak of the whole live path: 30 simulated minutes of faults, then loss, memory, rotation.

The demo's set-up (device twins on ptys, the real baromapd as its own process, baromap watch
following over Zenoh) on a longer mission played faster than real time, with what a robot's
day brings, at random simulated times from a seeded generator: each device unplugged (and
plugged back on a new pty), bursts of garbage on every line, stalls, one laser power cycle,
and the Zenoh router between the daemon and the watcher stopped and started again. The daemon
rotates its files by size and by age.

Printed, each against what it must be:
- lost messages on healthy streams: every frame a twin sent (its truth log) while its session
  was up and no fault was under way is in the recording; barometer samples by sequence number,
  scans and SIPs (which carry none) by count over each healthy stretch, where a stamp near a
  stretch's end can put one frame on either side;
- memory: the daemon's RSS and its anonymous part sampled every second; the steady growth of
  the anonymous memory's high-water after warm-up per hour of running and per 8-hour shift
  (the twins stream at least at their real rates: the laser at its line rate, the base and
  the barometer at the mission's speed, so a wall minute here carries at least a minute of a
  robot's data), flat below ``MEMORY_MAX_MB_PER_H``; and apart from it the steps at events
  (the router's restart) with what part of them was anonymous;
- rotation: files, sizes and spans against the configured limits, nothing lost or repeated at a
  split (barometer sequence continuous across files);
- live: floor events the watcher printed against those recorded, apart from those decided
  while the router was down (Zenoh keeps no history for a subscriber that cannot be reached).

    python bench/soak.py [--minutes 30] [--speed 6] [--seed 1] [--keep DIR]
                         [--probe] [--census S] [--trace-at S]
    python bench/soak.py router ENDPOINT      (the Zenoh router it starts and restarts)

``--probe`` loads bench/memory.py's probe into the daemon (its C heap, Python's blocks, its
threads every second; ``--census`` the collector's objects by type every S s; ``--trace-at``
tracemalloc from S s on) and prints what each memory step was made of; it costs the daemon
CPU, so a probed run's loss figures are not the bench's.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from baromap import logs
from baromap.cli.demo_config import free_loopback_port
from baromap.cli.demo_live import Additions, LiveRun, Shown, run_live
from baromap.cli.demo_mission import Mission
from baromap.evaluation.twin_truth import HostClock, SimTimeline, sim_timeline
from baromap.messages import DeviceHealth, DeviceState, PressureSample
from baromap.recording import read_messages, topics
from baromap.sim.route import default_route
from baromap.sim.twins.truth import FrameTruth, read_truth_log

#: Daemon device name -> twin name.
DEVICES = {"laser": "lms200", "base": "p3at", "barometer": "baro"}
ROTATE_SIZE_MB = 4.0
ROTATE_MINUTES = 1.0
#: Simulated seconds around a fault during which its device's stream is not "healthy".
FAULT_MARGIN_S = 2.0
#: Recording seconds cut off each end of a healthy stretch before counting frames.
EDGE_S = 0.2
#: Router down, as a fraction of the mission, and for how many simulated seconds.
ROUTER_DOWN_AT = 0.45
ROUTER_DOWN_S = 30.0
#: How far past a short stretch the daemon's counters are read for damage found late.
READ_LAG_S = 2.0
#: Wall seconds of warm-up before the memory slope is fitted: start-up, the Zenoh session, and
#: the first two files (the first rotation moves the MCAP writer's buffers from their own
#: mappings into the heap once, about 1 MB: a step, not growth).
MEMORY_WARM_UP_S = 2 * ROTATE_MINUTES * 60
#: Flat memory: growth below this after warm-up. 3 MB per hour of running is 24 MB over an
#: 8-hour shift, and keeps the daemon (about 100 MB) under bench/daemon.py's 150 MB target for
#: 16 hours; the leak this bench found grew 30-40 MB an hour.
MEMORY_MAX_MB_PER_H = 3.0
#: Memory increments are taken over this many wall seconds (a page every 4 kB: 0.5 MB per
#: hour is a page in 30 s), and a rise over ``MEMORY_STEP_MB`` within ``MEMORY_STEP_S`` is
#: printed as a step.
MEMORY_LAG_S = 30.0
MEMORY_STEP_MB = 0.25
MEMORY_STEP_S = 10.0


def run_router(endpoint: str) -> int:
    import threading

    import zenoh

    config = zenoh.Config()
    config.insert_json5("mode", '"router"')
    config.insert_json5("listen/endpoints", f'["{endpoint}"]')
    config.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(config)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    print("ready", flush=True)
    stop.wait()
    session.close()
    return 0


def faults(mission: Mission, rng: np.random.Generator) -> list[dict[str, Any]]:
    """Each device: an unplug, two bursts of garbage, a stall; the laser: a power cycle.

    Spread over the mission so that one device's faults do not overlap."""
    duration = mission.minutes * 60
    out: list[dict[str, Any]] = []
    for twin in DEVICES.values():
        kinds = ["unplug", "garbage", "garbage", "stall"] + (
            ["power_cycle"] if twin == "lms200" else []
        )
        slots = np.linspace(0.08, 0.92, len(kinds) + 1)
        order = rng.permutation(len(kinds))
        for k, kind in zip(order, kinds, strict=True):
            at = float(rng.uniform(slots[k], slots[k + 1] - 0.03)) * duration
            fault: dict[str, Any] = {"device": twin, "at_s": round(at, 1), "kind": kind}
            if kind == "unplug":
                fault["duration_s"] = round(float(rng.uniform(5, 20)), 1)
            elif kind == "stall":
                fault["duration_s"] = round(float(rng.uniform(3, 15)), 1)
            elif kind == "power_cycle":
                fault["duration_s"] = 2.0
            else:
                fault["size"] = int(rng.integers(200, 4000))
            out.append(fault)
    return sorted(out, key=lambda f: f["at_s"])


@dataclass
class RouterRestart:
    """Stops the Zenoh router at one simulated time and starts it again at another."""

    endpoint: str
    down_at_s: float
    up_at_s: float
    proc: subprocess.Popen[bytes] | None = None
    down_wall: float | None = None
    up_wall: float | None = None

    def start(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, __file__, "router", self.endpoint],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
        )
        assert self.proc.stdout is not None
        self.proc.stdout.readline()  # "ready"

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            if self.proc.stdout is not None:
                self.proc.stdout.close()

    def tick(self, sim_s: float) -> None:
        if self.down_wall is None and sim_s >= self.down_at_s:
            self.stop()
            self.down_wall = time.time()
        elif self.down_wall is not None and self.up_wall is None and sim_s >= self.up_at_s:
            self.start()
            self.up_wall = time.time()


@dataclass
class Memory:
    """The daemon's resident set and the anonymous part of it, sampled: (wall s, MB, MB)."""

    samples: list[tuple[float, float, float]] = field(default_factory=list)
    started_unix: float | None = None  # Unix time of the first sample (events are in Unix s)
    steps: list[tuple[float, float]] = field(default_factory=list)  # (wall s, MB), as printed

    def sample(self, pid: int) -> None:
        if self.started_unix is None:
            self.started_unix = time.time()
        kb: dict[str, int] = {}
        try:
            for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
                key, _, rest = line.partition(":")
                if key in ("Rss", "Anonymous"):
                    kb[key] = int(rest.split()[0])
        except OSError:
            return
        if len(kb) == 2:
            self.samples.append((time.monotonic(), kb["Rss"] / 1024, kb["Anonymous"] / 1024))


def healthy_stretches(
    health: list[DeviceHealth], fault_windows: list[tuple[int, int]]
) -> list[tuple[int, int]]:
    """Recording-time spans where the device was UP in consecutive health reports and no
    fault window touches them."""
    spans = []
    ordered = sorted(health, key=lambda h: h.t_ns)
    for a, b in itertools.pairwise(ordered):
        if a.state is DeviceState.UP and b.state is DeviceState.UP:
            spans.append((a.t_ns, b.t_ns))
    merged: list[list[int]] = []
    for lo, hi in spans:
        if merged and lo <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append([lo, hi])
    out = []
    for lo, hi in merged:
        cuts = sorted((a, b) for a, b in fault_windows if b > lo and a < hi)
        start = lo
        for a, b in cuts:
            if a > start:
                out.append((start, a))
            start = max(start, b)
        if hi > start:
            out.append((start, hi))
    return out


def fault_windows(
    scheduled: list[dict[str, Any]], twin: str, clock_timeline: SimTimeline
) -> list[tuple[int, int]]:
    out = []
    for f in scheduled:
        if f["device"] != twin:
            continue
        lo = f["at_s"] - FAULT_MARGIN_S
        hi = f["at_s"] + f.get("duration_s", 0.0) + FAULT_MARGIN_S
        a, b = clock_timeline.unix_ns_at([lo, hi])
        out.append((int(a), int(b)))
    return out


def reading(health: list[DeviceHealth], lo: int, hi: int) -> tuple[int, float]:
    """Between two recording times, from the daemon's health reports of one device: frames its
    decoder found damaged (bad CRC, garbage, sequence gaps: bytes lost or changed before it read
    them), and the longest time [s] its reader took in no byte at all. The span is stretched by
    ``READ_LAG_S``: a reader that fell behind finds the damage late."""
    hi += int(READ_LAG_S * 1e9)
    ordered = sorted(health, key=lambda h: h.t_ns)
    window = [h for h in ordered if lo <= h.t_ns <= hi]
    before = [h for h in ordered if h.t_ns < lo][-1:]
    after = [h for h in ordered if h.t_ns > hi][:1]

    def bad(h: DeviceHealth) -> int:
        return sum(
            int(v) for k, v in h.counters.items()
            if k.startswith("bad_") or k == "samples_lost"
        )  # fmt: skip

    span = before + window + after
    if len(span) < 2:
        return 0, 0.0
    damaged = bad(span[-1]) - bad(span[0])
    idle = 0.0
    since = span[0]
    for h in span[1:]:
        if h.counters.get("bytes_in", 0) != since.counters.get("bytes_in", 0):
            since = h
        else:
            idle = max(idle, (h.t_ns - since.t_ns) / 1e9)
    return damaged, idle


def internal_drops(by_topic: dict[str, list[Any]]) -> tuple[dict[str, int], int]:
    """What the daemon itself dropped after reading: its recorder's queue and pauses, its
    publisher's queues (last counters of each); and the recorder's backlog at that last
    report, apart: messages still queued at that instant, which the recorder writes before
    it stops (a queue's length, not a loss; the stretches' counts above would show a loss)."""
    last: dict[str, DeviceHealth] = {}
    for h in by_topic[topics.DIAGNOSTICS]:
        mine = isinstance(h, DeviceHealth) and h.device in ("recorder", "zenoh")
        if mine and (h.device not in last or h.t_ns >= last[h.device].t_ns):
            last[h.device] = h
    out: dict[str, int] = {}
    for device, h in sorted(last.items()):
        for k, v in h.counters.items():
            if k.startswith("dropped"):
                out[f"{device}.{k}"] = int(v)
    backlog = int(last["recorder"].counters.get("backlog", 0)) if "recorder" in last else 0
    return out, backlog


def report(
    live: LiveRun,
    mission: Mission,
    scheduled: list[dict[str, Any]],
    router: RouterRestart,
    memory: Memory,
) -> int:
    files = live.recordings
    records: list[FrameTruth] = read_truth_log(live.truth_log)
    clock = HostClock.of_recording(files[0])
    clock_timeline = sim_timeline(records, clock, devices=("baro",))
    by_topic: dict[str, list[Any]] = defaultdict(list)
    file_spans = []
    for path in files:
        stamps = []
        for r in read_messages(path):
            by_topic[r.topic].append(r.message)
            stamps.append(r.log_time_ns)
        file_spans.append((path, path.stat().st_size / 1e6, (max(stamps) - min(stamps)) / 1e9))
    health: dict[str, list[DeviceHealth]] = defaultdict(list)
    for h in by_topic[topics.DIAGNOSTICS]:
        if isinstance(h, DeviceHealth):
            health[h.device].append(h)
    failures = 0
    print(f"\nsoak: {mission.minutes:g} simulated minutes at x{mission.speed:g} "
          f"({live.wall_s:.0f} s), {len(scheduled)} scheduled faults, router restarted; "
          f"daemon exit {live.daemon_exit} (must be 0)")  # fmt: skip
    failures += live.daemon_exit != 0
    print("lost messages on healthy streams (must be 0):")
    short: list[tuple[str, int, int, int, int, float]] = []  # device, span, missing, ...
    for device, twin in DEVICES.items():
        windows = fault_windows(scheduled, twin, clock_timeline)
        stretches = healthy_stretches(health[device], windows)
        sent = [r for r in records if r.device == twin]
        sent_unix = clock.unix_ns([r.t_mono_ns for r in sent])
        if device == "barometer":
            # seq restarts when the board powers up again: a sample is found by its seq and
            # a stamp within half a second of when it was sent
            got: dict[int, list[int]] = defaultdict(list)
            for m in by_topic[topics.BARO]:
                if isinstance(m, PressureSample) and m.seq is not None:
                    got[m.seq].append(m.t_ns)
            inside = [
                (r, t) for r, t in zip(sent, sent_unix, strict=True)
                if any(lo <= t <= hi for lo, hi in stretches)
            ]  # fmt: skip
            lost_at = [
                int(t) for r, t in inside
                if not any(abs(int(t) - g) < 500_000_000 for g in got.get(r.seq or 0, ()))
            ]  # fmt: skip
            healthy_s = sum(hi - lo for lo, hi in stretches) / 1e9
            print(f"  barometer: {len(inside)} samples sent in {len(stretches)} healthy "
                  f"stretches ({healthy_s:.0f} s), {len(lost_at)} not recorded")  # fmt: skip
            failures += bool(lost_at)
            for lo, hi in stretches:
                n = sum(1 for t in lost_at if lo <= t <= hi)
                if n:
                    short.append((device, lo, hi, n, *reading(health[device], lo, hi)))
            continue
        topic = topics.SCAN if device == "laser" else topics.ODOM
        stamps = np.array(sorted(m.t_ns for m in by_topic[topic]))
        sent_sorted = np.sort(sent_unix)
        worst = 0
        total_sent = total_got = 0
        edge = int(EDGE_S * 1e9)
        for lo, hi in stretches:
            if hi - lo <= 2 * edge:
                continue
            a, b = lo + edge, hi - edge
            n_sent = int(np.count_nonzero((sent_sorted >= a) & (sent_sorted <= b)))
            n_got = int(np.count_nonzero((stamps >= a) & (stamps <= b)))
            total_sent += n_sent
            total_got += n_got
            worst = max(worst, n_sent - n_got)
            if n_sent - n_got > 2:
                short.append((device, a, b, n_sent - n_got, *reading(health[device], a, b)))
        print(f"  {device}: {total_sent} frames sent in {len(stretches)} healthy stretches, "
              f"{total_got} recorded; worst stretch short by {worst} (a stretch's two ends "
              "may each shift one frame: more than 2 is a loss)")  # fmt: skip
        failures += worst > 2
    t0 = min((m.t_ns for m in by_topic[topics.BARO]), default=0)
    for device, lo, hi, missing, damaged, idle in short:
        print(f"  where: {device} {(lo - t0) / 1e9:.0f}-{(hi - t0) / 1e9:.0f} s of the recording: "
              f"{missing} missing; there (and {READ_LAG_S:g} s after) the daemon's decoder counted "
              f"{damaged} damaged frame(s) or sequence gap(s), and its reader took in no byte "
              f"for up to {idle:.1f} s")  # fmt: skip
    drops, backlog = internal_drops(by_topic)
    print(f"  dropped inside the daemon after reading (must be 0): {sum(drops.values())} "
          f"({', '.join(f'{k} {v}' for k, v in drops.items()) or 'no counters'}); "
          f"recorder's queue at its last report {backlog} (written before it stopped)")  # fmt: skip
    failures += sum(drops.values()) > 0
    seqs = [m.seq for m in by_topic[topics.BARO] if isinstance(m, PressureSample)]
    print("rotation (every", ROTATE_SIZE_MB, "MB or", ROTATE_MINUTES, "min):")
    for path, size, span in file_spans:
        print(f"  {path.name}: {size:.1f} MB, {span:.0f} s of messages")
    too_big = [p for p, size, span in file_spans if size > ROTATE_SIZE_MB * 1.25]
    too_long = [p for p, size, span in file_spans if span > ROTATE_MINUTES * 60 + 5]
    boundary_gaps = 0
    previous_last = None
    for path in files:
        file_seqs = [
            r.message.seq for r in read_messages(path, [topics.BARO])
            if isinstance(r.message, PressureSample)
        ]  # fmt: skip
        if previous_last is not None and file_seqs:
            boundary_gaps += (file_seqs[0] - previous_last) % 65536 != 1
        if file_seqs:
            previous_last = file_seqs[-1]
    print(f"  {len(files)} files; over the size limit: {len(too_big)}, over the age limit: "
          f"{len(too_long)}, barometer sequence broken at a split: {boundary_gaps} (all 0); "
          f"{len(seqs)} samples in all, {len(seqs) - len(set(seqs))} repeated seq numbers "
          "(the board's counter wraps at 65536 and restarts after a power-up)")  # fmt: skip
    failures += bool(too_big or too_long or boundary_gaps)
    failures += not memory_flat(memory, router)
    events = [m for m in by_topic[topics.FLOOR_EVENT]]
    printed = [
        int(m.group(1)) for line in live.watch_lines if (m := re.search(r"\[event (\d+)\]", line))
    ]
    assert router.down_wall is not None and router.up_wall is not None
    reconnect_s = 15.0
    while_down = [
        e.event_id for e in events
        if router.down_wall * 1e9 <= e.t_ns <= (router.up_wall + reconnect_s) * 1e9
    ]  # fmt: skip
    missing = [e.event_id for e in events if e.event_id not in printed]
    unexplained = [k for k in missing if k not in while_down]
    print(f"live: {len(events)} floor events recorded, {len(printed)} printed by the watcher "
          f"through the router; {len(while_down)} decided while it was down or reconnecting, "
          f"{len(unexplained)} missing otherwise (must be 0)")  # fmt: skip
    back = [line for line in live.watch_lines if "back online" in line]
    print(f"  the watcher saw the robot back after the restart: {'yes' if back else 'no'}")
    failures += bool(unexplained) + (not back)
    print(f"verdict: {'PASS' if failures == 0 else f'FAIL ({failures})'}")
    return 0 if failures == 0 else 1


def memory_flat(memory: Memory, router: RouterRestart) -> bool:
    """Print the daemon's memory figures; whether it grows steadily after warm-up.

    What is judged is the daemon's anonymous memory: what it allocated (heaps, Python's
    arenas, thread stacks), where a leak grows. The rest of its resident set is pages of its
    libraries' files, read in when code runs for the first time (a Zenoh reconnection runs
    a megabyte of the library's code that nothing ran before: a step at the router's
    restart); they cannot grow past the libraries' size and the kernel may drop them at any
    time. Both are printed.

    Growth is told apart from steps: the median of the increments over ``MEMORY_LAG_S`` (one
    per second) is what the daemon gains all the time, a figure one event cannot move (a step
    lifts only ``MEMORY_LAG_S`` of them); the steps, one-off rises to a new high at events
    (the first run of a code path, a buffer that moves into the heap), are printed beside it
    with the events' times. What is judged is the high-water mark (the highest level so far,
    on the running median of 5 samples): memory the daemon takes back after it gave some to
    the system (glibc unmaps a megabyte when a file closes, and the heap fills the hole again
    over the next minute) is not growth, and a leak cannot hide from it, as it raises the
    high-water all the time. The increments of the level itself are printed beside it.
    """
    t = np.array([s[0] for s in memory.samples]) - memory.samples[0][0]
    rss = np.array([s[1] for s in memory.samples])
    anon = np.array([s[2] for s in memory.samples])
    warm = t >= MEMORY_WARM_UP_S
    print(f"memory: daemon RSS {rss[0]:.1f} MB at start, {rss[warm][0]:.1f} MB after "
          f"{MEMORY_WARM_UP_S:.0f} s of warm-up, {rss[-1]:.1f} MB at the end, peak "
          f"{rss.max():.1f} MB; of it anonymous {anon[0]:.1f}, {anon[warm][0]:.1f}, "
          f"{anon[-1]:.1f} MB (the rest: pages of library files); {len(rss)} samples")  # fmt: skip
    grid = np.arange(MEMORY_WARM_UP_S, t[-1] + 1e-9, 1.0)
    lag = round(MEMORY_LAG_S)
    if len(grid) < 3 * lag:
        print(f"  {t[-1]:.0f} s sampled: too short to judge after the warm-up (NOT FLAT)")
        return False

    def per_minute(y: np.ndarray, part: slice = slice(None)) -> float:
        on_grid = np.interp(grid, t, y)
        increments = (on_grid[lag:] - on_grid[:-lag])[part]
        return float(np.median(increments)) * 60 / MEMORY_LAG_S

    high = np.maximum.accumulate(_level(anon))
    per_min = per_minute(high)
    per_h = per_min * 60
    flat = per_h < MEMORY_MAX_MB_PER_H
    level_per_h = per_minute(anon) * 60
    rss_per_h = per_minute(np.maximum.accumulate(_level(rss))) * 60
    fitted = float(np.polyfit(t[warm] / 60, rss[warm], 1)[0])
    print(f"  steady growth of the anonymous memory's high-water after warm-up (median over "
          f"{MEMORY_LAG_S:g} s): {per_min:+.3f} MB per wall minute = {per_h:+.1f} MB per hour "
          f"of running = {per_h * 8:+.0f} MB per 8-hour shift (flat: under "
          f"{MEMORY_MAX_MB_PER_H:g} MB per hour): {'flat' if flat else 'NOT FLAT'}; of the "
          f"anonymous level itself {level_per_h:+.1f}, of the RSS's high-water "
          f"{rss_per_h:+.1f} MB per hour")  # fmt: skip
    # growth that slows down from third to third is the end of the warm-up, a leak does not
    thirds = np.array_split(np.arange(len(grid) - lag), 3)
    by_third = [per_minute(high, slice(p[0], p[-1] + 1)) * 60 for p in thirds]
    print(f"  the same by thirds of the {grid[-1] - grid[0]:.0f} s judged: "
          + ", ".join(f"{x:+.1f}" for x in by_third) + " MB per hour")  # fmt: skip
    steps = memory.steps = _steps(t, rss)
    started = memory.started_unix
    events = [f"files rotate every {ROTATE_MINUTES * 60:.0f} s"]
    if started is not None and router.down_wall is not None and router.up_wall is not None:
        events.append(f"the router was down {router.down_wall - started:.0f}-"
                      f"{router.up_wall - started:.0f} s")  # fmt: skip
    level_anon = _level(anon)
    described = []
    for at, mb, since in steps:
        i, j = int(np.searchsorted(t, since)), int(np.searchsorted(t, at))
        gained = level_anon[j] - level_anon[i]
        described.append(f"{mb:+.2f} MB at {at:.0f} s (anonymous {gained:+.2f})")
    print(f"  RSS steps to a new high over {MEMORY_STEP_MB:g} MB within {MEMORY_STEP_S:g} s: "
          + (", ".join(described) or "none")
          + f" ({'; '.join(events)}); a line fitted to the RSS after warm-up, steps and all: "
          f"{fitted:+.3f} MB per wall minute")  # fmt: skip
    return flat


def probe_report(path: Path, memory: Memory) -> None:
    """What the daemon's memory was made of (bench/memory.py's probe), at start, after warm-up
    and at the end, and what each step added: Python's blocks (a leak or a cache of Python
    objects), malloc's memory in use (native allocations: the Rust libraries, buffers), free
    but held (fragmentation), in mappings of its own, the rest of the anonymous memory
    (pymalloc's arenas, thread stacks), and threads."""
    records = [json.loads(line) for line in path.read_text().splitlines() if line]
    if not records or not memory.samples:
        print("probe: no samples")
        return
    t0 = memory.samples[0][0]
    t = np.array([r["t"] for r in records]) - t0
    keys = ["rss", "anonymous", "in_use", "free_held", "mmapped", "py_blocks", "threads"]
    series = {k: np.array([float(r[k]) for r in records]) for k in keys}
    print("probe (MB; Python's blocks in thousands): " + ", ".join(keys))

    def at(when: float) -> str:
        i = min(int(np.searchsorted(t, when)), len(t) - 1)
        return " ".join(
            f"{series[k][i] / (1000 if k == 'py_blocks' else 1):.{0 if k == 'threads' else 2}f}"
            for k in keys
        )

    print(f"  start {at(0)}; after warm-up {at(MEMORY_WARM_UP_S)}; end {at(t[-1])}")
    for when, mb, _ in memory.steps:
        lo = max(0, int(np.searchsorted(t, when - MEMORY_STEP_S - 3)))
        hi = min(int(np.searchsorted(t, when + 3)), len(t) - 1)
        delta = {k: series[k][hi] - series[k][lo] for k in keys}
        print(f"  step {mb:+.2f} MB at {when:.0f} s: "
              + ", ".join(
                  f"{k} {delta[k] / (1000 if k == 'py_blocks' else 1):+.2f}" for k in keys
              ))  # fmt: skip
    traced = [r for r in records if "traced" in r]
    for before, after in itertools.pairwise(traced):
        grown = after["traced"]
        print(f"  tracemalloc {before['t'] - t0:.0f}-{after['t'] - t0:.0f} s: traced "
              f"{grown['total_kb']:.0f} kB; grew most (outermost frame first):")  # fmt: skip
        for entry in grown["grew"][:4]:
            print(f"    {entry['kb']:+8.1f} kB {entry['n']:+6d} blocks: "
                  + " < ".join(entry["where"][-4:]))  # fmt: skip


def _level(y: np.ndarray) -> np.ndarray:
    """The running median of 5 samples (a file's close dips the RSS for a sample or two)."""
    padded = np.pad(y, 2, mode="edge")
    return np.asarray(np.median(np.lib.stride_tricks.sliding_window_view(padded, 5), axis=1))


def _steps(t: np.ndarray, rss: np.ndarray) -> list[tuple[float, float, float]]:
    """(wall s it had risen by, MB, wall s it rose from) of each rise of the RSS to a new high
    by over ``MEMORY_STEP_MB`` within ``MEMORY_STEP_S``. The highest level so far is what
    rises: memory that comes back after a dip (a megabyte the allocator gave back and took
    again, seconds later) is no step."""
    high = np.maximum.accumulate(_level(rss))
    out: list[tuple[float, float, float]] = []
    i = 0
    while i < len(t):
        j = int(np.searchsorted(t, t[i] + MEMORY_STEP_S, side="right")) - 1
        if j > i and high[j] - high[i] > MEMORY_STEP_MB:
            out.append((float(t[j]), float(high[j] - high[i]), float(t[i])))
            i = j
        i += 1
    return out


def main(argv: list[str] | None = None) -> int:
    args_in = sys.argv[1:] if argv is None else argv
    if args_in[:1] == ["router"]:
        return run_router(args_in[1])
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=30.0)
    parser.add_argument("--speed", type=float, default=6.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--floors", type=int, default=4)
    parser.add_argument(
        "--keep", help="keep the outputs in this directory (the daemon's RSS: daemon_rss.csv)"
    )
    parser.add_argument("--probe", action="store_true", help="probe the daemon's memory")
    parser.add_argument("--census", type=float, default=0.0, help="with --probe: s between "
                        "censuses of Python objects by type")  # fmt: skip
    parser.add_argument("--trace-at", type=float, default=-1.0, help="with --probe: wall s at "
                        "which tracemalloc starts in the daemon")  # fmt: skip
    args = parser.parse_args(args_in)
    logs.configure("console", "WARNING")
    mission = Mission(
        seed=args.seed,
        floors=args.floors,
        route=default_route(args.floors),
        minutes=args.minutes,
        speed=args.speed,
        robot="soak",
    )
    scheduled = faults(mission, np.random.default_rng(args.seed))
    router = RouterRestart(
        f"tcp/127.0.0.1:{free_loopback_port()}",
        ROUTER_DOWN_AT * mission.minutes * 60,
        ROUTER_DOWN_AT * mission.minutes * 60 + ROUTER_DOWN_S,
    )
    memory = Memory()

    def every_second(sim_s: float, pid: int) -> None:
        memory.sample(pid)
        router.tick(sim_s)

    def show(item: Shown) -> None:
        if item.source != "progress" or "0 of" in item.text:
            print(f"  {item.source:>8s} | {item.text}", flush=True)

    load = os.getloadavg()[0]
    print(f"faults: {scheduled}")
    with tempfile.TemporaryDirectory(prefix="baromap-soak-") as tmp:
        out = Path(args.keep) if args.keep else Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        probed = out / "memprobe.jsonl"
        if args.probe:
            from memory import PROBE  # bench/memory.py, beside this script

            (out / "probe").mkdir(exist_ok=True)
            (out / "probe" / "sitecustomize.py").write_text(PROBE)
            probed.unlink(missing_ok=True)
            os.environ["PYTHONPATH"] = os.pathsep.join(
                [str(out / "probe"), *filter(None, [os.environ.get("PYTHONPATH")])]
            )
            os.environ["BAROMAP_MEMPROBE_OUT"] = str(probed)
            os.environ["BAROMAP_MEMPROBE_EVERY"] = "1"
            os.environ["BAROMAP_MEMPROBE_CENSUS"] = str(args.census)
            os.environ["BAROMAP_MEMPROBE_TRACE_AT"] = str(args.trace_at)
        router.start()
        try:
            live = run_live(
                mission,
                out,
                show,
                Additions(
                    config={
                        "recording": {
                            "rotate_size_mb": ROTATE_SIZE_MB,
                            "rotate_minutes": ROTATE_MINUTES,
                        },
                        "zenoh": {"connect": [router.endpoint]},
                    },
                    twins={"faults": scheduled},
                    watch_connect=router.endpoint,
                    every_second=every_second,
                ),
            )
        finally:
            router.stop()
        code = report(live, mission, scheduled, router, memory)
        if args.probe:
            probe_report(probed, memory)
        t0 = memory.samples[0][0] if memory.samples else 0.0
        rows = "".join(f"{t - t0:.1f},{mb:.3f},{anon:.3f}\n" for t, mb, anon in memory.samples)
        (out / "daemon_rss.csv").write_text("wall_s,rss_mb,anonymous_mb\n" + rows)
    print(f"machine: {os.cpu_count()} cores, load average {load:.1f} at start, "
          f"{os.getloadavg()[0]:.1f} at end")  # fmt: skip
    return code


if __name__ == "__main__":
    raise SystemExit(main())
