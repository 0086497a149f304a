"""The mapping gate: every shared laser log and variants of them that imitate real logs, each
over several seeds, through ``baromap import carmen`` and ``baromap build-maps`` as a user runs
them, compared with a baseline kept in the repository.

    .venv/bin/python bench/gate.py [--quick] [--cases REGEX] [--seeds 0,1,2] [--workers N]
                                   [--tree PATH] [--baseline FILE] [--write-baseline FILE]
                                   [--runs K] [--keep DIR] [--extra CASE] [--list]
                                   [--table FILE]

A case is a log, a part and stride of it, an odometry error model and a way of timing and
stamping its lines (baromap.evaluation.log_variants): ``intel``, ``fr079/10:slip``,
``acapulco:pauses``, ``acapulco:stamps=zero``. For each case and seed the gate writes a raw
CARMEN log (odometry made from the corrected poses, as ``ODOM`` lines and as the laser lines'
robot pose), imports it, builds the maps, and scores ``trajectory.tum`` against the corrected
poses: the absolute trajectory error after one rigid 2D alignment (ATE), the Kuemmerle
relations where the log has them (Intel, Freiburg 079, every scan kept), the scans missing
from the trajectory, and the warnings the two commands logged (a false "odometry silent" or
"placed by odometry across a gap alone" is a fault a user would chase).

One line per case: its figures (mean over the seeds, then min-max), the baseline's, and
``worse on CASE by ...`` where the mean is worse than the baseline's by more than the larger of
half the baseline's seed range, 5 % and a floor (3 mm ATE, 0.5 mm relations), or where scans go
missing, warnings appear or a command fails that did not before. The exit status is 1 then,
0 otherwise. ``--write-baseline FILE`` writes what this run measured, one line per case and
seed; change the repository's baseline (bench/gate-baseline.tsv) only in a commit that says why.

``--extra CASE`` runs a case the gate does not hold as well, over ``--seeds`` (0-2 by
default), with no baseline: ``corridor:exact`` maps with the reference itself as odometry
(``log_variants.ODOMETRY["exact"]``), which tells what the scans alone move the SLAM off the
reference from what odometry's errors leave in it.

``--quick`` runs the cases marked quick with seed 0 only (about 3 minutes on two idle cores);
the full gate every case over its seeds (about 20). ``--tree PATH`` runs the commands of
another checkout (``PYTHONPATH=PATH``; e.g. a ``git worktree`` of an older commit) with this
checkout's variants and scoring. Times: each case's CPU (both commands and their children),
and the wall time and load of the whole gate.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
LASER = Path(os.environ.get("BAROMAP_SHARED_DATA", REPO.parent / "shared" / "data")) / "laser"
BASELINE = REPO / "bench" / "gate-baseline.tsv"

#: Logs by the name a case gives them: file, relations file (None: scored by ATE only).
LOGS = {
    "intel": ("intel-corrected-abstime.log.gz", "intel.relations"),
    "fr079": ("freiburg-079-corrected-abstime.log.gz", "fr079.relations"),
    "acapulco": ("acapulco-corrected.log.gz", None),
    "belgioioso": ("belgioioso-corrected.log.gz", None),
    "corridor": ("infinite-corridor-corrected.log.gz", None),
    "campus": ("freiburg-campus-corrected.log.gz", None),
}

#: The cases: (name, seeds, in the quick subset). Names: LOG[/STRIDE][[a:b]][:VARIANT...],
#: a variant an odometry model (log_variants.ODOMETRY), a timing (log_variants.TIMINGS) or
#: stamps=KIND (log_variants.STAMPS).
CASES: list[tuple[str, tuple[int, ...], bool]] = [
    # every shared log as published, odometry at the scan times as --synth-odometry has it
    ("intel", (0, 1, 2), False),
    ("fr079", (0, 1, 2), False),
    ("acapulco", (0, 1, 2), False),
    ("belgioioso", (0, 1, 2), True),
    ("corridor", (0, 1, 2), False),
    ("campus", (0, 1, 2), False),
    # what real logs do with their time
    ("intel:pauses", (0, 1, 2), True),
    ("acapulco:pauses", (0, 1, 2), False),
    ("fr079/10:pauses", (0, 1, 2), True),
    ("intel:10hz", (0, 1, 2), False),
    ("intel:reset", (0, 1, 2), False),
    ("intel:quiet", (0, 1, 2), False),
    ("acapulco:stamps=constant", (0, 1, 2), False),
    ("intel:stamps=wrap", (0, 1, 2), True),
    # fewer scans
    ("intel/2", (0, 1, 2), False),
    ("fr079/10", (0, 1, 2), False),
    ("acapulco/2", (0, 1, 2), True),
    # odometry worse than the default in each way
    ("intel:scale", (0, 1, 2), False),
    ("acapulco:drift", (0, 1, 2), False),
    ("fr079/10:slip", (0, 1, 2), False),
    ("intel:noisy", (0, 1, 2), False),
    ("belgioioso:noisy", (0, 1, 2), False),
    ("fr079[0:1500]", (0, 1, 2), True),
]

#: Worse than the baseline when the mean over seeds is worse by more than the largest of
#: these: half the baseline's range over its seeds, a share of its mean, a floor.
SPREAD_SHARE = 0.5
RELATIVE = 0.05
FLOOR = {"ate_m": 0.003, "rel_m": 0.0005}
#: Warnings a case is expected to say nothing of when nothing broke (the variants break
#: nothing but the reset).
WATCHED = (
    "odometry silent",
    "part of the run is placed by odometry across a gap alone",
    "laser silent",
    "odometry counted from zero again: joined at the pose before",
)


@dataclass(frozen=True, slots=True)
class CaseSpec:
    name: str
    log: str
    stride: int
    part: tuple[int, int] | None
    odometry: str
    timing: str
    stamps: str


_CASE = re.compile(
    r"^(?P<log>[a-z0-9]+)(?:/(?P<stride>\d+))?(?:\[(?P<a>\d+):(?P<b>\d+)\])?(?P<rest>(?::[a-z0-9=]+)*)$"
)


def parse_case(name: str) -> CaseSpec:
    from baromap.evaluation.log_variants import ODOMETRY, STAMPS, TIMINGS

    match = _CASE.match(name)
    if match is None or match["log"] not in LOGS:
        raise SystemExit(f"gate: case {name!r} is not LOG[/N][[a:b]][:VARIANT...]")
    odometry, timing, stamps = "default", "scan", "asis"
    for word in filter(None, match["rest"].split(":")):
        if word in ODOMETRY:
            odometry = word
        elif word in TIMINGS:
            timing = word
        elif word.startswith("stamps=") and word[7:] in STAMPS:
            stamps = word[7:]
        else:
            raise SystemExit(f"gate: case {name!r}: unknown variant {word!r}")
    part = (int(match["a"]), int(match["b"])) if match["a"] is not None else None
    return CaseSpec(name, match["log"], int(match["stride"] or 1), part, odometry, timing, stamps)


def _load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.1f} (5 min {five:.1f}) on {os.cpu_count()} cpus"


# ---------------------------------------------------------------- one case, in its own process


def run_commands(case_dir: Path, tree: str | None, runs: int = 1) -> None:
    """Import the case's log and build its maps with the CLI of ``tree`` (this checkout when
    None), ``--runs runs`` where it is not 1; write what they said and their CPU into
    ``result.json``."""
    # run from the case's directory: python -m puts the working directory first on the path
    env = dict(os.environ)
    env["PYTHONPATH"] = (tree or str(REPO)) + os.pathsep + env.get("PYTHONPATH", "")
    base = [sys.executable, "-m", "baromap.cli", "--log-json", "--log-level", "WARNING"]
    log, run, out = (str(case_dir / n) for n in ("log.txt", "run.mcap", "out"))
    steps = [
        ("import", [*base, "import", "carmen", log, "-o", run]),
        ("build", [*base, "build-maps", run, "-o", out, "--no-progress"]),
    ]
    if runs != 1:
        steps[1][1].extend(["--runs", str(runs)])
    result: dict[str, object] = {"failed": None, "warnings": {}, "import_said": ""}
    warnings: dict[str, int] = {}
    for label, argv in steps:
        done = subprocess.run(
            argv, capture_output=True, text=True, env=env, cwd=case_dir, check=False
        )
        failure = ""
        for line in done.stderr.splitlines():
            try:
                event = json.loads(line)
            except ValueError:
                failure = failure or (line if line.startswith("baromap: error") else "")
                continue
            if event.get("event") == "command failed":
                failure = str(event.get("error"))
            if event.get("level") in ("warning", "error") or event.get("log_level") in (
                "warning",
                "error",
            ):
                name = str(event.get("event"))
                warnings[name] = warnings.get(name, 0) + 1
        if label == "import":
            result["import_said"] = done.stdout.strip()
        if done.returncode != 0:
            tail = failure or (done.stderr.strip().splitlines() or ["?"])[-1]
            result["failed"] = f"{label}: {tail[:300]}"
            break
    result["warnings"] = warnings
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    result["cpu_s"] = usage.ru_utime + usage.ru_stime
    (case_dir / "result.json").write_text(json.dumps(result))


# ---------------------------------------------------------------- the gate


@dataclass(slots=True)
class Outcome:
    case: str
    seed: int
    ate_m: float
    rel_m: float  # nan where the case has no relations
    lost: int  # scans missing from the trajectory
    warnings: dict[str, int]
    failed: str | None
    cpu_s: float

    def row(self) -> str:
        said = ",".join(f"{k}={v}" for k, v in sorted(self.warnings.items())) or "-"
        return "\t".join(
            [
                self.case,
                str(self.seed),
                f"{self.ate_m:.4f}",
                f"{self.rel_m:.5f}",
                str(self.lost),
                said.replace("\t", " "),
                (self.failed or "-").replace("\t", " "),
                f"{self.cpu_s:.1f}",
            ]
        )

    @classmethod
    def from_row(cls, line: str) -> Outcome:
        case, seed, ate, rel, lost, said, failed, cpu = line.rstrip("\n").split("\t")
        warnings = {}
        if said != "-":
            for item in said.split(","):
                k, _, v = item.rpartition("=")
                warnings[k] = int(v)
        return cls(
            case,
            int(seed),
            float(ate),
            float(rel),
            int(lost),
            warnings,
            None if failed == "-" else failed,
            float(cpu),
        )


HEADER = "case\tseed\tate_m\trel_m\tlost\twarnings\tfailed\tcpu_s"


def read_baseline(path: Path) -> dict[tuple[str, int], Outcome]:
    if not path.exists():
        return {}
    rows = [r for r in path.read_text().splitlines() if r and not r.startswith(("#", "case\t"))]
    return {(o.case, o.seed): o for o in map(Outcome.from_row, rows)}


class Sources:
    """Each shared log read once, its relations too."""

    def __init__(self) -> None:
        self._logs: dict[str, object] = {}

    def get(self, log: str):  # type: ignore[no-untyped-def]
        if log not in self._logs:
            from baromap.evaluation.log_variants import read_source
            from baromap.mapping.relations import read_relations

            name, relations = LOGS[log]
            source = read_source(LASER / name, log)
            self._logs[log] = (source, read_relations(LASER / relations) if relations else None)
        return self._logs[log]


def case_dir_name(name: str, seed: int) -> str:
    """The directory a case's seed is run in, under the gate's root or ``--keep DIR``."""
    return f"{re.sub(r'[^A-Za-z0-9=.-]+', '_', name)}-s{seed}"


def variant_of(spec: CaseSpec, source, seed: int):  # type: ignore[no-untyped-def]
    """The case's log for ``seed``, made from its source log."""
    from baromap.evaluation.log_variants import Variant, make_variant

    return make_variant(
        source, Variant(spec.odometry, spec.timing, spec.stamps, spec.stride, spec.part), seed
    )


def prepare(spec: CaseSpec, seed: int, sources: Sources, case_dir: Path):  # type: ignore[no-untyped-def]
    source, relations = sources.get(spec.log)
    variant = variant_of(spec, source, seed)
    case_dir.mkdir(parents=True, exist_ok=True)
    variant.write(case_dir / "log.txt")
    return source, relations, variant


def _tum(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Times (ns) and poses (x, y, yaw) of a trajectory.tum."""
    times, poses = [], []
    for line in path.read_text().splitlines():
        f = line.split()
        if len(f) < 8 or line.startswith("#"):
            continue
        whole, _, frac = f[0].partition(".")
        times.append(int(whole) * 1_000_000_000 + int((frac + "000000000")[:9]))
        qz, qw = float(f[6]), float(f[7])
        poses.append([float(f[1]), float(f[2]), 2.0 * math.atan2(qz, qw)])
    return np.array(times, dtype=np.int64), np.array(poses).reshape(-1, 3)


def scan_rows(variant, t: np.ndarray) -> np.ndarray | None:  # type: ignore[no-untyped-def]
    """Each of the variant's scans' row in a trajectory stamped ``t`` (-1: not in it), or
    None where scans are missing and the stamps do not say which."""
    n = len(variant.reference)
    if variant.scan_ns is not None:
        # the scans' own stamps (a variant's added scans are not among them)
        pos = np.clip(np.searchsorted(t, variant.scan_ns), 0, max(len(t) - 1, 0))
        hit = (len(t) > 0) & (t[pos] == variant.scan_ns) if len(t) else np.zeros(n, bool)
        return np.where(hit, pos, -1)
    if len(t) == n + variant.extra_scans and variant.extra_scans == 0:
        return np.arange(n)  # stamps made by the importer: the scans in order
    if len(t) < n:
        return None
    return np.full(n, -1)


def score(spec: CaseSpec, seed: int, case_dir: Path, prepared) -> Outcome:  # type: ignore[no-untyped-def]
    from baromap.evaluation.trajectory import trajectory_error
    from baromap.mapping.relations import relation_pairs

    source, relations, variant = prepared
    said = json.loads((case_dir / "result.json").read_text())
    nan = float("nan")
    out = Outcome(spec.name, seed, nan, nan, 0, said["warnings"], said["failed"], said["cpu_s"])
    tum = case_dir / "out" / "trajectory.tum"
    if out.failed is not None:
        return out
    if not tum.exists():
        out.failed = "build: no trajectory.tum"
        return out
    t, poses = _tum(tum)
    n = len(variant.reference)
    found = scan_rows(variant, t)
    if found is None:
        out.failed = f"{n - len(t)} scans missing and the stamps do not say which"
        out.lost = n - len(t)
        return out
    kept = found >= 0
    out.lost = int((~kept).sum())
    if kept.sum() < 2:
        out.failed = "fewer than two scans in the trajectory"
        return out
    est = np.full((n, 3), np.nan)
    est[kept] = poses[found[kept]]
    out.ate_m = trajectory_error(est[kept], variant.reference[kept]).rms_m
    if relations is not None and spec.stride == 1 and source.times_ns is not None:
        from baromap.mapping import se2

        times = source.times_ns[variant.source_index]
        i1, i2, motion, _ = relation_pairs(times, relations)
        ok = kept[i1] & kept[i2]
        if ok.any():
            error = se2.between(motion[ok], se2.between(est[i1[ok]], est[i2[ok]]))
            out.rel_m = float(np.mean(np.hypot(error[:, 0], error[:, 1])))
    return out


def _cost(spec: CaseSpec) -> float:
    """Rough CPU of a case, to start the longest first."""
    beams = {"fr079": 4791, "corridor": 1941, "campus": 2400, "acapulco": 1000, "intel": 910}
    scans = beams.get(spec.log, 500)
    if spec.part is not None:
        scans = min(scans, spec.part[1] - spec.part[0])
    return scans / spec.stride


def run_gate(
    cases: list[tuple[CaseSpec, int]],
    workers: int,
    tree: str | None,
    keep: Path | None,
    runs: int = 1,
) -> list[Outcome]:
    sources = Sources()
    root = keep or Path(tempfile.mkdtemp(prefix="baromap-gate-"))
    root.mkdir(parents=True, exist_ok=True)
    prepared = {}
    for spec, seed in cases:
        case_dir = root / case_dir_name(spec.name, seed)
        if case_dir.exists():
            shutil.rmtree(case_dir)
        prepared[(spec.name, seed)] = (case_dir, *prepare(spec, seed, sources, case_dir))
    order = sorted(cases, key=lambda c: -_cost(c[0]))

    def one(item: tuple[CaseSpec, int]) -> Outcome:
        spec, seed = item
        case_dir, *made = prepared[(spec.name, seed)]
        argv = [sys.executable, __file__, "--run-case", str(case_dir)]
        if tree:
            argv += ["--tree", tree]
        if runs != 1:
            argv += ["--runs", str(runs)]
        subprocess.run(argv, check=True)
        outcome = score(spec, seed, case_dir, made)
        if keep is None:
            shutil.rmtree(case_dir, ignore_errors=True)
        return outcome

    with ThreadPoolExecutor(max_workers=workers) as pool:
        outcomes = list(pool.map(one, order))
    if keep is None:
        shutil.rmtree(root, ignore_errors=True)
    return outcomes


def _fmt(values: list[float], digits: int) -> str:
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return "-"
    if len(finite) == 1:
        return f"{finite[0]:.{digits}f}"
    return f"{np.mean(finite):.{digits}f} ({min(finite):.{digits}f}-{max(finite):.{digits}f})"


def compare(
    names: list[str], outcomes: list[Outcome], baseline: dict[tuple[str, int], Outcome]
) -> tuple[list[str], list[str]]:
    """The table's lines and the ``worse on`` lines."""
    lines, worse = [], []
    by_case: dict[str, list[Outcome]] = {}
    for o in outcomes:
        by_case.setdefault(o.case, []).append(o)
    width = max(len(n) for n in names)
    lines.append(
        f"{'case':{width}}  seeds  {'ATE m (min-max)':24} {'base ATE m':24} "
        f"{'rel m':8} {'base rel':8} lost  warnings  cpu s"
    )
    for name in names:
        now = sorted(by_case.get(name, []), key=lambda o: o.seed)
        base = [baseline[(name, o.seed)] for o in now if (name, o.seed) in baseline]
        seeds = ",".join(str(o.seed) for o in now)
        failed = [o for o in now if o.failed]
        ate = [o.ate_m for o in now]
        rel = [o.rel_m for o in now]
        said = sum(sum(v for k, v in o.warnings.items() if k in WATCHED) for o in now)
        text = (
            f"{name:{width}}  {seeds:5}  {_fmt(ate, 3):24} "
            f"{_fmt([b.ate_m for b in base], 3) if base else 'none':24} "
            f"{_fmt(rel, 4).split(' ')[0]:8} {_fmt([b.rel_m for b in base], 4).split(' ')[0]:8} "
            f"{sum(o.lost for o in now):4}  {said:8}  {sum(o.cpu_s for o in now):5.0f}"
        )
        if failed:
            text += f"  FAILED {len(failed)}: {failed[0].failed}"
        lines.append(text)
        if not base:
            continue
        # judged on the seeds the baseline has
        now = [o for o in now if (name, o.seed) in baseline]
        failed = [o for o in now if o.failed]
        said = sum(sum(v for k, v in o.warnings.items() if k in WATCHED) for o in now)
        if failed and not any(b.failed for b in base):
            worse.append(f"worse on {name}: failed ({failed[0].failed})")
            continue
        for metric, digits in (("ate_m", 3), ("rel_m", 4)):
            a = [getattr(o, metric) for o in now]
            b = [getattr(o, metric) for o in base]
            if not all(map(math.isfinite, a + b)) or not a:
                continue
            full = [
                getattr(o, metric)
                for (c, _), o in baseline.items()
                if c == name and math.isfinite(getattr(o, metric))
            ]
            spread = (max(full) - min(full)) if full else 0.0
            tolerance = max(SPREAD_SHARE * spread, RELATIVE * float(np.mean(b)), FLOOR[metric])
            gap = float(np.mean(a) - np.mean(b))
            if gap > tolerance:
                worse.append(
                    f"worse on {name} by {gap:.{digits}f} m {metric[:-2].upper()} "
                    f"({np.mean(a):.{digits}f} against {np.mean(b):.{digits}f}, "
                    f"tolerance {tolerance:.{digits}f})"
                )
        lost_now, lost_base = sum(o.lost for o in now), sum(o.lost for o in base)
        if lost_now > lost_base:
            worse.append(f"worse on {name}: {lost_now} scans missing, {lost_base} before")
        said_base = sum(sum(v for k, v in o.warnings.items() if k in WATCHED) for o in base)
        if said > said_base:
            worse.append(f"worse on {name}: {said} gap/silence warnings, {said_base} before")
    return lines, worse


def markdown_table(path: Path) -> list[str]:
    """A baseline file as a Markdown table, one row per case: the means over its seeds and
    their range, the scans lost, the watched warnings and the failures over all seeds."""
    by_case: dict[str, list[Outcome]] = {}
    for outcome in read_baseline(path).values():
        by_case.setdefault(outcome.case, []).append(outcome)
    lines = [
        "| case | seeds | ATE m (min-max) | relations m (min-max) | lost | warnings | failed |"
        " CPU s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, _, _ in CASES:
        now = sorted(by_case.get(name, []), key=lambda o: o.seed)
        if not now:
            continue
        said = sum(sum(v for k, v in o.warnings.items() if k in WATCHED) for o in now)
        seeds = ",".join(str(o.seed) for o in now)
        lines.append(
            f"| `{name}` | {seeds} | {_fmt([o.ate_m for o in now], 3)} "
            f"| {_fmt([o.rel_m for o in now], 4)} | {sum(o.lost for o in now)} | {said} "
            f"| {sum(1 for o in now if o.failed)} | {sum(o.cpu_s for o in now):.0f} |"
        )
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the quick subset, seed 0")
    parser.add_argument("--cases", default=None, help="only the cases whose name matches REGEX")
    parser.add_argument(
        "--seeds",
        default=None,
        help="these seeds of every chosen case (comma-separated); seeds the baseline does not "
        "hold are measured and not compared",
    )
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--tree", default=None, help="run the commands of this checkout")
    parser.add_argument("--baseline", type=Path, default=BASELINE)
    parser.add_argument("--write-baseline", type=Path, default=None, metavar="FILE")
    parser.add_argument("--keep", type=Path, default=None, help="keep each case's files here")
    parser.add_argument(
        "--runs",
        type=int,
        default=1,
        metavar="K",
        help="build-maps --runs K (default 1, build-maps' own default)",
    )
    parser.add_argument(
        "--extra",
        action="append",
        default=[],
        metavar="CASE",
        help="also run CASE, one of no gate case (e.g. corridor:exact), over its --seeds",
    )
    parser.add_argument("--list", action="store_true", help="list the cases and exit")
    parser.add_argument(
        "--table", type=Path, default=None, metavar="FILE", help="print FILE as Markdown and exit"
    )
    parser.add_argument("--run-case", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.run_case is not None:
        run_commands(args.run_case, args.tree, args.runs)
        return 0
    if args.table is not None:
        print("\n".join(markdown_table(args.table)))
        return 0
    chosen = [
        (parse_case(name), seeds)
        for name, seeds, quick in CASES
        if (quick or not args.quick) and (args.cases is None or re.search(args.cases, name))
    ]
    chosen += [(parse_case(name), (0, 1, 2)) for name in args.extra]
    only = tuple(int(s) for s in args.seeds.split(",")) if args.seeds else None
    cases = [
        (spec, seed)
        for spec, seeds in chosen
        for seed in (only if only is not None else seeds[:1] if args.quick else seeds)
    ]
    if args.list:
        for spec, seed in cases:
            print(f"{spec.name} seed {seed}")
        return 0
    if not LASER.is_dir():
        print(f"gate: the laser logs are not at {LASER} (set BAROMAP_SHARED_DATA)")
        return 2
    start = time.perf_counter()
    outcomes = run_gate(cases, args.workers, args.tree, args.keep, args.runs)
    wall = time.perf_counter() - start
    baseline = read_baseline(args.baseline)
    lines, worse = compare([s.name for s, _ in chosen], outcomes, baseline)
    print("\n".join(lines))
    cpu = sum(o.cpu_s for o in outcomes)
    print(
        f"{len(outcomes)} runs in {wall / 60:.1f} min wall, {cpu / 60:.1f} min CPU, "
        f"{args.workers} workers; {_load()}"
    )
    print(f"baseline: {args.baseline if baseline else 'none'}")
    if args.write_baseline:
        rows = sorted(outcomes, key=lambda o: ([s.name for s, _ in chosen].index(o.case), o.seed))
        args.write_baseline.write_text(HEADER + "\n" + "\n".join(o.row() for o in rows) + "\n")
        print(f"wrote {args.write_baseline}")
    print("\n".join(worse) if worse else "worse on: none")
    return 1 if worse else 0


if __name__ == "__main__":
    raise SystemExit(main())
