"""A store damaged in HDF5's global heap is refused (exit 5, one line), never a hang.

The damage is made as an attacker (or a bad disk) would: bytes overwritten in place in the
global heap collection that holds a real store's strings. The collection is found through
HDF5 itself (the raw variable-length references of ``entries/path``: length, collection
address, object index), not by the signature scan the code uses, and its objects are walked
here by the file format's description.
"""

from __future__ import annotations

import struct
import subprocess

import h5py
import pytest
from clitools import run_shapeidx
from storetools import build, small_kicad

from shapeidx.store.heaps import GlobalHeapDamaged, check_global_heaps

TIMEOUT = 60  # the damage made every command spin forever in HDF5's heap decoder


def collection_of_paths(main) -> int:
    """The file address of the global heap collection holding the first entry's path."""
    with h5py.File(main, "r") as f:
        dataset = f["entries/path"]
        if dataset.chunks:
            _, raw = dataset.id.read_direct_chunk((0,))
        else:
            with open(main, "rb") as g:
                g.seek(dataset.id.get_offset())
                raw = g.read(16)
    _, address, _ = struct.unpack_from("<IQI", raw, 0)
    return address


def objects(main, address):
    """(index, offset, size) of each object of the collection at ``address``."""
    data = open(main, "rb").read()
    assert data[address : address + 4] == b"GCOL"
    end = address + struct.unpack_from("<Q", data, address + 8)[0]
    p, found = address + 16, []
    while p + 16 <= end:
        index, size = struct.unpack_from("<H", data, p)[0], struct.unpack_from("<Q", data, p + 8)[0]
        found.append((index, p, size))
        p += size if index == 0 else 16 + (size + 7) // 8 * 8
    return found


def overwrite(path, offset, data: bytes):
    with open(path, "r+b") as f:  # in place, as dd conv=notrunc would
        f.seek(offset)
        f.write(data)


@pytest.fixture
def store(data_dir, tmp_path):
    tree = small_kicad(data_dir, tmp_path, ("LED_SMD",))
    store = tmp_path / "s.shapeidx"
    assert build(tree, store).exit_code == 0
    return tree, store


def damage(main, how):
    address = collection_of_paths(main)
    found = objects(main, address)
    free = [o for o in found if o[0] == 0]
    if how == "free space of size 0":
        _, at, _ = free[-1]
        overwrite(main, at + 8, struct.pack("<Q", 0))
    elif how == "an object turned into empty free space":
        _, at, _ = found[1]
        overwrite(main, at, struct.pack("<H", 0))
        overwrite(main, at + 8, struct.pack("<Q", 0))
    elif how == "an object size that wraps around":
        _, at, _ = found[2]
        overwrite(main, at + 8, struct.pack("<Q", 2**64 - 32))
    else:
        raise AssertionError(how)


HOWS = ["free space of size 0", "an object turned into empty free space", "an object size that wraps around"]


@pytest.mark.parametrize("how", HOWS)
def test_every_command_refuses_the_damage_in_one_line(store, how):
    tree, store = store
    main = store / "main.h5"
    damage(main, how)
    with pytest.raises(GlobalHeapDamaged, match="global heap collection at byte"):
        check_global_heaps(main)
    entry = "LED_SMD/" + sorted(p.name for p in (tree / "LED_SMD").iterdir())[0]
    for args in (("stats",), ("query", "--id", entry), ("check",), ("duplicates",)):
        try:
            result = run_shapeidx(*args, "--store", store, timeout=TIMEOUT)
        except subprocess.TimeoutExpired:
            pytest.fail(f"shapeidx {args[0]} hangs on a store damaged in its global heap ({how})")
        assert result.returncode == 5, (args, result.stderr)
        assert "Traceback" not in result.stderr
        assert "global heap collection at byte" in result.stderr + result.stdout, (args, result.stderr)
        if args[0] != "check":
            assert len(result.stderr.strip().splitlines()) == 1, result.stderr


def test_repair_rebuilds_a_store_damaged_in_its_global_heap(store):
    tree, store = store
    damage(store / "main.h5", "free space of size 0")
    try:
        result = run_shapeidx("build", tree, "--store", store, "--repair", "--points", "128", "--workers", "1",
                              timeout=4 * TIMEOUT)
    except subprocess.TimeoutExpired:
        pytest.fail("build --repair hangs on a store damaged in its global heap")
    assert result.returncode == 0, result.stderr
    assert "main file could not be used" in result.stderr
    again = run_shapeidx("check", "--store", store, timeout=TIMEOUT)
    assert again.returncode == 0, again.stdout + again.stderr


def test_a_sound_store_passes_and_a_stray_signature_is_not_a_collection(store, tmp_path):
    _, store = store
    check_global_heaps(store / "main.h5")
    odd = tmp_path / "odd.bin"
    odd.write_bytes(b"GCOL" * 10 + b"GCOL\x02\x00\x00\x00" + b"\xff" * 64 + b"GCOL")  # not collection headers
    check_global_heaps(odd)


@pytest.mark.parametrize("offset", [48, 56])
def test_a_damaged_object_header_is_damage_not_a_bug(store, offset):
    """A bit flipped in the root group's object header (h5py raises KeyError, not OSError,
    when it reads the attributes): check and build say damaged (5), --repair rebuilds."""
    tree, store = store
    main = store / "main.h5"
    data = bytearray(main.read_bytes())
    data[offset] ^= 1
    main.write_bytes(bytes(data))
    check = run_shapeidx("check", "--store", store, timeout=TIMEOUT)
    assert check.returncode == 5 and "internal error" not in check.stderr, check.stderr
    built = run_shapeidx("build", tree, "--store", store, "--points", "128", "--workers", "1", timeout=4 * TIMEOUT)
    assert built.returncode == 5 and len(built.stderr.strip().splitlines()) == 1, built.stderr
    repaired = run_shapeidx("build", tree, "--store", store, "--repair", "--points", "128", "--workers", "1",
                            timeout=4 * TIMEOUT)
    assert repaired.returncode == 0, repaired.stderr
    assert run_shapeidx("check", "--store", store, timeout=TIMEOUT).returncode == 0


def test_a_forged_verified_record_does_not_skip_the_heap_walk_of_a_small_store(store):
    """STORE/verified rewritten to match the damaged main file (as a build that read it whole
    would): a store below TRUST_VERIFIED_ABOVE is walked all the same."""
    import json
    import os

    _, store = store
    main = store / "main.h5"
    damage(main, "free space of size 0")
    stat = os.stat(main)
    (store / "verified").write_text(json.dumps({k: int(getattr(stat, k)) for k in
                                                ("st_dev", "st_ino", "st_size", "st_mtime_ns", "st_ctime_ns")}))
    try:
        result = run_shapeidx("stats", "--store", store, timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        pytest.fail("a forged STORE/verified makes stats hang")
    assert result.returncode == 5 and "global heap" in result.stderr


@pytest.mark.parametrize("name", ["committed", "build.json", "verified", "lock", "main.h5"])
def test_a_fifo_in_place_of_a_store_file_never_blocks(store, name):
    """A FIFO without a writer, put where a store file was: opening it for reading blocks
    forever, so every read of a store file goes through a non-blocking open."""
    import os

    tree, store = store
    target = store / name
    target.unlink(missing_ok=True)
    os.mkfifo(target)
    entry = "LED_SMD/" + sorted(p.name for p in (tree / "LED_SMD").iterdir())[0]
    for args in (("stats",), ("check",), ("query", "--id", entry), ("build", tree, "--points", "128", "--workers", "1")):
        try:
            result = run_shapeidx(*args, "--store", store, timeout=TIMEOUT)
        except subprocess.TimeoutExpired:
            pytest.fail(f"shapeidx {args[0]} blocks on a FIFO in place of {name}")
        assert result.returncode in (0, 1, 5) and "Traceback" not in result.stderr, (args, result.stderr)
        if name == "main.h5":
            assert result.returncode == 5
        if name == "lock" and args[0] == "build":
            assert result.returncode == 1 and "not a regular file" in result.stderr


def test_a_damaged_metadata_table_is_found_by_check_and_written_again(data_dir, tmp_path):
    """metadata.h5 cut in half: every command that reads it said damaged (5) but check passed
    it (0), and build --metadata, the one way to mend it, refused too."""
    import os

    tree = small_kicad(data_dir, tmp_path, ("LED_SMD",))
    table = tmp_path / "meta.csv"
    table.write_text("path,material\n" + "".join(f"LED_SMD/{p.name},steel\n" for p in sorted((tree / "LED_SMD").iterdir())))
    store = tmp_path / "s.shapeidx"
    assert build(tree, store, "--metadata", table).exit_code == 0
    meta = store / "metadata.h5"
    os.truncate(meta, meta.stat().st_size // 2)
    check = run_shapeidx("check", "--store", store, timeout=TIMEOUT)
    assert check.returncode == 5 and "metadata.h5" in check.stdout + check.stderr, check.stdout + check.stderr
    assert run_shapeidx("stats", "--store", store, timeout=TIMEOUT).returncode == 5
    again = run_shapeidx("build", tree, "--store", store, "--metadata", table, "--points", "128", "--workers", "1",
                         timeout=4 * TIMEOUT)
    assert again.returncode == 0 and "metadata table was damaged" in again.stderr, again.stderr
    assert run_shapeidx("check", "--store", store, timeout=TIMEOUT).returncode == 0
    stats = run_shapeidx("stats", "--store", store, timeout=TIMEOUT)
    assert stats.returncode == 0 and "material" in stats.stdout
