"""What a build's start reads of a large store: the entries by path key (shapeidx.store.known),
checked against the reader's own assembly of the journal by path (an independent route), and
the main file's full verification only when it is not the very file verified before
(shapeidx.store.verified)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from shapeidx.errors import StoreDamagedError
from shapeidx.signing.parameters import SIGNATURE_VERSION
from shapeidx.signing.pipeline import signature_of_solid, solid_of_file
from shapeidx.store import Batch, Entry, StoreParams, StoreWriter, open_store
from shapeidx.store import check as store_check
from shapeidx.store.known import known_files
from shapeidx.store.files import main_file
from shapeidx.store.verified import is_verified, verified_path

PARAMS = StoreParams(points=64, seed=7, bin_divisor=50, signature_version=SIGNATURE_VERSION)


@pytest.fixture(scope="module")
def signed(data_dir):
    solid = solid_of_file(data_dir / "mesh-wild" / "trimesh-models" / "plate_holes.STL")
    return signature_of_solid(solid, PARAMS.points, PARAMS.seed), solid.describe()


def entry(signed, path, size, mtime=10**18):
    sig, facts = signed
    return Entry.indexed(path, f"{size:064x}", size, mtime, sig, facts)


def journal_store(tmp_path, signed) -> Path:
    """A main file and three journal segments that replace, touch, remove and re-add entries."""
    path = tmp_path / "s.h5"
    with StoreWriter(path, PARAMS, Path("/parts")) as w:
        w.commit(Batch(entries=[entry(signed, f"a/{i:02d}.stl", 100 + i) for i in range(30)]
                       + [Entry.failed("a/broken.stl", "e" * 64, 7, 8, "is empty (0 bytes)")]))
        w.merge()
        w.commit(Batch(entries=[entry(signed, f"b/{i}.stl", 200 + i) for i in range(5)]
                       + [entry(signed, f"a/{i:02d}.stl", 300 + i) for i in (1, 2, 3)],
                       touched=[("a/04.stl", 104, 5), ("a/05.stl", 105, 6), ("b/0.stl", 200, 7), ("zz.stl", 1, 1)],
                       removed=["a/06.stl", "a/07.stl"]))
        w.commit(Batch(entries=[entry(signed, "a/06.stl", 406), entry(signed, "a/05.stl", 405)],
                       touched=[("a/04.stl", 104, 9), ("a/01.stl", 301, 11)], removed=["b/1.stl", "a/broken.stl"]))
        w.commit(Batch(touched=[("b/2.stl", 202, 12)], removed=["a/08.stl"]))
    return path


def assert_known_as_assembled(store: Path):
    with open_store(store) as reader:
        known = known_files(reader)
        paths = list(reader.paths)
        assert len(known) == len(paths)
        at = known.lookup(paths)
        assert np.all(at >= 0) and len(set(at.tolist())) == len(paths)
        for name, values in (("size", known.size), ("mtime_ns", known.mtime_ns), ("status", known.status)):
            assert np.array_equal(values[at], reader.column(f"entries/{name}")), name
        assert known.paths(at) == paths
        assert known.hashes(at) == [h.decode() for h in reader.column("entries/hash")]
        assert np.all(known.lookup(["a/07.stl", "a/08.stl", "b/1.stl", "zz.stl", "nothing.stl"]) == -1)
        return reader.journal


def test_the_live_entries_by_key_are_the_readers_assembly(tmp_path, signed):
    store = journal_store(tmp_path, signed)
    assert assert_known_as_assembled(store) == 3  # three segments on top of the main file
    with open_store(store) as reader:
        known = known_files(reader)
        (i,), (j,), (k,) = (known.lookup([p]) for p in ("a/04.stl", "a/01.stl", "a/05.stl"))
        assert known.mtime_ns[i] == 9  # the newest touch wins
        assert known.mtime_ns[j] == 11 and known.size[j] == 301  # a touch newer than the entry applies
        assert known.mtime_ns[k] == 10**18 and known.size[k] == 405  # an entry newer than the touch wins


def test_files_without_path_keys_are_keyed_from_their_paths(tmp_path, signed):
    store = journal_store(tmp_path, signed)
    with h5py.File(main_file(store), "r+") as f:  # as a file of layout 2 (no ranking section) is
        del f["rank"]
    assert assert_known_as_assembled(store) == 3


def test_a_build_reads_the_main_file_whole_only_when_it_is_not_the_file_verified(tmp_path, signed, monkeypatch):
    store = journal_store(tmp_path, signed)
    assert is_verified(store)  # the merge that wrote it recorded it
    scans = []
    real_scan = store_check.scan_file
    monkeypatch.setattr(store_check, "scan_file", lambda *a, **k: scans.append(a[0]) or real_scan(*a, **k))
    StoreWriter(store, PARAMS, Path("/parts")).close()
    assert scans == []
    os.utime(main_file(store))  # any change through the file system: verified again, then recorded again
    StoreWriter(store, PARAMS, Path("/parts")).close()
    assert scans == [main_file(store)] and is_verified(store)
    copy = tmp_path / "copy.h5"
    shutil.copytree(store, copy)  # the store with its record: a copied record does not name the copy
    assert not is_verified(copy)
    verified_path(store).write_text("not json")
    StoreWriter(store, PARAMS, Path("/parts")).close()
    assert scans == [main_file(store), main_file(store)] and is_verified(store)


def test_a_damaged_main_file_is_still_refused_after_it_was_verified(tmp_path, signed):
    store = journal_store(tmp_path, signed)
    assert is_verified(store)
    with h5py.File(main_file(store), "r") as f:  # a flipped byte of a chunk, written through the file system
        chunk = f["histograms/all/counts"].id.get_chunk_info(0)
    with open(main_file(store), "r+b") as raw:
        raw.seek(chunk.byte_offset + 8)
        byte = raw.read(1)
        raw.seek(chunk.byte_offset + 8)
        raw.write(bytes([byte[0] ^ 0xFF]))
    assert not is_verified(store)
    with pytest.raises(StoreDamagedError, match="histograms/all/counts"):
        StoreWriter(store, PARAMS, Path("/parts"))


def test_the_plan_decodes_none_of_the_main_files_paths_but_the_removed_ones(tmp_path, signed, monkeypatch):
    from shapeidx.index.build import BuildOptions
    from shapeidx.index.plan import make_plan
    from shapeidx.index.walk import FoundFile, Walk
    from shapeidx.store import reader as store_reader

    store = journal_store(tmp_path, signed)
    with open_store(store) as reader:
        listing = list(zip(reader.paths, reader.column("entries/size"), reader.column("entries/mtime_ns")))
    files = [FoundFile(p, f"/parts/{p}", int(s), int(m)) for p, s, m in listing if p != "a/10.stl"]
    files[0] = FoundFile(files[0].path, files[0].absolute, files[0].size, files[0].mtime_ns + 1)  # touched
    files.append(FoundFile("c/new.stl", "/parts/c/new.stl", 5, 5))
    real_column = store_reader._SourceFile.column

    def column(self, name):  # small journal batches are read whole when opened (verified): the main file is not
        assert not (name == "entries/path" and self.seq == 0), "the plan decoded the main file's paths"
        return real_column(self, name)

    monkeypatch.setattr(store_reader._SourceFile, "column", column)
    # as in a large store, where a few removed entries are far below the share that reads the column whole
    monkeypatch.setattr("shapeidx.store.known.WHOLE_COLUMN_SHARE", 1.0)
    with open_store(store) as reader:
        plan = make_plan(Walk(files=files), reader, BuildOptions())
    assert [(t.path, t.known_hash, t.in_store) for t in plan.tasks] == [
        (files[0].path, f"{files[0].size:064x}", True), ("c/new.stl", None, False)]
    assert plan.removed == ["a/10.stl"] and plan.unchanged == len(listing) - 2
