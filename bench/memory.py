"""Where baromapd's memory goes: the daemon on the pty twins (no faults), its C heap sampled.

The soak (bench/soak.py) says whether the daemon's memory is flat; this says why not. A probe
loaded into the daemon (a ``sitecustomize`` on its ``PYTHONPATH``, written here) samples every
``--every`` seconds its resident set, the anonymous part of it, and glibc's ``mallinfo2()``:
bytes in use, free but held, and in mappings of their own. Growth in use is a leak; growth of
free-but-held memory with nothing more in use is fragmentation. Printed: each figure at start,
after warm-up, at the end, and its slope after warm-up (the median of its increments over a
minute, per wall minute and per hour of running: the twins stream at their real rates).

``--old-read`` gives the daemon's readers an allocate-and-shrink read: ``os.read(fd, 65536)``,
which allocates 64 KiB per read and shrinks it, its result handed on as it is (a name or two
in ``baromapd.session`` swapped, not a copy of the reader), to show the growth such a read
causes and why the readers read into a reused buffer.

``rotations`` is the recorder's rotation alone, in this process: ``--files`` recordings opened,
given the daemon's JSON messages (pressure and health), closed, deleted; printed every fifth of
the way: resident and anonymous memory, Python's blocks, and the ``foxglove.Channel`` objects
still alive (the SDK kept every one in a registry of its own: the files' channels piled up).

    python bench/memory.py [--minutes 5] [--devices laser,base,barometer] [--zenoh]
                           [--compression zstd|lz4|none] [--old-read] [--warm-up 120]
                           [--every 5] [--trace-at S] [--keep FILE]
    python bench/memory.py rotations [--files 1000]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from baromap.sim.twins import SimDevices

PROBE = r"""
import collections, ctypes, gc, json, os, sys, threading, time

class _MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd",
                "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]

_libc = ctypes.CDLL("libc.so.6")
_libc.mallinfo2.restype = _MallInfo2
_OUT, _EVERY = os.environ["BAROMAP_MEMPROBE_OUT"], float(os.environ["BAROMAP_MEMPROBE_EVERY"])
# s between censuses of the collector's objects by type (0: none)
_CENSUS_EVERY = float(os.environ.get("BAROMAP_MEMPROBE_CENSUS", "0"))
# s after start at which tracemalloc starts (negative: never); then every _TRACE_EVERY s the
# biggest sources of what was allocated since and is still alive
_TRACE_AT = float(os.environ.get("BAROMAP_MEMPROBE_TRACE_AT", "-1"))
_TRACE_EVERY = 60.0

def _is_daemon():
    # the bench's children inherit the environment: only the daemon is probed
    with open("/proc/self/cmdline", "rb") as f:
        argv = f.read().split(b"\0")
    return any(a.endswith(b"/baromapd") or a == b"baromapd.main" for a in argv)

def _rollup():
    out = {}
    with open("/proc/self/smaps_rollup") as f:
        for line in f:
            parts = line.split()
            if parts[0] in ("Rss:", "Anonymous:"):
                out[parts[0][:-1]] = int(parts[1]) / 1024
    return out

class _FormerBuffer:
    # stands for a session's read buffer: it keeps what os.read(fd, 65536) returned, and its
    # slice is that very object (bytes() of a bytes is itself): the readers' former read
    data = b""

    def __getitem__(self, key):
        return self.data

class _FormerOs:
    def __getattr__(self, name):
        return getattr(os, name)

    @staticmethod
    def readv(fd, buffers):
        buffers[0].data = os.read(fd, 65536)
        return len(buffers[0].data)


_SNAPSHOT = []

def _mallocstats():
    # sys._debugmallocstats() writes to the C stderr: pymalloc's blocks by size class and the
    # objects the free lists keep. Lines others write meanwhile land in the file too.
    import tempfile
    with tempfile.TemporaryFile("w+") as f:
        sys.stderr.flush()
        saved = os.dup(2)
        try:
            os.dup2(f.fileno(), 2)
            sys._debugmallocstats()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        f.seek(0)
        return f.read()

def _traced():
    # what grew since the last snapshot, by where it was allocated (file:line, innermost
    # first; no source text: linecache would grow in the snapshot it is measuring)
    import tracemalloc
    snapshot = tracemalloc.take_snapshot().filter_traces(
        [tracemalloc.Filter(False, __file__), tracemalloc.Filter(False, tracemalloc.__file__)])
    previous = _SNAPSHOT[:1] or [snapshot]
    _SNAPSHOT[:] = [snapshot]
    stats = snapshot.compare_to(previous[0], "traceback")
    total = sum(s.size for s in snapshot.statistics("filename"))
    return {"total_kb": round(total / 1024, 1), "grew": [
        {"kb": round(s.size_diff / 1024, 1), "n": s.count_diff,
         "where": [f"{f.filename.rsplit('/', 2)[-1]}:{f.lineno}" for f in s.traceback]}
        for s in sorted(stats, key=lambda s: -s.size_diff)[:12]]}

def _sample():
    import tracemalloc
    start = time.monotonic()
    census_at = trace_at = -1e18
    while True:
        now = time.monotonic()
        info = _libc.mallinfo2()
        rollup = _rollup()
        record = {"t": now, "rss": rollup["Rss"], "anonymous": rollup["Anonymous"],
                  "in_use": info.uordblks / 2**20, "free_held": info.fordblks / 2**20,
                  "mmapped": info.hblkhd / 2**20, "py_blocks": sys.getallocatedblocks(),
                  "threads": len(os.listdir("/proc/self/task"))}
        if _CENSUS_EVERY > 0 and now - census_at >= _CENSUS_EVERY:
            census_at = now
            objects = gc.get_objects()  # made since the daemon froze its start-up objects
            counts = collections.Counter(type(o).__name__ for o in objects)
            record["census"] = dict(counts.most_common(80))
            # the largest containers, by identity: one that keeps growing holds the leak
            sized = [(len(o), id(o), o) for o in objects
                     if isinstance(o, (dict, list, set, collections.deque, bytearray))]
            sized.sort(key=lambda x: -x[0])
            record["largest"] = [
                [n, i, type(o).__name__, repr(next(iter(o), None))[:80] if n else ""]
                for n, i, o in sized[:40]]
            del objects, sized
            record["mallocstats"] = _mallocstats()
        if 0 <= _TRACE_AT <= now - start:
            if not tracemalloc.is_tracing():
                tracemalloc.start(8)
                trace_at = now
                record["traced"] = _traced()
            elif now - trace_at >= _TRACE_EVERY:
                trace_at = now
                record["traced"] = _traced()
        with open(_OUT, "a") as f:
            f.write(json.dumps(record) + "\n")
        time.sleep(_EVERY)

if _is_daemon():
    if os.environ.get("BAROMAP_MEMPROBE_OLD_READ"):
        import baromapd.session as _session
        _session.os = _FormerOs()
        _session.memoryview = lambda _: _FormerBuffer()
    threading.Thread(target=_sample, name="memprobe", daemon=True).start()
"""

CONFIG = """robot = "memory"
[recording]
directory = "{rec}"
min_free_mb = 0
compression = "{compression}"
rotate_size_mb = 4
rotate_minutes = 1
[zenoh]
{zenoh}
"""
DEVICES = {
    "laser": '[laser]\nport = "{lms200}"\nbaud = 500000\n',
    "base": '[base]\nport = "{p3at}"\n',
    "barometer": '[barometer]\nport = "{baro}"\nrate_hz = 50\n',
}
#: Slopes are the median of increments over this many seconds: a file's close dips the heap
#: for one sample, a rotation can step it once; neither is growth.
LAG_S = 60.0
FIGURES = {
    "rss": "resident set",
    "anonymous": "anonymous resident",
    "in_use": "malloc in use",
    "free_held": "malloc free but held",
    "mmapped": "malloc in own mappings",
    "py_blocks": "Python blocks (thousands)",
}


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _own_memory_mb() -> tuple[float, float]:
    kb = {}
    for line in Path("/proc/self/smaps_rollup").read_text().splitlines():
        key, _, rest = line.partition(":")
        if key in ("Rss", "Anonymous"):
            kb[key] = int(rest.split()[0])
    return kb["Rss"] / 1024, kb["Anonymous"] / 1024


def rotations(files: int) -> int:
    import gc

    import foxglove

    from baromap import logs
    from baromap.messages import DeviceHealth, DeviceState, PressureSample
    from baromap.recording import RecordingWriter

    logs.configure("console", "WARNING")
    t0 = 1_763_700_000_000_000_000
    print(f"{files} recordings opened, written to and closed in one process; "
          f"load {os.getloadavg()[0]:.1f}")  # fmt: skip
    print("  files  RSS MB  anonymous MB  Python blocks  foxglove.Channel alive")
    with tempfile.TemporaryDirectory(prefix="baromap-rotations-") as tmp:
        for part in range(files):
            path = Path(tmp) / f"run_{part:05d}.mcap"
            with RecordingWriter(path, robot="r", fsync=False) as writer:
                for k in range(20):
                    t = t0 + k * 20_000_000
                    writer.write(PressureSample(t, 101325.0 + k, 21.0, seq=k))
                    writer.write(DeviceHealth(t, "barometer", DeviceState.UP, "/dev/x", "", {}))
            path.unlink()
            if part % max(1, files // 5) == 0 or part == files - 1:
                gc.collect()
                alive = sum(isinstance(o, foxglove.Channel) for o in gc.get_objects())
                rss, anonymous = _own_memory_mb()
                print(f"  {part + 1:5d}  {rss:6.2f}  {anonymous:12.2f}  "
                      f"{sys.getallocatedblocks():13d}  {alive:5d}")  # fmt: skip
    return 0


def main() -> int:
    if sys.argv[1:2] == ["rotations"]:
        parser = argparse.ArgumentParser(description="the recorder's rotation alone")
        parser.add_argument("--files", type=int, default=1000)
        return rotations(parser.parse_args(sys.argv[2:]).files)
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=5.0, help="wall minutes")
    parser.add_argument("--speed", type=float, default=6.0, help="the mission's speed")
    parser.add_argument("--devices", default="laser,base,barometer")
    parser.add_argument("--zenoh", action="store_true", help="run the live publisher")
    parser.add_argument("--compression", default="zstd", choices=["zstd", "lz4", "none"])
    parser.add_argument("--old-read", action="store_true", help="the readers' former read")
    parser.add_argument("--warm-up", type=float, default=120.0, help="s before slopes are fitted")
    parser.add_argument("--every", type=float, default=5.0, help="s between samples")
    parser.add_argument("--keep", help="keep the probe's samples in this file (JSON lines)")
    parser.add_argument("--trace-at", type=float, default=-1.0, help="s at which tracemalloc "
                        "starts in the daemon (then what grew, every minute)")  # fmt: skip
    args = parser.parse_args()
    devices = [d for d in args.devices.split(",") if d]
    if not devices or any(d not in DEVICES for d in devices):
        parser.error(f"--devices: a comma-separated choice of {', '.join(DEVICES)}")
    zenoh = f'listen = ["tcp/127.0.0.1:{_free_port()}"]' if args.zenoh else "enabled = false"
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="baromap-memory-") as tmp:
        work = Path(tmp)
        (work / "probe").mkdir()
        (work / "probe" / "sitecustomize.py").write_text(PROBE)
        samples = work / "samples.jsonl"
        minutes = args.minutes * args.speed + 10
        with SimDevices(link_dir=work / "links", minutes=minutes, seed=11, speed=args.speed) as sim:
            config = CONFIG.format(rec=work / "rec", compression=args.compression, zenoh=zenoh)
            config += "".join(DEVICES[d].format(**sim.paths()) for d in devices)
            (work / "baromapd.toml").write_text(config)
            env = {
                **os.environ,
                "PYTHONPATH": os.pathsep.join(
                    [str(work / "probe"), *filter(None, [os.environ.get("PYTHONPATH")])]
                ),
                "BAROMAP_MEMPROBE_OUT": str(samples),
                "BAROMAP_MEMPROBE_EVERY": str(args.every),
                "BAROMAP_MEMPROBE_TRACE_AT": str(args.trace_at),
            }
            if args.old_read:
                env["BAROMAP_MEMPROBE_OLD_READ"] = "1"
            proc = subprocess.Popen(
                [sys.executable, "-m", "baromapd.main", "--config", str(work / "baromapd.toml")],
                stderr=(work / "daemon.log").open("wb"),
                env=env,
            )
            time.sleep(args.minutes * 60)
            proc.send_signal(signal.SIGTERM)
            code = proc.wait(60)
        records = [json.loads(line) for line in samples.read_text().splitlines()]
        if args.keep:
            Path(args.keep).write_text(samples.read_text())
    t = np.array([r["t"] for r in records]) - records[0]["t"]
    warm = t >= args.warm_up
    print(f"baromapd on the twins for {args.minutes:g} min (exit {code}): devices "
          f"{', '.join(devices)}, Zenoh {'on' if args.zenoh else 'off'}, compression "
          f"{args.compression}, {'former os.read' if args.old_read else 'current'} reads; "
          f"load {load_before:.1f} at start, {os.getloadavg()[0]:.1f} at end")  # fmt: skip
    if np.count_nonzero(warm) * args.every < 2 * LAG_S:
        print(f"  too short: {t[-1]:.0f} s sampled, warm-up {args.warm_up:g} s")
        return 1
    print(f"  MB at start / after {args.warm_up:g} s / at the end; slope after warm-up (median "
          f"over {LAG_S:g} s) per wall minute (per hour of running)")  # fmt: skip
    lag = max(1, round(LAG_S / args.every))
    for key, name in FIGURES.items():
        y = np.array([r[key] for r in records]) / (1000 if key == "py_blocks" else 1)
        slope = float(np.median(y[warm][lag:] - y[warm][:-lag])) * 60 / (lag * args.every)
        print(f"  {name:24s} {y[0]:7.1f} / {y[warm][0]:7.1f} / {y[-1]:7.1f}   "
              f"{slope:+.3f} ({slope * 60:+.1f})")  # fmt: skip
    traced = [r for r in records if "traced" in r]
    for before, after in itertools.pairwise(traced):
        grown = after["traced"]
        lo, hi = before["t"] - records[0]["t"], after["t"] - records[0]["t"]
        print(f"  tracemalloc {lo:.0f}-{hi:.0f} s: traced {grown['total_kb']:.0f} kB; grew most "
              "(outermost frame first):")  # fmt: skip
        for entry in grown["grew"][:5]:
            print(f"    {entry['kb']:+8.1f} kB {entry['n']:+6d} blocks: "
                  + " < ".join(entry["where"][-4:]))  # fmt: skip
    return 0 if code == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
