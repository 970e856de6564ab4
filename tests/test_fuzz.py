"""Mutated real files of every format end as a good mesh or one clean LoadError line.

A small, fixed run of scripts/fuzz.py (the large run and its figures are in
docs/reliability.md): real seed files of every format from the shared data, mutated with a
fixed seed, each loaded and cleaned in a worker process with a memory and a time limit.
No case may end as an uncaught exception, a wrapped internal exception, a native crash or
a hang, and nothing but the result may reach stderr (no numpy warning beside the line).
"""

from __future__ import annotations

import random

import pytest

from test_bombs import import_fuzz  # also puts scripts/ on sys.path

CASES = 600
SEED = 20260101


@pytest.fixture(scope="module")
def fuzz():
    return import_fuzz()


@pytest.fixture(scope="module")
def seeds(fuzz, data_dir):
    return fuzz.find_seeds(data_dir, per_kind=3, max_bytes=40_000, rng=random.Random(SEED))


def test_seeds_cover_every_format(fuzz, seeds):
    assert {s.kind for s in seeds} == set(fuzz.KINDS)


def test_cases_are_reproducible(fuzz, seeds):
    assert fuzz.make_case(seeds, SEED, 17) == fuzz.make_case(seeds, SEED, 17)
    assert fuzz.make_case(seeds, SEED, 17)[0] != fuzz.make_case(seeds, SEED, 18)[0]


def test_every_mutated_file_is_a_good_mesh_or_one_clean_line(fuzz, seeds):
    results = fuzz.fuzz(seeds, CASES, SEED, workers=2, memory=2 << 30, timeout=60, signature=False, keep=None)
    summary = fuzz.summarise(results)
    bad = [(info, r) for info, r in results if r["outcome"] not in fuzz.CLEAN]
    assert not bad, bad[:5]
    noisy = [(info, r) for info, r in results if r.get("warnings") or r.get("stderr")]
    assert not noisy, noisy[:5]
    # the run exercised both ends on every kind of file
    assert summary["outcomes"]["mesh"] >= CASES // 20 and summary["outcomes"]["load_error"] >= CASES // 2
    for kind, counts in summary["by_kind"].items():
        assert counts.get("load_error", 0) > 0, kind
    assert sum(counts.get("mesh", 0) > 0 for counts in summary["by_kind"].values()) >= len(fuzz.KINDS) - 2
