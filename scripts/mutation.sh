#!/usr/bin/env bash
# Mutation testing (mutmut) of one part, in a scratch copy of HEAD, with the narrowest tests
# that cover it; not part of `make test` (CPU-heavy: run it nice'd). docs/mutation.md has the
# figures and the survivors.
#
#   scripts/mutation.sh protocols|recorder|detector [SCRATCH_DIR]
#
# MUTANTS='GLOB ...' runs only the mutants whose names match (fnmatch), e.g. a sample:
# MUTANTS='*__mutmut_*3 *__mutmut_*7' is every mutant whose number ends in 3 or 7 (a fifth).
# The summary counts the mutants run; the ones not run are reported apart.
#
# Needs the checkout's .venv (`make setup`) and mutmut in it (`.venv/bin/pip install mutmut`).
set -euo pipefail

part=${1:?usage: scripts/mutation.sh protocols|recorder|detector [SCRATCH_DIR]}
repo=$(cd "$(dirname "$0")/.." && pwd)
scratch=${2:-${TMPDIR:-/tmp}/baromap-mutation-$part}

# mutmut names a mutant by its file's path from the copy's root, so the daemon's package is
# moved there (daemon/baromapd -> baromapd) for its modules to be named as they are imported.
case $part in
  protocols)
    only='baromap/protocols/*'
    # The long drives in test_p2os.py test the odometry integrator (a third of these files'
    # test time): every codec function they call is tested in these files already.
    tests='tests/test_lms200.py tests/test_p2os.py tests/test_baro_codec.py
      --deselect=tests/test_p2os.py::test_long_drives_cross_the_wrap_without_losing_a_tick
      --deselect=tests/test_p2os.py::test_ten_kilometre_drive_in_both_directions'
    # no test of these files takes more than 3 s at a load of 10
    test_timeout=20
    ;;
  recorder)
    only='baromapd/recorder.py'
    tests='tests/daemon/test_daemon_recorder.py'
    test_timeout=180
    ;;
  detector)
    only='baromap/floors/online.py'
    # the detector's decisions (test_floors_online.py), its edges: thresholds met exactly,
    # gaps, the first samples, finish (test_floors_online_edges.py), and its live account:
    # rides, names, corrections (test_floors_live.py); none takes more than 5 s at a load of 10
    tests='tests/test_floors_online.py tests/test_floors_online_edges.py tests/test_floors_live.py'
    test_timeout=60
    ;;
  *) echo "unknown part $part" >&2; exit 2 ;;
esac

rm -rf "$scratch"
mkdir -p "$scratch"
git -C "$repo" archive HEAD | tar -x -C "$scratch"
mv "$scratch/daemon/baromapd" "$scratch/baromapd"
# The root conftest only loads pytest_baromap, which the installed entry point loads anyway;
# mutmut, taking "." off sys.path, makes it unimportable (pytest exit 4).
rm "$scratch/conftest.py"
# mutmut reads its settings from setup.cfg; the list values are one per line.
{
  echo "[mutmut]"
  # without it, this mutmut (3.8) ran its statistics pass into a pytest usage error (exit 4)
  echo "debug=true"
  echo "source_paths="
  echo "    ."
  echo "only_mutate="
  echo "    $only"
  echo "pytest_add_cli_args_test_selection="
  for t in $tests; do echo "    $t"; done
  # A mutant that loops forever is killed by a test's timeout (several times the test's
  # longest run at a load of 10), not only by mutmut's CPU limit, which is many times the
  # run of every test that covers the function.
  echo "timeout_multiplier=3.0"
  echo "pytest_add_cli_args="
  echo "    --timeout=$test_timeout"
  echo "    -p"
  echo "    no:cacheprovider"
  echo "    -x"
  echo "    -q"
} > "$scratch/setup.cfg"
cd "$scratch"
# The copy's own code must be what the tests import, not the checkout's editable install:
# a venv that sees the checkout venv's packages through a .pth line (whose own .pth files,
# the editable install's finder among them, are then not run), and the copy on PYTHONPATH.
"$repo/.venv/bin/python" -m venv --without-pip "$scratch/venv"
site=$("$scratch/venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
"$repo/.venv/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])' > "$site/checkout-venv.pth"
# mutmut takes the directory it runs the tests in off sys.path, so the copy's packages are
# found by a finder of their own (as an editable install's are).
cat > "$site/baromap_mutants.py" <<PY
import importlib.machinery
import sys


class MutantsFinder:
    @classmethod
    def find_spec(cls, name, path=None, target=None):
        if path is None and name in ("baromap", "baromapd", "pytest_baromap"):
            return importlib.machinery.PathFinder.find_spec(name, ["$scratch/mutants"])
        return None


sys.meta_path.insert(0, MutantsFinder)
PY
echo "import baromap_mutants" > "$site/baromap-mutants.pth"
# shellcheck disable=SC2086  # MUTANTS is a list of globs, each an argument, unexpanded
(set -f; "$scratch/venv/bin/python" -m mutmut run --max-children "${MUTMUT_CHILDREN:-2}" ${MUTANTS:-}) || true
"$scratch/venv/bin/python" -m mutmut results --all true > "$scratch/results.txt" || true
"$repo/.venv/bin/python" - "$scratch/results.txt" <<'PY'
import collections, sys
counts = collections.Counter()
survivors = []
for line in open(sys.argv[1]):
    name, _, status = line.strip().rpartition(": ")
    if not name:
        continue
    counts[status] += 1
    if status == "survived":
        survivors.append(name)
not_run = counts.pop("not checked", 0)
total = sum(counts.values())
killed = counts["killed"] + counts["timeout"]
print(dict(counts), f"(not run: {not_run})")
print(f"killed {killed} of {total} run: {100 * killed / max(total, 1):.1f} %")
print("survivors:")
for name in survivors:
    print("  ", name)
PY
