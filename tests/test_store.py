"""The HDF5 store: round trip, journal semantics, refusals, the lock, and the documented layout."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from shapeidx.errors import StoreError
from shapeidx.signing.parameters import HISTOGRAMS, SIGNATURE_VERSION
from shapeidx.signing.pipeline import signature_of_solid, solid_of_file
from shapeidx.store import (
    STATUS_FAILED,
    STATUS_OK,
    Batch,
    Entry,
    StoreParams,
    StoreWriter,
    describe_store,
    open_store,
)
from shapeidx.store.files import batch_files, journal_dir, main_file

PARAMS = StoreParams(points=64, seed=7, bin_divisor=50, signature_version=SIGNATURE_VERSION)
PARTS = (
    "trimesh-models/plate_holes.STL",
    "trimesh-models/octagonal_pocket.stl",
    "trimesh-models/featuretype.STL",
    "trimesh-models/soup.stl",  # not watertight
    "voron2/Tools/pulley_jig.stl",
)


@pytest.fixture(scope="module")
def real_entries(data_dir):
    """Entries of real parts (ok) and of a real broken file (failed), with their signatures."""
    entries, signatures = [], {}
    for i, rel in enumerate(PARTS):
        solid = solid_of_file(data_dir / "mesh-wild" / rel)
        sig = signature_of_solid(solid, PARAMS.points, PARAMS.seed)
        entries.append(Entry.indexed(rel, f"{i:064x}", 1000 + i, 10**18 + i, sig, solid.describe()))
        signatures[rel] = (sig, solid.describe())
    entries.append(Entry.failed("openscad-testdata/testdata/stl/empty.stl", "f" * 64, 0, 5, "is empty (0 bytes)"))
    return entries, signatures


def writer(tmp_path, root="/parts"):
    return StoreWriter(tmp_path / "s.h5", PARAMS, Path(root))


def merged_store(tmp_path, entries) -> Path:
    """A store holding ``entries`` in its main file."""
    with writer(tmp_path) as w:
        w.commit(Batch(entries=entries))
        w.merge()
    return tmp_path / "s.h5"


def snapshot(reader) -> dict:
    """Every column and every histogram of a reader, for comparisons."""
    from shapeidx.store.layout import ENTRY_COLUMNS

    out = {name: reader.column(name) for name in ENTRY_COLUMNS}
    for name in HISTOGRAMS:
        out[f"{name}/counts"], out[f"{name}/lengths"] = reader.counts(name)
    return out


def assert_same(a: dict, b: dict):
    assert a.keys() == b.keys()
    for key in a:
        assert np.array_equal(a[key], b[key], equal_nan=a[key].dtype.kind == "f"), key


class TestRoundTrip:
    def test_signatures_and_facts_come_back_exactly(self, tmp_path, real_entries):
        entries, signatures = real_entries
        with open_store(merged_store(tmp_path, entries)) as r:
            assert list(r.paths) == sorted(e.path for e in entries)
            status = r.column("entries/status")
            for rel, (sig, facts) in signatures.items():
                i = r.index_of(rel)
                assert status[i] == STATUS_OK
                stored = r.signature(i)
                for name in HISTOGRAMS:
                    assert np.array_equal(stored.histograms[name].counts, sig.histograms[name].counts)
                    assert stored.histograms[name].mean == sig.histograms[name].mean
                    assert stored.histograms[name].bin_width == sig.histograms[name].bin_width
                assert stored.fractions == sig.fractions
                assert r.column("entries/triangles")[i] == facts["triangles"]
                assert r.column("entries/area")[i] == facts["area"]
                assert r.column("entries/watertight")[i] == facts["watertight"]
            failed = r.index_of("openscad-testdata/testdata/stl/empty.stl")
            assert status[failed] == STATUS_FAILED
            assert r.column("entries/reason")[failed] == "is empty (0 bytes)"
            assert r.column("entries/hash")[failed] == b"f" * 64
            assert r.column("entries/mtime_ns")[r.index_of(PARTS[0])] == 10**18

    def test_readable_with_h5py_alone_as_documented(self, tmp_path, real_entries):
        """The README's recipe: row i's histogram is counts[offsets[i]:offsets[i+1]]."""
        entries, signatures = real_entries
        with h5py.File(main_file(merged_store(tmp_path, entries)), "r") as f:
            assert f.attrs["schema_version"] == 4 and f.attrs["points"] == 64 and f.attrs["seed_policy"] == "fixed"
            paths = list(f["entries/path"].asstr()[()])
            i = paths.index(PARTS[0])
            sig, _ = signatures[PARTS[0]]
            for name in HISTOGRAMS:
                offsets = f[f"histograms/{name}/offsets"]
                counts = f[f"histograms/{name}/counts"][offsets[i] : offsets[i + 1]]
                assert np.array_equal(counts, sig.histograms[name].counts)
            assert tuple(f["entries/fractions"][i]) == tuple(sig.fractions[c] for c in ("in", "out", "mixed"))
            assert h5py.check_enum_dtype(f["entries/status"].dtype) == {"ok": 0, "failed": 1}

    def test_empty_store(self, tmp_path):
        with writer(tmp_path):
            pass
        with open_store(tmp_path / "s.h5") as r:
            assert len(r) == 0 and r.journal == 0
            assert describe_store(r)["entries"] == 0


class TestJournal:
    def test_batches_apply_in_order_and_merge_changes_nothing(self, tmp_path, real_entries):
        entries, _ = real_entries
        a, b, c = entries[0], entries[1], entries[2]
        changed = Entry.failed(b.path, "e" * 64, 5, 6, "changed and now broken")
        with writer(tmp_path) as w:
            w.commit(Batch(entries=[a, b, c]))
            w.merge()
            w.commit(Batch(entries=[changed], touched=[(a.path, 77, 88)]))
            w.commit(Batch(entries=[entries[3]], removed=[c.path]))
            with open_store(tmp_path / "s.h5") as r:
                assert r.journal == 2
                assert list(r.paths) == sorted([a.path, b.path, entries[3].path])
                i = r.index_of(a.path)
                assert (r.column("entries/size")[i], r.column("entries/mtime_ns")[i]) == (77, 88)
                assert r.column("entries/hash")[i] == a.hash.encode()  # touched keeps the content's hash
                j = r.index_of(b.path)
                assert r.column("entries/reason")[j] == "changed and now broken"
                assert r.counts("all", np.array([j]))[1][0] == 0
                before = snapshot(r)
            w.merge()
        with open_store(tmp_path / "s.h5") as r:
            assert r.journal == 0
            assert_same(before, snapshot(r))
        assert not journal_dir(tmp_path / "s.h5").exists()

    def test_batches_left_after_a_merge_are_not_applied_twice(self, tmp_path, real_entries):
        """A kill between the merged file's rename and the batches' deletion leaves them behind."""
        entries, _ = real_entries
        store = tmp_path / "s.h5"
        with writer(tmp_path) as w:
            w.commit(Batch(entries=entries[:2]))
            w.commit(Batch(removed=[entries[0].path]))
            kept = [(seq, p.read_bytes()) for seq, p in batch_files(store)]
            w.merge()
        for seq, data in kept:  # as if the deletions never happened
            journal_dir(store).mkdir(exist_ok=True)
            (journal_dir(store) / f"batch-{seq:010d}.h5").write_bytes(data)
        with open_store(store) as r:
            assert r.journal == 0 and list(r.paths) == [entries[1].path]
        with writer(tmp_path) as w:  # the next writer deletes them
            w.commit(Batch(entries=[entries[0]]))
            assert w.next_seq == 4
        assert [seq for seq, _ in batch_files(store)] == [3]
        with open_store(store) as r:
            assert list(r.paths) == sorted([entries[0].path, entries[1].path])

    def test_leftover_temporary_files_are_ignored_then_removed(self, tmp_path, real_entries):
        store = tmp_path / "s.h5"
        with writer(tmp_path) as w:
            w.commit(Batch(entries=real_entries[0][:1]))
        (store / "main.h5.tmp-999").write_bytes(b"half a file")
        (journal_dir(store) / "batch-0000000009.h5.tmp-999").write_bytes(b"half a batch")
        with open_store(store) as r:
            assert len(r) == 1
        with writer(tmp_path):
            pass
        assert not (store / "main.h5.tmp-999").exists()
        assert not list(journal_dir(store).glob("*.tmp-*"))

    def test_a_reader_keeps_its_view_while_a_merge_replaces_the_files(self, tmp_path, real_entries):
        entries, _ = real_entries
        with writer(tmp_path) as w:
            w.commit(Batch(entries=entries[:3]))
            with open_store(tmp_path / "s.h5") as r:
                w.merge()  # renames a new main file, deletes the batch the reader holds open
                assert not batch_files(tmp_path / "s.h5")
                assert len(r) == 3 and len(r.counts("in")[1]) == 3

    def test_a_merge_between_opening_the_main_file_and_listing_the_journal(self, tmp_path, real_entries,
                                                                            monkeypatch):
        """The reader must not end up with the old main file and no batches (entries lost)."""
        import shapeidx.store.reader as store_module

        entries, _ = real_entries
        listing = store_module.batch_files
        with writer(tmp_path) as w:
            w.commit(Batch(entries=entries[:2]))
            w.merge()
            w.commit(Batch(entries=entries[2:4]))
            merges = []

            def merge_first(path):  # the writer's merge lands right after the reader opened the main file
                if not merges:
                    merges.append(path)
                    w.merge()
                return listing(path)

            monkeypatch.setattr(store_module, "batch_files", merge_first)
            with open_store(tmp_path / "s.h5") as r:
                assert merges and len(r) == 4


class TestRefusals:
    def test_other_parameters_are_refused(self, tmp_path):
        with writer(tmp_path):
            pass
        for other in (StoreParams(128, 7, 50, SIGNATURE_VERSION), StoreParams(64, 8, 50, SIGNATURE_VERSION),
                      StoreParams(64, 7, 50, SIGNATURE_VERSION + 1)):
            with pytest.raises(StoreError, match="other signature parameters.*another --store"):
                StoreWriter(tmp_path / "s.h5", other, Path("/parts"))

    def test_another_root_is_refused(self, tmp_path):
        with writer(tmp_path):
            pass
        with pytest.raises(StoreError, match="indexes /parts, not /elsewhere"):
            writer(tmp_path, root="/elsewhere")

    def test_missing_foreign_and_newer_files(self, tmp_path):
        with pytest.raises(StoreError, match="no store at"):
            open_store(tmp_path / "none.h5")
        (tmp_path / "text.h5").write_text("not hdf5")
        with pytest.raises(StoreError, match="is not a shapeidx store"):
            open_store(tmp_path / "text.h5")
        (tmp_path / "other").mkdir()
        with h5py.File(tmp_path / "other" / "main.h5", "w") as f:  # an HDF5 file of another program
            f["x"] = 1
        with pytest.raises(StoreError, match="is not a shapeidx store"):
            open_store(tmp_path / "other")
        (tmp_path / "empty").mkdir()
        with pytest.raises(StoreError, match="is not a shapeidx store"):
            open_store(tmp_path / "empty")
        with writer(tmp_path):
            pass
        with h5py.File(main_file(tmp_path / "s.h5"), "a") as f:
            f.attrs["schema_version"] = 99
        with pytest.raises(StoreError, match="newer shapeidx"):
            open_store(tmp_path / "s.h5")


class TestLock:
    def test_a_second_writer_is_refused_with_the_holder_named(self, tmp_path):
        with writer(tmp_path):
            with pytest.raises(StoreError, match=r"another build is writing s\.h5 \(pid \d+"):
                writer(tmp_path)
        with writer(tmp_path):  # released
            pass

    def test_the_lock_dies_with_its_holder(self, tmp_path):
        holder = subprocess.Popen(
            [sys.executable, "-c",
             "import sys, time; from pathlib import Path; from shapeidx.store import *;"
             "from shapeidx.signing.parameters import SIGNATURE_VERSION;"
             "w = StoreWriter(Path(sys.argv[1]), StoreParams(64, 7, 50, SIGNATURE_VERSION), Path('/parts'));"
             "print('locked', flush=True); time.sleep(60)", str(tmp_path / "s.h5")],
            stdout=subprocess.PIPE, text=True,
        )
        try:
            assert holder.stdout.readline().strip() == "locked"
            with pytest.raises(StoreError, match="another build"):
                writer(tmp_path)
        finally:
            holder.kill()
            holder.wait()
        deadline = time.monotonic() + 5
        while True:
            try:
                writer(tmp_path).close()
                break
            except StoreError:
                assert time.monotonic() < deadline, "the lock outlived its holder"
                time.sleep(0.05)


def test_stats_describes_the_store(tmp_path, real_entries):
    entries, _ = real_entries
    with writer(tmp_path) as w:
        w.commit(Batch(entries=entries))
    shutil.copy(main_file(tmp_path / "s.h5"), tmp_path / "copy.h5")
    with open_store(tmp_path / "s.h5") as r:
        facts = describe_store(r)
    assert (facts["entries"], facts["ok"], facts["failed"]) == (6, 5, 1)
    assert facts["journal_batches"] == 1
    assert facts["parameters"] == PARAMS.as_attrs()
    assert facts["root"] == "/parts"
    assert facts["failure_reasons"] == [{"reason": "is empty (0 bytes)", "count": 1}]
    assert facts["bytes"] > (tmp_path / "copy.h5").stat().st_size  # main file plus the batch
