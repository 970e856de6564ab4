"""Start-up: ``--version`` and ``--help`` import no heavy library; the CLI's copied defaults are the library's.

The time itself is measured by scripts/bench_startup.py (not a timed test).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("numpy", "h5py", "scipy", "trimesh", "embreex", "manifold3d", "igl")

PROBE = """
import json, sys
from shapeidx.cli import main
try:
    main({args!r})
except SystemExit:
    pass
print(json.dumps(sorted({{m.split('.')[0] for m in sys.modules}})), file=sys.stderr)
"""


def imported_by(args: list[str]) -> set[str]:
    """Top-level modules a fresh interpreter holds after ``shapeidx ARGS``."""
    proc = subprocess.run([sys.executable, "-c", PROBE.format(args=args)], capture_output=True, text=True, timeout=60)
    return set(json.loads(proc.stderr.strip().splitlines()[-1]))


@pytest.mark.parametrize("args", [["--version"], ["--help"], [], ["query", "--help"], ["build", "--help"],
                                  ["evaluate", "--help"], ["check", "--help"], ["stats", "--help"]])
def test_version_and_help_import_no_heavy_module(args):
    heavy = imported_by(args) & set(HEAVY)
    assert not heavy, f"shapeidx {' '.join(args)} imported {sorted(heavy)}"


def test_a_real_command_does_import_them():
    """The probe can fail: a command that works imports numpy and h5py."""
    assert {"numpy", "h5py"} <= imported_by(["stats", "--store", "/nonexistent/x.h5"])


def test_the_copied_defaults_equal_the_librarys():
    from shapeidx.console import params
    from shapeidx.distance import METRICS
    from shapeidx.index.commit import DEFAULT_COMMIT_INTERVAL, MERGE_AFTER
    from shapeidx.index.workers import DEFAULT_TIMEOUT
    from shapeidx.signing.parameters import DEFAULT_POINTS, DEFAULT_SEED
    from shapeidx.store.layout import DEFAULT_STORE, STORE_ENV

    assert params.METRICS == tuple(METRICS)
    assert (params.DEFAULT_POINTS, params.DEFAULT_SEED) == (DEFAULT_POINTS, DEFAULT_SEED)
    assert (params.DEFAULT_STORE, params.STORE_ENV) == (DEFAULT_STORE, STORE_ENV)
    assert (params.DEFAULT_COMMIT_INTERVAL, params.MERGE_AFTER, params.DEFAULT_TIMEOUT) == (
        DEFAULT_COMMIT_INTERVAL, MERGE_AFTER, DEFAULT_TIMEOUT)
