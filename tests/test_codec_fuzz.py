"""Short fuzz pass over every codec in bench/codecs.py's registry (the bench runs 1,000,000).

Inputs are random bytes and mutated windows of valid streams (bit flips, insertions,
deletions, truncations, duplicated slices, tampered LEN/COUNT), fed in random chunks: no input
may raise, every input fed whole must decode exactly as it did chunked, and the wire sizes of
the items decoded must add up to the bytes fed.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

BENCH = Path(__file__).resolve().parent.parent / "bench" / "codecs.py"
FUZZ_INPUTS = 20_000


def _load_bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_codecs", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses resolve their module by name
    spec.loader.exec_module(module)
    return module


bench = _load_bench()


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(bench.CODECS))
def test_fuzz_pass_raises_nothing_and_chunking_never_matters(name: str) -> None:
    result = bench.fuzz_codec(name, FUZZ_INPUTS, seed=1234, compare_every=1)
    assert result.inputs == FUZZ_INPUTS
    assert result.exceptions == 0, "\n".join(result.first_errors)
    assert result.mismatches == 0, "\n".join(result.first_errors)
    assert result.miscounted == 0, "\n".join(result.first_errors)
    assert result.messages > FUZZ_INPUTS // 2  # the mutated windows still hold real frames
    assert result.bad["garbage"] > 0


@pytest.mark.parametrize("name", sorted(bench.CODECS))
def test_registry_streams_decode_cleanly(name: str) -> None:
    make_stream, make_decoder = bench.CODECS[name]
    stream = make_stream(50)
    decoder = make_decoder()
    out = decoder.feed(stream)
    out += getattr(decoder, "flush", list)()
    assert len(out) >= 50
    assert sum(decoder.stats.bad.values()) == 0
