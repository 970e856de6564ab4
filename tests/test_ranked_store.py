"""The store's memory-mapped ranking section and its size-tiered journal segments.

Ranking from the ``rank/`` arrays (shapeidx.store.ranked, shapeidx.search) is checked against
``compare()`` over the signatures of the canonical (Fletcher-32) data, which shares none of
its layout: every distance equal bit for bit, the same hits, on a real kicad6 store, on a
synthetic one and on stores whose journal holds segments that supersede and remove entries of
the main file.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest
from clitools import cli, run_shapeidx
from storetools import REPO, build, small_kicad

from shapeidx.api import query as query_store
from shapeidx.distance import METRICS, compare
from shapeidx.errors import StoreError
from shapeidx.search import Searcher
from shapeidx.search.distances import distances
from shapeidx.store import Batch, Entry, StoreWriter, open_store
from shapeidx.store.files import batch_files, journal_dir, main_file
from shapeidx.store.ranked import ranked_view
from shapeidx.store.writer import GROWTH


@pytest.fixture(scope="module")
def real_store(data_dir, tmp_path_factory):
    """A real store of 30 kicad6 parts (fast points) and a synthetic one of 3,000 entries made from it."""
    tmp = tmp_path_factory.mktemp("ranked")
    tree = small_kicad(data_dir, tmp)
    store = tmp / "real.shapeidx"
    assert build(tree, store).exit_code == 0
    made = tmp / "made.shapeidx"
    run = subprocess.run([sys.executable, str(REPO / "scripts" / "make_store.py"), str(store), "3000", str(made)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    return tree, store, made


def canonical(reader):
    """Every entry's path and signature from the canonical (checksummed) datasets, sorted by path."""
    ok = np.flatnonzero(reader.column("entries/status") == 0)
    return reader.paths[ok], [reader.signature(int(i)) for i in ok]


def expected_hits(paths, d, top, first=None):
    order = sorted(range(len(d)), key=lambda i: (d[i], i != first, paths[i]))[:top]
    return [(str(paths[i]), float(d[i])) for i in order]


def assert_ranks_as_the_table(store, queries=4, reader=None):
    """Every metric's distances from the ranking arrays equal compare() over the canonical
    signatures, bit for bit; the hits are the same."""
    own = reader is None
    reader = reader or open_store(store)
    try:
        paths, signatures = canonical(reader)
    finally:
        if own:
            reader.close()
    with Searcher(store) as searcher:
        view = searcher.view
        assert len(view) == len(paths)
        # the view lists files one after another; the canonical list is sorted by path: match them by path
        view_paths = np.array([view.path_at(k) for k in range(len(view))], dtype=object)
        order = np.argsort(view_paths, kind="stable")
        assert np.array_equal(view_paths[order], paths)
        rng = np.random.default_rng(7)
        for q in rng.choice(len(paths), min(queries, len(paths)), replace=False):
            signature = signatures[q]
            pairwise = [compare(signature, other) for other in signatures]
            for metric in METRICS:
                expected = np.array([p[metric] for p in pairwise])
                for threads in (1, 2):
                    got = distances(view, signature, metric, threads=threads)[order]
                    assert np.array_equal(got, expected), (metric, threads)
                for top in (1, 10):  # every metric prunes by its lower bounds: the hits are still exact
                    hits = [(h["relative_path"], h["distance"]) for h in query_store(searcher, signature, top=top, metric=metric)]
                    assert hits == expected_hits(paths, expected, top), (metric, top)
            d = np.array([p["weighted"] for p in pairwise])
            limit = float(np.sort(d)[min(len(d) - 1, 40)])
            within = np.flatnonzero(d <= limit)
            hits = [(h["relative_path"], h["distance"]) for h in query_store(searcher, signature, top=500, max_distance=limit)]
            assert hits == expected_hits(paths[within], d[within], 500)


def test_a_real_store_ranks_from_its_mapped_arrays_bit_for_bit(real_store):
    _, store, _ = real_store
    with h5py.File(main_file(store), "r") as f:  # the documented layout: contiguous, mappable, checksummed
        counts = f["rank/in/counts"]
        assert counts.chunks is None and counts.id.get_offset() is not None and "crc32" in counts.attrs
    assert_ranks_as_the_table(store, queries=6)


def test_a_synthetic_store_ranks_from_its_mapped_arrays_bit_for_bit(real_store):
    _, _, made = real_store
    assert_ranks_as_the_table(made, queries=2)


def test_query_by_entry_finds_the_same_hits_as_the_full_table(real_store):
    tree, store, _ = real_store
    with open_store(store) as reader:
        paths, signatures = canonical(reader)
    entry = str(paths[3])
    d = np.array([compare(signatures[3], other)["weighted"] for other in signatures])
    expected = expected_hits(paths, d, 5, first=3)
    assert [(h["relative_path"], h["distance"]) for h in query_store(store, entry=entry, top=5)] == expected
    assert expected[0][0] == entry
    # a file of the tree as the part: its own entry wins its ties, as with --id
    assert query_store(store, tree / entry, top=1)[0]["relative_path"] == entry
    excluded = query_store(store, entry=entry, top=4, exclude_self=True, scale="sensitive")
    assert entry not in [h["relative_path"] for h in excluded]
    out = json.loads(run_shapeidx("query", "--id", entry, "--store", store, "--top", "3", "--json").stdout)
    assert [h["relative_path"] for h in out["hits"]] == [p for p, _ in expected[:3]]


def _entry_like(path, signature):
    return Entry(path=path, hash="a" * 64, size=1, mtime_ns=1, triangles=12, area=1.0, watertight=True,
                 fractions=tuple(signature.fractions[c] for c in ("in", "out", "mixed")),
                 histograms=dict(signature.histograms), angles=tuple(np.ravel(signature.angles).tolist()))


def test_journal_segments_supersede_main_rows_and_rank_as_the_full_view(real_store, tmp_path):
    """Commits that change, add and remove entries of a synthetic store; after each tiered merge
    the mapped ranking equals the full (path-merged) reader, and the main file is never rewritten."""
    _, _, made = real_store
    store = tmp_path / "s.shapeidx"
    shutil.copytree(made, store)
    with open_store(store) as reader:
        params, root, paths = reader.params, reader.attrs["root"], list(reader.paths)
        donors = [reader.signature(i) for i in range(0, 300, 3)]
    inode = main_file(store).stat().st_ino
    rng = np.random.default_rng(3)
    expected = set(paths)
    with StoreWriter(store, params, root) as writer:
        for k in range(12):
            changed = {paths[i] for i in rng.choice(len(paths), 40, replace=False)}
            added = {f"added/{k}-{j}.wrl" for j in range(10)}
            entries = [_entry_like(p, donors[(k + j) % len(donors)]) for j, p in enumerate(sorted(changed | added))]
            removed = [p for p in (paths[i] for i in rng.choice(len(paths), 3)) if p not in changed and p in expected]
            writer.commit(Batch(entries=entries, removed=removed, touched=[(paths[k], 5, 6)]))
            writer.compact()
            expected = (expected | added | changed) - set(removed)
            with open_store(store) as reader:
                assert set(reader.paths) == expected
                segments = [len(s) for s in reader._sources[1:]]
                # sizes grow geometrically from the newest segment to the oldest: O(log N) of them
                assert all(older > GROWTH * newer for older, newer in zip(segments, segments[1:]))
                if k % 4 == 3:
                    assert_ranks_as_the_table(store, queries=2, reader=reader)
    assert main_file(store).stat().st_ino == inode  # tiered merges never reached the 3,000-entry main file
    with StoreWriter(store, params, root) as writer:
        writer.merge()  # everything into the main file, as before
    assert not batch_files(store)
    with open_store(store) as reader:
        assert set(reader.paths) == expected
    assert_ranks_as_the_table(store, queries=2)


def test_a_merge_killed_before_deleting_its_batches_leaves_the_same_view(real_store, tmp_path):
    """A merge of batches a..b writes batch-b and then deletes a..b-1: the store reads the same
    with those still there (a kill in between), and the next writer deletes them."""
    _, _, made = real_store
    store = tmp_path / "s.shapeidx"
    shutil.copytree(made, store)
    with open_store(store) as reader:
        params, root = reader.params, reader.attrs["root"]
        donor = reader.signature(0)
    with StoreWriter(store, params, root) as writer:
        for k in range(3):
            writer.commit(Batch(entries=[_entry_like(f"n/{k}-{j}.wrl", donor) for j in range(40)]))
    saved = {path.name: path.read_bytes() for _, path in batch_files(store)}
    with StoreWriter(store, params, root) as writer:
        writer.compact()
    after = [path.name for _, path in batch_files(store)]
    assert len(after) < len(saved)
    for name, data in saved.items():  # as if killed right after the merged segment's rename
        if name not in after:
            (journal_dir(store) / name).write_bytes(data)
    with open_store(store) as reader:
        assert len(reader._sources) == 1 + len(after)  # the covered batches are left out
    assert_ranks_as_the_table(store, queries=2)
    with StoreWriter(store, params, root):
        pass
    assert [path.name for _, path in batch_files(store)] == after


def copy_and_query(real_store, tmp_path, row: int, **options):
    """A copy of the real store, the signature of its entry ``row`` and that entry's hits."""
    store = tmp_path / "s.shapeidx"
    shutil.copytree(real_store[1], store)
    with open_store(store) as reader:
        signature = reader.signature(row)
    return store, signature, query_store(store, signature, top=5, **options)


def test_check_finds_a_flipped_byte_in_the_ranking_arrays_and_repair_rebuilds_them(real_store, tmp_path):
    store, signature, before = copy_and_query(real_store, tmp_path, 5)
    with h5py.File(main_file(store), "r") as f:
        offset = f["rank/out/counts"].id.get_offset() + 4 * 17
    with open(main_file(store), "r+b") as f:
        f.seek(offset)
        byte = f.read(1)
        f.seek(offset)
        f.write(bytes([byte[0] ^ 0x10]))
    result = cli("check", "--store", store)
    assert result.exit_code == 5
    assert "rank/out/counts fails its checksum" in result.output and "check --repair" in result.output
    repaired = cli("check", "--store", store, "--repair")
    assert repaired.exit_code == 0, repaired.output
    assert "rebuilt the ranking arrays" in repaired.output
    assert query_store(store, signature, top=5) == before


def test_a_layout_2_store_is_refused_in_one_line_until_check_repair_adds_the_arrays(real_store, tmp_path):
    store, signature, before = copy_and_query(real_store, tmp_path, 2, metric="avg4")
    with h5py.File(main_file(store), "r+") as f:  # what a layout-2 shapeidx wrote: no rank/ section
        del f["rank"]
        f.attrs["schema_version"] = 2
    with open_store(store) as reader, pytest.raises(StoreError, match="check --repair"):
        ranked_view(reader)
    refused = cli("query", "--store", store, "--id", str(before[0]["relative_path"]))
    assert refused.exit_code == 1 and len(refused.stderr.strip().splitlines()) == 1 and "check --repair" in refused.stderr
    result = cli("check", "--store", store)
    assert result.exit_code == 0 and "check --repair" in result.output
    assert cli("check", "--store", store, "--repair").exit_code == 0
    assert query_store(store, signature, top=5, metric="avg4") == before


def test_a_layout_2_store_gains_the_arrays_at_its_next_merge(real_store, tmp_path):
    _, _, made = real_store
    store = tmp_path / "s.shapeidx"
    shutil.copytree(made, store)
    with h5py.File(main_file(store), "r+") as f:
        del f["rank"]
        f.attrs["schema_version"] = 2
    with open_store(store) as reader:
        params, root = reader.params, reader.attrs["root"]
        donor = reader.signature(1)
    with StoreWriter(store, params, root) as writer:
        writer.commit(Batch(entries=[_entry_like("new/one.wrl", donor)]))
        writer.compact()  # a tiered merge would leave the main file alone; without arrays it is rewritten
    assert not batch_files(store)
    with open_store(store) as reader:
        assert reader.attrs["schema_version"] == 4 and len(reader) == 3001
    assert_ranks_as_the_table(store, queries=1)
