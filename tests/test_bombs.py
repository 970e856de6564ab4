"""Bombs: small files that claim or expand to enormous parts are refused quickly, in bounded memory.

Each bomb (scripts/bombs.py: made by code, no big file is stored) is loaded and cleaned with
the default limits in a worker process that has a memory limit (RLIMIT_DATA) and a time
limit, the same guarded worker the fuzzer uses (scripts/fuzz.py). Each must end as one clean
line naming the file and the reason, well inside both limits, and the worker's peak memory
is checked against a bound far below what the bomb would need.
"""

from __future__ import annotations

import sys

import pytest

from shapeidx.errors import LoadError
from shapeidx.io import LoadLimits, load
from storetools import REPO

WORKER_MEMORY = 2 << 30  # the worker's RLIMIT_DATA
PEAK_MB = 700  # no bomb may make the worker's resident memory exceed this
SECONDS = 120  # wall time before a case counts as a hang (a busy machine stretches it)
CPU_SECONDS = 10  # what each bomb may cost

if str(REPO / "scripts") not in sys.path:
    # the scripts as modules importable by name: the fuzzer's spawned workers (which get
    # this process's sys.path) import it to find their entry point
    sys.path.insert(0, str(REPO / "scripts"))
import bombs  # noqa: E402


def import_fuzz():
    import fuzz

    return fuzz


@pytest.fixture(scope="module")
def bomb_results(tmp_path_factory):
    """Every bomb written and run once in guarded workers: name -> (path, result)."""
    return bombs.run_bombs(tmp_path_factory.mktemp("bombs"), WORKER_MEMORY, SECONDS)


@pytest.mark.parametrize("name", list(bombs.BOMBS))
def test_bomb_is_refused_quickly_in_bounded_memory(bomb_results, name):
    path, result = bomb_results[name]
    assert result["outcome"] == "load_error", result
    message = result["error"]
    assert message.startswith(str(path)) and "\n" not in message
    assert bombs.BOMBS[name][2] in message, message
    assert result["cpu_seconds"] < CPU_SECONDS, result
    assert result["peak_kb"] < PEAK_MB * 1024, result
    assert not result.get("warnings") and not result.get("stderr"), result


def test_the_memory_budget_is_configurable(tmp_path):
    n = 30  # an n x n grid: 2 n^2 triangles over (n + 1)^2 points
    lines = [f"OFF\n{(n + 1) ** 2} {n * n} 0"] + [f"{x} {y} 0" for y in range(n + 1) for x in range(n + 1)]
    lines += [f"4 {y * (n + 1) + x} {y * (n + 1) + x + 1} {(y + 1) * (n + 1) + x + 1} {(y + 1) * (n + 1) + x}" for y in range(n) for x in range(n)]
    path = tmp_path / "grid.off"
    path.write_text("\n".join(lines) + "\n")
    assert len(load(path).face_sizes) == 900
    need = LoadLimits().estimated_bytes(1800, 961)
    with pytest.raises(LoadError, match=r"would need about 1\.4 MiB of memory \(1,800 triangles, 961 vertices\), more than the limit of 1\.0 MiB"):
        load(path, LoadLimits(max_bytes=1 << 20))
    assert len(load(path, LoadLimits(max_bytes=need)).face_sizes) == 900
    # VRML is refused from its counted expansion, before any array is built
    doubled = tmp_path / "doubled.wrl"
    doubled.write_text("#VRML V2.0 utf8\n" + bombs.doubling(4, "Group { children [ " + bombs.grid_face_set(n) + " ] }"))
    with pytest.raises(LoadError, match=r"\(55,800 triangles\)"):
        load(doubled, LoadLimits(max_bytes=10_000_000))
