"""Twins drawn again (issue 33): a copy of a part signed with another seed than its original,
so that its points land elsewhere, as a re-export's would. FamilyTable.with_signatures and
scripts/library_twins.py's ``measure --twin-seed`` road (drawn_again), on real kicad6 parts."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import analytic
from clitools import cli
from storetools import REPO, copy_tree, load_script
from shapeidx.families.duplicates import find_duplicates, pair_tiers
from shapeidx.families.table import FamilyTable
from shapeidx.signing.pipeline import signature_of_solid, solid_of_file
from shapeidx.store import open_store

sys.path.insert(0, str(REPO / "scripts"))  # library_twins.py imports its neighbours, as when run as a script
twins_script = load_script("library_twins")

PART = "LED_SMD/LED_RGB_5050-6.wrl"  # chiral: its mirrored twin is flagged
TWINS = ("LED_SMD/LED_RGB_5050-6.rotated.stl", "LED_SMD/LED_RGB_5050-6.mirrored.stl")


@pytest.fixture(scope="module")
def stores(tmp_path_factory, data_dir):
    """A library store (kicad6's LED_SMD) and a twins' store (a rotated and a mirrored STL of one part)."""
    tmp = tmp_path_factory.mktemp("twins")
    library = copy_tree(data_dir / "kicad6", tmp / "library", ["LED_SMD"])
    solid = solid_of_file(library / PART)
    twins = tmp / "twins"
    (twins / "LED_SMD").mkdir(parents=True)
    turn = _rotation()
    analytic.write_stl(twins / TWINS[0], solid.vertices @ turn.T, solid.faces)
    analytic.write_stl(twins / TWINS[1], solid.vertices @ (turn @ np.diag([-1.0, 1, 1])).T, solid.faces[:, ::-1])
    for tree, store in ((library, tmp / "library.shapeidx"), (twins, tmp / "twins.shapeidx")):
        result = cli("build", tree, "--store", store, "-q")
        assert result.exit_code == 0, result.output
    return library, tmp / "library.shapeidx", twins, tmp / "twins.shapeidx"


def _rotation():
    q, _ = np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _counts(signature):
    return {h: signature.histograms[h].counts for h in signature.histograms}


def test_a_twin_signed_with_another_seed_differs_but_stays_in_its_originals_group_as_same(stores):
    library, library_store, twins, twins_store = stores
    table, _, _ = twins_script.combined_table(library_store, twins_store)
    i, j = table.index_of(PART), table.index_of("twins/" + TWINS[0])
    solid = solid_of_file(twins / TWINS[0])
    with open_store(twins_store) as reader:
        stored = reader.signature(int(np.flatnonzero(reader.paths == TWINS[0])[0]))
        params = reader.params
    # the store's seed again gives the stored signature, and putting it back changes nothing
    again = signature_of_solid(solid, params.points, params.seed, params.bin_divisor)
    assert all(np.array_equal(a, b) for a, b in zip(_counts(again).values(), _counts(stored).values()))
    same_again = table.with_signatures([j], [again])
    pairs = (np.array([i, i]), np.array([j, table.index_of("twins/" + TWINS[1])]))
    assert np.allclose(same_again.pair_distances(*pairs, "combined-angle"), table.pair_distances(*pairs, "combined-angle"))
    # seed 7: other points, so another signature and another distance to its original
    seven = signature_of_solid(solid, params.points, 7, params.bin_divisor)
    assert seven.seed == 7 and any(not np.array_equal(a, b) for a, b in zip(_counts(seven).values(), _counts(stored).values()))
    drawn = table.with_signatures([j], [seven])
    assert drawn.d2_basis is None
    before, after = (t.pair_distances(np.array([i]), np.array([j]), "combined-angle")[0] for t in (table, drawn))
    assert after != before and after > 0
    assert not np.allclose(drawn.fractions[j], table.fractions[j]) or not np.allclose(drawn.means[j], table.means[j])
    assert np.array_equal(drawn.moments, table.moments, equal_nan=True) and np.array_equal(drawn.hashes, table.hashes)
    assert np.array_equal(drawn.handedness, table.handedness, equal_nan=True)
    others = np.array([k for k in range(len(table)) if k != j])
    assert np.array_equal(drawn.pair_distances(others[:-1], others[1:], "combined-angle"),
                          table.pair_distances(others[:-1], others[1:], "combined-angle"))
    # exact moments, so still one surface: tier same, in its original's group
    assert pair_tiers(drawn, np.array([i]), np.array([j]))["tier"][0] == "same"
    group = next(g for g in find_duplicates(drawn) if PART in g["members"])
    assert "twins/" + TWINS[0] in group["members"]
    with pytest.raises(ValueError):
        table.with_signatures([j, i], [seven])


def test_measure_twin_seed_signs_every_twin_again_once_per_seed(stores, tmp_path):
    library, library_store, twins, twins_store = stores
    cache = tmp_path / "again.pkl"
    tables, facts = twins_script.drawn_again(twins_store, [7, 8], cache=cache, check_every=1)
    assert facts["checked"] == facts["matched"] == 2 and not facts["failed"] and cache.exists()
    with open_store(twins_store) as reader:
        shared = FamilyTable.load(reader)
    k = shared.index_of(TWINS[1])  # the mirrored twin: seed S + 1000 x its kind
    assert twins_script.kind_seed(7, "mirrored") == 7 + 2000
    assert not np.array_equal(tables[7].means, shared.means) and np.array_equal(tables[7].moments, shared.moments)
    assert not np.array_equal(tables[7].means[k], tables[8].means[k])
    for seed in (7, 8):
        table, _, _ = twins_script.combined_table(library_store, twins_store, twins_table=tables[seed])
        figures = twins_script.twin_figures(table, "combined-angle", ["identical", "same", "converted"], 1, None)
        assert {v: len(k["found"]) for v, k in figures["kinds"].items()} == {"rotated": 1, "mirrored": 1}
        assert figures["kinds"]["mirrored"]["mirrored"] == 1 == figures["kinds"]["mirrored"]["chiral"]
        assert figures["kinds"]["rotated"]["pair_tier"]["twins/" + TWINS[0]] == "same"
    # the cache is read back (the same signatures) when it holds the seeds asked for
    again, _ = twins_script.drawn_again(twins_store, [8], cache=cache)
    assert np.array_equal(again[8].histograms["all"].p, tables[8].histograms["all"].p)
