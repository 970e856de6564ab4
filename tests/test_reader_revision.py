"""A format's reader revision (``Format.revision``, ``entries/revision``): a build signs again
the entries an older reader of their format signed, and only those.

The stale entries are real: the EI54 transformer's old entry is what the STEP reader made
before the multi-turn repair (its ``unwound`` patched out, in this process), committed with
revision 1 and the file's own size, time and hash, exactly as a store built by the previous
release holds it. A build must find it by its revision alone, sign it again without the
same-content shortcut, leave the VRML and STL entries alone, and end with the store a fresh
build makes, bit for bit.
"""

from __future__ import annotations

import glob
import json
import os
import shutil
import signal
import subprocess

import h5py
import numpy as np
import pytest
from clitools import cli, shapeidx_command
from storetools import FAST_POINTS, build, copy_tree, summary_counts

from shapeidx.index.build import BuildOptions
from shapeidx.index.plan import make_plan
from shapeidx.index.walk import walk_parts
from shapeidx.io import FORMATS, reader_revision
from shapeidx.store import Batch, StoreWriter, open_store
from shapeidx.store.known import known_files
from shapeidx.store.layout import ENTRY_COLUMNS, REVISION_COLUMN
from shapeidx.signing.parameters import HISTOGRAMS

pytest.importorskip("OCP", reason="cadquery-ocp-novtk (OpenCASCADE) is a dependency of shapeidx")

EI54 = "Transformer_THT/Transformer_CHK_EI54-12VA_Neutral.step"
ORDINARY = "Capacitor_THT/C_Axial_L5.1mm_D3.1mm_P10.00mm_Horizontal.step"
STL = "mesh-wild/openscad-testdata/testdata/stl/adns2610_dev_circuit_inv.stl"


def mixed_tree(data_dir, tmp_path, step=(EI54, ORDINARY)):
    """Two STEP files (one with multi-turn faces), ten VRML parts and an STL, writable."""
    tree = copy_tree(data_dir / "kicad6", tmp_path / "parts", ["LED_SMD"])
    for rel in step:
        (tree / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(data_dir / "kicad6-step" / rel, tree / rel)
    shutil.copy2(data_dir / STL, tree / "mesh.stl")
    for path in tree.rglob("*"):
        path.chmod(path.stat().st_mode | 0o200)
    return tree


def store_files(store) -> list:
    return sorted(glob.glob(os.path.join(store, "**", "*.h5"), recursive=True))


def set_revision(store, revision: int, which=lambda path: path.endswith(".step") or ".step#" in path) -> int:
    """Write ``revision`` into the revision column of the rows ``which`` selects, in every file
    of ``store`` (main file and journal segments); the rows changed."""
    changed = 0
    for name in store_files(store):
        with h5py.File(name, "r+") as f:
            if "entries/path" not in f or REVISION_COLUMN not in f:
                continue
            paths = f["entries/path"].asstr()[()]
            values = f[REVISION_COLUMN][()]
            rows = np.array([which(str(p)) for p in paths], dtype=bool)
            values[rows] = revision
            f[REVISION_COLUMN][...] = values
            changed += int(rows.sum())
    return changed


def drop_revision(store) -> int:
    """Delete the revision column from every file of ``store``: a store of before it."""
    dropped = 0
    for name in store_files(store):
        with h5py.File(name, "r+") as f:
            if REVISION_COLUMN in f:
                del f[REVISION_COLUMN]
                dropped += 1
    return dropped


def contents(store) -> dict:
    """path -> every column's value and every histogram's counts: the store as a reader sees it."""
    out = {}
    with open_store(store) as r:
        columns = {name: r.column(name) for name in ENTRY_COLUMNS}
        counts = {name: r.counts(name, np.arange(len(r))) for name in HISTOGRAMS}
        offsets = {name: np.concatenate([[0], np.cumsum(lengths)]) for name, (_, lengths) in counts.items()}
        for i, path in enumerate(r.paths):
            row = {name: np.asarray(values[i]) for name, values in columns.items()}
            for name, (flat, _) in counts.items():
                row[f"{name}/counts"] = np.asarray(flat[offsets[name][i]:offsets[name][i + 1]])
            out[str(path)] = row
    return out


def assert_same(a: dict, b: dict, paths=None) -> None:
    assert sorted(a) == sorted(b)
    for path in paths or a:
        for name, value in a[path].items():
            other = b[path][name]
            if value.dtype.kind == "f":
                assert np.array_equal(value, other, equal_nan=True), (path, name)
            else:
                assert np.array_equal(value, other), (path, name, value, other)


def old_reader_entry(tree, rel, params):
    """The entry the STEP reader made before the multi-turn repair (revision 1)."""
    import shapeidx.io.step as step
    from shapeidx.index.workers import _signed
    from shapeidx.io import LoadLimits
    from shapeidx.io.base import file_hash
    from shapeidx.signing.solid import make_solid

    path = tree / rel
    limits = LoadLimits(root=tree, faceting=params.faceting)
    saved = step.unwound
    step.unwound = lambda shapes: (shapes, 0)
    try:
        mesh = step._read_step(path, limits, "step", path.read_bytes())
    finally:
        step.unwound = saved
    stat = path.stat()
    entry = _signed(rel, file_hash(path), stat.st_size, stat.st_mtime_ns, make_solid(mesh, path), params, str(path))
    entry.revision = 1
    return entry


def plan_of(tree, store, **options):
    with open_store(store) as reader:
        return make_plan(walk_parts(tree), reader, BuildOptions(**options))


def test_the_registry_declares_the_revisions():
    assert FORMATS["step"].revision == FORMATS["iges"].revision == 2
    assert {FORMATS[name].revision for name in ("stl", "obj", "off", "ply", "vrml")} == {1}
    assert reader_revision("a/b.STP.gz") == 2 and reader_revision("a/b.wrl") == 1
    assert reader_revision("a/b.step#3") == 2 and reader_revision("a/b.igs#1") == 2
    assert reader_revision("no-format") == 1


def test_entries_an_older_step_reader_signed_are_signed_again(data_dir, tmp_path):
    tree = mixed_tree(data_dir, tmp_path)
    store, fresh = tmp_path / "s.shapeidx", tmp_path / "fresh.shapeidx"
    assert build(tree, fresh).exit_code == 0
    assert build(tree, store).exit_code == 0
    with open_store(store) as r:
        revisions = dict(zip(map(str, r.paths), r.column(REVISION_COLUMN).tolist()))
        params = r.params
    assert revisions[EI54] == revisions[ORDINARY] == 2
    assert {v for p, v in revisions.items() if not p.endswith(".step")} == {1}

    # the previous release's store: EI54 as its reader meshed it, the other STEP file only marked
    with StoreWriter(store, params, tree.resolve()) as w:
        w.commit(Batch(entries=[old_reader_entry(tree, EI54, params)]))
    assert set_revision(store, 1, lambda p: p == ORDINARY) == 1
    before = contents(store)
    assert not np.array_equal(before[EI54]["all/counts"], contents(fresh)[EI54]["all/counts"])  # really stale

    stats = json.loads(cli("stats", "--store", store, "--json").stdout)
    assert stats["older_reader"] == {"STEP": 2}
    assert "2 STEP entries signed by an older reader" in cli("stats", "--store", store).stdout
    dry = cli("build", tree, "--store", store, "--points", FAST_POINTS, "--dry-run", "--json")
    assert json.loads(dry.stdout)["older_reader"] == {"STEP": 2} and json.loads(dry.stdout)["planned"] == 2
    dry = cli("build", tree, "--store", store, "--points", FAST_POINTS, "--dry-run")
    assert "would index 0 new or changed, 2 signed by an older STEP reader, 11 unchanged" in dry.stdout
    assert_same(contents(store), before)  # the dry run wrote nothing

    run = build(tree, store)
    assert run.exit_code == 0, run.output
    assert "13 files: 0 new or changed, 2 signed by an older STEP reader, 11 unchanged, 0 to remove" in run.stderr
    assert summary_counts(run.stdout) == {"indexed": 2, "unchanged": 11, "removed": 0, "failed": 0}
    assert "signed again by a newer reader: 2 STEP" in run.stdout
    after = contents(store)
    assert_same(after, contents(fresh))  # what a fresh build makes, bit for bit
    others = [p for p in after if not p.endswith(".step")]
    assert_same(after, before, others)  # the VRML and STL entries as they were

    again = build(tree, store)
    assert summary_counts(again.stdout)["indexed"] == 0 and "older" not in again.stderr + again.stdout
    assert json.loads(cli("stats", "--store", store, "--json").stdout)["older_reader"] == {}
    check = cli("check", "--store", store)
    assert check.exit_code == 0, check.output


def test_a_store_without_the_column_reads_as_revision_1(data_dir, tmp_path):
    tree = mixed_tree(data_dir, tmp_path, step=(ORDINARY,))
    store, fresh = tmp_path / "s.shapeidx", tmp_path / "fresh.shapeidx"
    assert build(tree, fresh).exit_code == 0
    assert build(tree, store).exit_code == 0
    assert drop_revision(store) >= 1
    with open_store(store) as r:
        assert set(r.column(REVISION_COLUMN).tolist()) == {1}
        assert r._sources[0].value_at(REVISION_COLUMN, 0) == 1
        assert set(known_files(r).revision.tolist()) == {1}
    check = cli("check", "--store", store)
    assert check.exit_code == 0, check.output  # an older layout is not damage
    plan = plan_of(tree, store)
    assert [t.path for t in plan.tasks] == [ORDINARY] and plan.older == {"STEP": 1}
    assert all(t.known_hash is None for t in plan.tasks)  # no same-content shortcut

    run = build(tree, store)
    assert summary_counts(run.stdout) == {"indexed": 1, "unchanged": 11, "removed": 0, "failed": 0}
    assert_same(contents(store), contents(fresh))
    assert cli("check", "--store", store).exit_code == 0


def test_failed_entries_of_an_older_reader_are_retried(data_dir, tmp_path):
    tree = mixed_tree(data_dir, tmp_path, step=(ORDINARY,))
    (tree / "broken.step").write_text("ISO-10303-21;\nHEADER;\nENDSEC;\nDATA;\n#1 = NOTHING('x');\nENDSEC;\nEND-ISO-10303-21;\n")
    shutil.copy2(data_dir / "mesh-wild/openscad-testdata/testdata/stl/unparseable.stl", tree / "broken.stl")
    (tree / "broken.stl").chmod(0o644)
    store = tmp_path / "s.shapeidx"
    assert build(tree, store).exit_code == 0
    with open_store(store) as r:
        failed = {str(p) for p, s in zip(r.paths, r.column("entries/status")) if s}
        revisions = dict(zip(map(str, r.paths), r.column(REVISION_COLUMN).tolist()))
    assert failed == {"broken.step", "broken.stl"}
    assert revisions["broken.step"] == 2 and revisions["broken.stl"] == 1  # failed entries record it too
    assert plan_of(tree, store).tasks == []

    set_revision(store, 1, lambda p: True)
    plan = plan_of(tree, store)
    assert sorted(t.path for t in plan.tasks) == sorted(["broken.step", ORDINARY])  # not broken.stl
    assert "broken.step" in plan.failed_before  # failing again is not news
    quiet = build(tree, store, "-q")
    assert "broken" not in quiet.stderr, quiet.stderr
    with open_store(store) as r:
        revisions = dict(zip(map(str, r.paths), r.column(REVISION_COLUMN).tolist()))
    assert revisions["broken.step"] == 2 and revisions[ORDINARY] == 2


def test_changed_and_full_builds_do_not_count_them_as_older(data_dir, tmp_path):
    tree = mixed_tree(data_dir, tmp_path, step=(EI54, ORDINARY))
    store = tmp_path / "s.shapeidx"
    assert build(tree, store).exit_code == 0
    set_revision(store, 1)
    os.utime(tree / ORDINARY, ns=(1, 1))  # its time changed: "changed", and still no same-content shortcut
    plan = plan_of(tree, store)
    assert plan.older == {"STEP": 1} and sorted(t.path for t in plan.tasks) == sorted([EI54, ORDINARY])
    assert all(t.known_hash is None for t in plan.tasks)
    assert plan_of(tree, store, full=True).older == {}
    rehash = plan_of(tree, store, rehash=True)
    assert {t.path for t in rehash.tasks if t.known_hash is None} == {EI54, ORDINARY}  # others may be the same


def test_sub_parts_an_older_reader_made_are_made_again(data_dir, tmp_path):
    tree = mixed_tree(data_dir, tmp_path)
    store, fresh = tmp_path / "s.shapeidx", tmp_path / "fresh.shapeidx"
    assert build(tree, fresh, "--parts").exit_code == 0
    assert build(tree, store, "--parts").exit_code == 0
    with open_store(store / "parts") as r:
        revisions = dict(zip(map(str, r.paths), r.column(REVISION_COLUMN).tolist()))
    assert {v for p, v in revisions.items() if ".step#" in p} == {2}
    assert set_revision(store / "parts", 1) >= 2  # the sub-entries only: the whole files are up to date
    run = build(tree, store, "--parts")
    assert run.exit_code == 0, run.output
    assert "2 files whose sub-parts were made by an older STEP reader" in run.stderr
    assert summary_counts(run.stdout.split(";")[0] + " in")["indexed"] == 0
    assert "sub-parts made again by a newer reader: 2 STEP" in run.stdout
    assert_same(contents(store / "parts"), contents(fresh / "parts"))
    again = build(tree, store, "--parts")
    assert "older" not in again.stderr and "parts: 0 signed" in again.stdout


def test_a_killed_re_signing_loses_nothing_and_the_next_build_finishes(data_dir, tmp_path):
    """kill -9 while the STEP files are being signed again: every entry is still there (old or
    new revision), and the next build signs the rest; the end is a fresh build's store."""
    steps = tuple(f"Capacitor_THT/{p.name}" for p in sorted((data_dir / "kicad6-step" / "Capacitor_THT").glob("*.step")))
    tree = mixed_tree(data_dir, tmp_path, step=steps)
    store, fresh = tmp_path / "s.shapeidx", tmp_path / "fresh.shapeidx"
    assert build(tree, fresh).exit_code == 0
    assert build(tree, store).exit_code == 0
    assert set_revision(store, 1) == len(steps)
    proc = subprocess.Popen(shapeidx_command("build", tree, "--store", store, "--points", FAST_POINTS, "--verbose",
                                             "--workers", "1", "--commit-interval", "0.05"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        indexed = 0
        while indexed < 3:
            line = proc.stderr.readline()
            if not line:
                break
            indexed += "committed batch" in line
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.communicate(timeout=60)
    with open_store(store) as r:
        assert len(r) == len(contents(fresh))  # nothing lost
        step = np.array([str(p).endswith(".step") for p in r.paths])
        left = int(np.sum(step & (r.column(REVISION_COLUMN) < 2)))
    print(f"killed after {indexed} commits: {left} of {len(steps)} STEP entries left to sign again")
    assert 0 < left < len(steps) or indexed < 3  # (a fast machine may finish before the kill lands)
    run = build(tree, store)
    assert run.exit_code == 0, run.output
    if left:
        assert f"{left} signed by an older STEP reader" in run.stderr
    assert summary_counts(run.stdout)["indexed"] == left
    assert_same(contents(store), contents(fresh))


def test_check_compares_the_ranking_arrays_in_a_store_without_the_column(data_dir, tmp_path):
    """A store written before the column still has its ranking arrays checked against its entries."""
    from shapeidx.store.files import main_file

    tree = mixed_tree(data_dir, tmp_path, step=(ORDINARY,))
    store = tmp_path / "s.shapeidx"
    assert build(tree, store).exit_code == 0
    assert drop_revision(store) >= 1
    assert cli("check", "--store", store).exit_code == 0
    with h5py.File(main_file(store), "r+") as f:  # an entry's mean moved, its checksum written anew
        f["histograms/all/mean"][0] = f["histograms/all/mean"][0] * 1.5
    check = cli("check", "--store", store)
    assert check.exit_code == 5 and "disagrees with the entries" in check.output, check.output


def test_planned_counts_the_files_signed_whole(data_dir, tmp_path):
    """``build --parts`` on a store built without it splits every file but signs none whole."""
    tree = mixed_tree(data_dir, tmp_path, step=(ORDINARY,))
    store = tmp_path / "s.shapeidx"
    assert build(tree, store).exit_code == 0
    run = build(tree, store, "--parts", "--json")
    assert run.exit_code == 0, run.output
    facts = json.loads(run.stdout)
    assert facts["planned"] == 0 and facts["indexed"] == 0 and facts["parts"]["indexed"] >= 12


def test_an_older_workers_entries_are_of_the_first_revision(data_dir, tmp_path):
    """An entry from a Dask worker running a shapeidx of before revisions has no revision of its
    own (unpickled, it falls back to the class's None): it is revision 1, not the build's."""
    from shapeidx.index.dask_pool import _revision_of_older_worker
    from shapeidx.index.workers import Outcome, Task, index_file
    from shapeidx.store.layout import entries_to_columns

    tree = mixed_tree(data_dir, tmp_path, step=(ORDINARY,))
    store = tmp_path / "s.shapeidx"
    assert build(tree, store).exit_code == 0
    with open_store(store) as r:
        params = r.params
    outcome = index_file(Task(ORDINARY, str(tree / ORDINARY)), params, str(tree))
    assert outcome.entry.revision == 2
    _revision_of_older_worker(outcome)
    assert outcome.entry.revision == 2  # a worker of today's keeps its own
    del vars(outcome.entry)["revision"]  # as an older shapeidx's pickled entry arrives
    assert outcome.entry.revision is None
    _revision_of_older_worker(outcome)
    columns, _ = entries_to_columns([outcome.entry])
    assert columns[REVISION_COLUMN].tolist() == [1]
    assert isinstance(outcome, Outcome)
