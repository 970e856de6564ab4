"""The store contract: what every kind of store promises, one suite that each kind passes (as
zarr-python's ``StoreTests``).

The kinds: an ordinary store (``build``), a sharded store (``build --shards``: N ordinary stores
under one manifest) and a sub-parts store (``build --parts``: ``STORE/parts``, asked through its
owner). Each is driven as a user drives it, through the command line: opened and read
(``stats``), searched (``query``), committed to (an incremental build), killed mid-build
(``kill -9`` of a real build process), checked, damaged (bytes of a main file flipped) and
repaired with the very command its damage message names. The reference for every count is the
tree itself (files, or the sub-parts an ordinary ``--parts`` build reports), not the kind's code.
"""

from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import pytest
from clitools import cli, cli_json, shapeidx_command
from storetools import FAST_POINTS, build, copy_tree

FOLDERS = ("Diode_SMD", "LED_SMD")
KINDS = ("one", "sharded", "parts")
SHARDS = 2


@dataclass
class Kind:
    """How a user addresses one kind of store."""

    name: str
    store: Path  # what --store takes for build, query, check
    build_args: tuple  # what its build takes beyond the tree and --store

    @property
    def data(self) -> Path:
        """The store that holds the entries (the sub-parts store of a --parts build)."""
        return self.store / "parts" if self.name == "parts" else self.store

    def main_files(self) -> list[Path]:
        if self.name == "sharded":
            return sorted(self.store.glob("shards/*/main.h5"))
        return [self.data / "main.h5"]

    def query_args(self) -> tuple:
        return ("--parts",) if self.name == "parts" else ()

    def entries(self) -> int:
        """Entries the store holds, as ``stats`` reports them."""
        facts = cli_json("stats", "--store", self.store)
        return facts["parts"]["entries"] if self.name == "parts" else facts["entries"]

    def some_entry(self) -> str:
        """An entry of the store: the first file, or its first sub-part."""
        return f"{self.first_file}#1" if self.name == "parts" else self.first_file


def make(kind: str, tree: Path, store: Path) -> Kind:
    extra = {"one": (), "sharded": ("--shards", SHARDS), "parts": ("--parts",)}[kind]
    return Kind(kind, store, ("--workers", "1") + extra)


def files_of(tree: Path) -> list[str]:
    return sorted(p.relative_to(tree).as_posix() for p in tree.rglob("*.wrl"))


def first_answer(result) -> dict:
    data = json.loads(result.stdout)
    return data[0] if isinstance(data, list) else data


@pytest.fixture(scope="module")
def reference(data_dir, tmp_path_factory):
    """The tree, and the sub-parts an ordinary --parts build of it reports (the parts kind's count)."""
    tmp = tmp_path_factory.mktemp("contract")
    tree = copy_tree(data_dir / "kicad6", tmp / "tree", FOLDERS)
    result = build(tree, tmp / "ref.shapeidx", "--workers", "1", "--parts")
    assert result.exit_code == 0, result.output
    sub_entries = cli_json("stats", "--store", tmp / "ref.shapeidx")["parts"]["entries"]
    return tree, sub_entries


@pytest.fixture(params=KINDS)
def store(request, reference, tmp_path):
    """A store of each kind, built from a copy of the reference tree."""
    tree = copy_tree(reference[0], tmp_path / "tree")
    kind = make(request.param, tree, tmp_path / f"{request.param}.shapeidx")
    result = build(tree, kind.store, *kind.build_args)
    assert result.exit_code == 0, result.output + result.stderr
    kind.tree = tree
    kind.first_file = files_of(tree)[0]
    return kind


def expected_entries(kind: Kind, reference) -> int:
    return reference[1] if kind.name == "parts" else len(files_of(reference[0]))


def test_open_and_read(store, reference):
    assert store.entries() == expected_entries(store, reference)
    facts = cli_json("stats", "--store", store.store)
    assert facts["parameters"]["points"] == int(FAST_POINTS) and facts["failed"] == 0


def test_search_finds_an_entry_first(store):
    entry = store.some_entry()
    result = cli("query", "--id", entry, "--store", store.store, *store.query_args(), "--top", 5, "--json")
    assert result.exit_code == 0, result.output + result.stderr
    hits = first_answer(result)["hits"]
    assert hits[0]["relative_path"] == entry and hits[0]["distance"] == 0
    assert [h["distance"] for h in hits] == sorted(h["distance"] for h in hits) and len(hits) == 5


def test_check_is_ok(store, reference):
    report = cli_json("check", "--store", store.store)
    assert report["ok"] and report["problems"] == []
    held = report["parts"]["entries"] if store.name == "parts" else report["entries"]
    assert held == expected_entries(store, reference)


def test_a_commit_is_seen_by_the_next_question(store, data_dir, reference):
    before = store.entries()
    new = data_dir / "kicad6" / "Resistor_SMD"
    added = sorted(new.glob("*.wrl"))[0]
    target = store.tree / "Resistor_SMD" / added.name
    target.parent.mkdir()
    target.write_bytes(added.read_bytes())
    result = build(store.tree, store.store, *store.build_args)
    assert result.exit_code == 0, result.output + result.stderr
    assert store.entries() > before
    # the new file answers a query of itself first
    result = cli("query", target, "--store", store.store, *store.query_args(), "--top", 1, "--json")
    assert result.exit_code == 0, result.output + result.stderr
    assert first_answer(result)["hits"][0]["path"] == str(target)
    assert cli_json("check", "--store", store.store)["ok"]


def test_damage_is_named_in_one_line_and_its_named_command_repairs_it(store):
    entries = store.entries()
    main = store.main_files()[-1]
    data = bytearray(main.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 4000] = bytes(b ^ 0x5A for b in data[middle : middle + 4000])
    main.write_bytes(data)
    checked = cli("check", "--store", store.store)
    assert checked.exit_code == 5, checked.output + checked.stderr
    named = main.relative_to(store.store).as_posix()
    assert f"problem: {named}: " in checked.stderr, checked.stderr
    assert "Traceback" not in checked.output + checked.stderr
    # a query meets the damage in one line (exit 5) naming the commands that list and repair it
    entry = store.first_file
    asked = cli("query", store.tree / entry, "--store", store.store, *store.query_args())
    if asked.exit_code != 0:  # the flipped bytes may lie where this query does not read
        assert asked.exit_code == 5 and len(asked.stderr.strip().splitlines()) == 1, asked.stderr
        assert "'shapeidx check --store " in asked.stderr and "Traceback" not in asked.stderr
    # the repair command check names, as printed, with the tree for DIR
    repair = checked.stdout.split("'")[1]
    words = shlex.split(repair.replace("DIR", str(store.tree), 1))
    assert words[:2] == ["shapeidx", "build"] and "--repair" in words
    result = cli(*words[1:], "--points", FAST_POINTS, "--workers", "1")
    assert result.exit_code == 0, result.output + result.stderr
    assert cli_json("check", "--store", store.store)["ok"]
    assert store.entries() == entries


def _committed_anything(kind: Kind) -> bool:
    return any(p.exists() for p in ([kind.data / "committed"] if kind.name != "sharded"
                                    else list(kind.store.glob("shards/*/committed"))))


def test_kill_9_mid_build_loses_nothing_committed(reference, tmp_path):
    """A real build process killed (SIGKILL, its workers too) once it has committed: the store
    checks ok, keeps what it committed, and the next build finishes it; for every kind."""
    for name in KINDS:
        tree = copy_tree(reference[0], tmp_path / name / "tree")
        kind = make(name, tree, tmp_path / name / "s.shapeidx")
        process = subprocess.Popen(
            shapeidx_command("build", tree, "--store", kind.store, "--points", FAST_POINTS, "--commit-interval", "0.1",
                             *kind.build_args),
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        deadline = time.time() + 120
        while not _committed_anything(kind) and process.poll() is None and time.time() < deadline:
            time.sleep(0.05)
        assert process.poll() is None, f"{name}: the build finished before it could be killed"
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
        report = cli_json("check", "--store", kind.store)
        assert report["ok"], (name, report["problems"])
        held = kind.entries()
        print(f"{name}: killed holding {held} of {expected_entries(kind, reference)}")
        assert 0 < held, name
        result = build(tree, kind.store, *kind.build_args)
        assert result.exit_code == 0, (name, result.output + result.stderr)
        assert kind.entries() == expected_entries(kind, reference), name
        assert cli_json("check", "--store", kind.store)["ok"], name
