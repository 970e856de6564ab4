"""A damaged store is found, reported in one line, and repaired; environment errors are one line."""

from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess

import h5py
import numpy as np
import pytest
from clitools import assert_one_line_error, cli, cli_json, shapeidx_command
from storetools import FAST_POINTS, build, small_kicad

import shapeidx.store.layout as layout
import shapeidx.store.reader as reader_module
from shapeidx.console import exits
from shapeidx.index.workers import Task, index_file
from shapeidx.signing.parameters import HISTOGRAMS
from shapeidx.store import Batch, StoreWriter, open_store
from shapeidx.store.files import batch_files, main_file

CUBE = "mesh-wild/trimesh-models/unit_cube.STL"


@pytest.fixture(scope="module")
def pristine(data_dir, tmp_path_factory):
    """A real store of 20 parts whose histogram counts span several checksummed chunks."""
    tmp = tmp_path_factory.mktemp("check")
    tree = small_kicad(data_dir, tmp, ["LED_SMD", "Diode_SMD"])
    store = tmp / "pristine.h5"
    chunk = layout.CHUNK_COUNTS
    layout.CHUNK_COUNTS = 256  # small chunks: a damaged chunk holds a few entries, not all
    try:
        assert build(tree, store).exit_code == 0
    finally:
        layout.CHUNK_COUNTS = chunk
    return tree, store


@pytest.fixture
def store(pristine, tmp_path):
    tree, original = pristine
    copy = tmp_path / "s.h5"
    shutil.copytree(original, copy)
    return tree, copy


def entry_of(tree):
    return sorted((tree / "LED_SMD").iterdir())[0].relative_to(tree).as_posix()


def flip_chunk(store, dataset: str, chunk: int) -> None:
    """Flip bytes inside one stored chunk of ``dataset`` (its checksum no longer matches)."""
    with h5py.File(main_file(store), "r") as f:
        info = f[dataset].id.get_chunk_info(chunk)
    with open(main_file(store), "r+b") as f:
        f.seek(info.byte_offset + 8)
        data = f.read(16)
        f.seek(info.byte_offset + 8)
        f.write(bytes(b ^ 0x5A for b in data))


def signatures(store) -> dict:
    with open_store(store) as reader:
        return {str(p): reader.signature(i) for i, p in enumerate(reader.paths)}


def test_every_dataset_written_is_checksummed(pristine, tmp_path, data_dir):
    tree, store = pristine
    shutil.copytree(store, tmp_path / "s.h5")
    with StoreWriter(tmp_path / "s.h5", _params(store), tree.resolve()) as w:
        task = Task("LED_SMD/extra.stl", str(data_dir / CUBE))
        w.commit(Batch(entries=[index_file(task, _params(store), str(tree.resolve())).entry],
                       touched=[("a", 1, 2)], removed=["b"]))
        files = [main_file(tmp_path / "s.h5")] + [p for _, p in batch_files(tmp_path / "s.h5")]
    assert len(files) == 2
    for path in files:
        with h5py.File(path, "r") as f:
            datasets = []
            f.visititems(lambda name, obj: datasets.append(obj) if isinstance(obj, h5py.Dataset) else None)
            assert len(datasets) >= 22
            for d in datasets:
                string = h5py.check_string_dtype(d.dtype)
                if string is not None and string.length is None:  # variable length: HDF5 filters none
                    assert layout.CONTENT_HASH in d.attrs, d.name
                elif d.name.startswith("/rank/"):  # contiguous, to be mapped: a CRC-32 of its bytes
                    assert d.chunks is None and "crc32" in d.attrs, d.name
                elif d.shape[0]:
                    assert d.fletcher32, d.name


def _params(store):
    with open_store(store) as reader:
        return reader.params


def test_a_store_without_checksums_stays_readable(store, tmp_path):
    tree, path = store
    old = tmp_path / "old.h5"
    old.mkdir()
    with h5py.File(main_file(path), "r") as src, h5py.File(main_file(old), "w") as dst:  # as shapeidx wrote before checksums
        dst.attrs.update(src.attrs)
        dst.attrs["schema_version"] = 2
        names = []
        src.visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset) else None)
        for name in (n for n in names if not n.startswith("rank/")):  # nor had it ranking arrays
            dst.create_dataset(name, data=src[name][()], dtype=src[name].dtype)
    expected = cli_json("query", "--id", entry_of(tree), "--store", path)["hits"]
    refused = cli("query", "--id", entry_of(tree), "--store", old)  # no ranking arrays: one line says how
    assert refused.exit_code == exits.ERROR and "check --repair" in refused.stderr
    assert cli("check", "--store", old, "--repair").exit_code == 0
    assert cli_json("query", "--id", entry_of(tree), "--store", old)["hits"] == expected
    report = cli_json("check", "--store", old)
    assert report["ok"] and report["checksummed"] is False and report["notes"]


def test_a_flipped_chunk_is_found_named_refused_and_repaired(store, pristine):
    tree, path = store
    expected = cli_json("query", "--id", entry_of(tree), "--store", path)["hits"]
    flip_chunk(path, "histograms/in/counts", 1)
    check = cli("check", "--store", path)
    assert check.exit_code == exits.DAMAGED
    assert "histograms/in/counts" in check.stderr and "DAMAGED" in check.stdout
    # a query reads the ranking arrays (checked as it ranks them) and the query entry's own
    # rows, not every histogram: the right answer, or the one line if it touched the damage
    query = cli("query", "--id", entry_of(tree), "--store", path, "--json")
    if query.exit_code == 0:
        assert json.loads(query.stdout)["hits"] == expected
    else:
        assert_one_line_error(query, path, status=exits.DAMAGED)
        assert "--repair" in query.stderr and "histograms/in/counts" in query.stderr
    refused = build(tree, path)
    assert_one_line_error(refused, path, status=exits.DAMAGED)
    repaired = build(tree, path, "--repair", "--json")
    assert repaired.exit_code == 0, repaired.stderr
    summary = cli_json("build", tree, "--store", path, "--dry-run")
    indexed = json.loads(repaired.stdout)["indexed"]
    assert 0 < indexed < 20 and "repair:" in repaired.stderr
    assert summary["planned"] == 0
    assert cli("check", "--store", path).exit_code == 0
    before, after = signatures(pristine[1]), signatures(path)
    assert before.keys() == after.keys()
    for p in before:  # the re-indexed entries are what they were, bit for bit
        for name in HISTOGRAMS:
            assert np.array_equal(before[p].histograms[name].counts, after[p].histograms[name].counts), p


def test_offsets_out_of_bounds_are_one_line_not_an_index_error(store):
    tree, path = store
    with h5py.File(main_file(path), "r+") as f:  # a consistent checksum, wrong values: what a bug could write
        offsets = f["histograms/all/offsets"]
        values = offsets[()]
        values[5] = values[-1] + 1000
        offsets[...] = values
        row = int(np.searchsorted(f["entries/path"].asstr()[()], entry_of(tree)))
    for query_row in (row, 5):  # the entry's own offsets, then the query of the damaged row
        with h5py.File(main_file(path), "r") as f:
            entry = f["entries/path"].asstr()[query_row]
        result = cli("query", "--id", entry, "--store", path)
        if query_row == 5:
            assert_one_line_error(result, path, status=exits.DAMAGED)
            assert "out of bounds" in result.stderr
    assert cli("check", "--store", path).exit_code == exits.DAMAGED


def test_4_kib_overwritten_anywhere_gives_the_right_answer_or_one_line(store):
    tree, path = store
    expected = cli_json("query", "--id", entry_of(tree), "--store", path, "--top", "20")
    main = main_file(path)
    size = main.stat().st_size
    pristine_bytes = main.read_bytes()
    for offset in range(0, size - 4096, size // 9):
        main.write_bytes(pristine_bytes)
        with open(main, "r+b") as f:
            f.seek(offset)
            f.write(bytes(range(256)) * 16)
        result = cli("query", "--id", entry_of(tree), "--store", path, "--top", "20", "--json")
        if result.exit_code == 0:
            answer = json.loads(result.stdout)
            assert answer["hits"] == expected["hits"], offset  # never a wrong answer
        else:
            assert result.exit_code in (exits.DAMAGED, exits.ERROR), (offset, result.stderr)
            assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
        checked = cli("check", "--store", path)
        assert checked.exit_code in (exits.OK, exits.DAMAGED, exits.ERROR)
        assert "internal error" not in checked.stderr


def test_a_damaged_journal_batch_is_refused_then_redone(store, data_dir):
    tree, path = store
    new = tree / "LED_SMD" / "new_cube.stl"
    shutil.copy(data_dir / CUBE, new)
    params, root = _params(path), str(tree.resolve())
    with StoreWriter(path, params, tree.resolve()) as w:
        w.commit(Batch(entries=[index_file(Task("LED_SMD/new_cube.stl", str(new)), params, root).entry]))
    (seq, batch), = batch_files(path)
    data = bytearray(batch.read_bytes())
    data[len(data) // 2 : len(data) // 2 + 2048] = b"\0" * 2048
    batch.write_bytes(bytes(data))
    with open_store(path, skip_damaged=True) as reader:  # what the build sees: the batch left out
        assert reader.skipped and reader.skipped[0][0] == batch and len(reader) == 20
    for command in (("stats", "--store", path), ("query", "--id", entry_of(tree), "--store", path)):
        refused = cli(*command)  # never an answer over fewer entries than the store holds
        assert_one_line_error(refused, path, status=exits.DAMAGED)
        assert batch.name in refused.stderr
    again = build(tree, path, "--json")
    assert again.exit_code == 0, again.stderr
    assert "dropped the damaged journal batch" in again.stderr
    assert json.loads(again.stdout)["indexed"] == 1  # its work, redone
    # the batch that redid it may take the same number (it stays a journal segment): it is sound
    assert cli("check", "--store", path).exit_code == 0
    with open_store(path) as reader:
        assert not reader.skipped and len(reader) == 21


def test_a_reader_racing_a_merge_retries(store, monkeypatch, data_dir):
    """h5py raises a plain OSError (not FileNotFoundError) for a batch that vanished."""
    tree, path = store
    params, root = _params(path), str(tree.resolve())
    opened = reader_module._SourceFile
    with StoreWriter(path, params, tree.resolve()) as w:
        new = tree / "race.stl"
        shutil.copy(data_dir / CUBE, new)
        w.commit(Batch(entries=[index_file(Task("race.stl", str(new)), params, root).entry]))
        raced = []

        def racing(source_path, seq, store=None):
            if seq > 0 and not raced:  # the merge lands between listing the batch and opening it
                raced.append(source_path)
                w.merge()
                raise OSError(f"Unable to synchronously open file (unable to open file: name = '{source_path}')")
            return opened(source_path, seq, store)

        monkeypatch.setattr(reader_module, "_SourceFile", racing)
        with open_store(path) as reader:
            assert raced and "race.stl" in set(reader.paths) and not reader.skipped


def test_a_full_disk_is_one_line_and_leaves_the_store_as_it_was(store, data_dir):
    tree, path = store
    shutil.copy(data_dir / CUBE, tree / "one_more.stl")
    before = {p.relative_to(path): p.read_bytes() for p in path.rglob("*") if p.is_file() and p.name != "lock"}

    def small_files():  # ulimit -f: a write past 256 KiB fails as on a full disk
        resource.setrlimit(resource.RLIMIT_FSIZE, (256 << 10, 256 << 10))

    proc = subprocess.run(shapeidx_command("build", tree, "--store", path, "--points", FAST_POINTS),
                          capture_output=True, text=True, timeout=300, preexec_fn=small_files)
    assert proc.returncode == exits.ERROR, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and "cannot write" in errors[0] and "Traceback" not in proc.stderr
    assert "HDF5" not in proc.stderr and "errno" not in proc.stderr
    after = {p.relative_to(path): p.read_bytes() for p in path.rglob("*") if p.is_file() and p.name != "lock"}
    records = ("build.json", "verified")  # what the build records of itself; the data files are untouched
    assert {k: v for k, v in after.items() if k.name not in records} == {k: v for k, v in before.items() if k.name not in records}
    assert cli("check", "--store", path).exit_code == 0


@pytest.mark.skipif(os.geteuid() != 0, reason="a read-only bind mount needs root")
def test_a_read_only_file_system_is_one_line(store, tmp_path):
    tree, path = store
    mount = tmp_path / "ro"
    mount.mkdir()
    if subprocess.run(["mount", "--bind", str(path.parent), str(mount)], capture_output=True).returncode:
        pytest.skip("mount --bind is not allowed here")
    try:
        if subprocess.run(["mount", "-o", "remount,ro,bind", str(mount)], capture_output=True).returncode:
            pytest.skip("cannot remount read-only here")
        ro_store = mount / path.name
        assert cli("query", "--id", entry_of(tree), "--store", ro_store).exit_code == 0  # reading works
        (tree / "LED_SMD" / sorted(os.listdir(tree / "LED_SMD"))[0]).touch()
        result = cli("build", tree, "--store", ro_store)
        assert_one_line_error(result, ro_store, status=exits.ERROR)
        assert "ead-only file system" in result.stderr
    finally:
        subprocess.run(["umount", str(mount)], capture_output=True)
