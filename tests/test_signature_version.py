"""A store of an older signature version (SIGNATURE_VERSION) is refused by every reader with
the command that mends it, and that build signs every entry again: the store it leaves equals
a fresh build's, entry for entry."""

from __future__ import annotations

import glob
import os

import h5py
import numpy as np
from clitools import cli, cli_json
from storetools import build, small_kicad, summary_counts

from shapeidx.signing.parameters import HISTOGRAMS, SIGNATURE_VERSION
from shapeidx.store import open_store


def make_older(store, version: int) -> int:
    """Stamp every file of ``store`` with signature ``version``, as an older shapeidx wrote it."""
    files = glob.glob(os.path.join(store, "**", "*.h5"), recursive=True)
    stamped = 0
    for name in files:
        with h5py.File(name, "r+") as f:
            if "signature_version" in f.attrs:
                f.attrs["signature_version"] = version
                stamped += 1
    return stamped


def entries(store) -> dict:
    with open_store(store) as reader:
        paths = [str(p) for p in reader.column("entries/path")]
        counts = {h: reader.counts(h, np.arange(len(paths))) for h in HISTOGRAMS}
        return {"version": reader.params.signature_version, "paths": paths,
                "counts": {h: (c[0].tolist(), c[1].tolist()) for h, c in counts.items()}}


def test_an_older_store_is_refused_then_signed_again_by_its_next_build(data_dir, tmp_path):
    tree = small_kicad(data_dir, tmp_path)
    store, fresh = tmp_path / "old.shapeidx", tmp_path / "fresh.shapeidx"
    assert build(tree, store).exit_code == 0
    assert make_older(store, SIGNATURE_VERSION - 1) >= 1
    part = next(tree.rglob("*.wrl"))

    refused = cli("query", part, "--store", store)
    assert refused.exit_code == 1, refused.output
    line = refused.stderr.strip()
    assert len(line.splitlines()) == 1 and "Traceback" not in line
    assert f"version {SIGNATURE_VERSION - 1}" in line and f"--store {store}" in line and "build" in line

    again = build(tree, store)
    assert again.exit_code == 0, again.output + again.stderr
    assert f"signature version {SIGNATURE_VERSION - 1}" in again.stderr + again.output
    assert summary_counts(again.output)["indexed"] == 30  # every entry, though no file changed
    assert not (tmp_path / "old.shapeidx.resign").exists() and not (tmp_path / "old.shapeidx.older").exists()

    assert build(tree, fresh).exit_code == 0
    assert entries(store) == entries(fresh)
    assert entries(store)["version"] == SIGNATURE_VERSION
    assert cli("query", part, "--store", store).exit_code == 0
    assert cli_json("check", "--store", store)["ok"]
    assert summary_counts(build(tree, store).output)["indexed"] == 0  # current now: nothing to do
