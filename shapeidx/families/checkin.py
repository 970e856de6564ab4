"""``shapeidx check-new``: is this new part already in the library?

Each new or changed part file is signed with the store's parameters, its nearest entries
are found on the one query road (:class:`shapeidx.search.searcher.Searcher`, metric
``default_metric("check-new")`` unless another is given), joined by the entries whose exact
surface moments are nearest (as ``duplicates`` finds its candidates twice) and those whose file
content is the same, and each candidate pair is put in its tier by
:func:`shapeidx.families.duplicates.pair_tiers` over a small table of the new part and its
candidates: the same tiers, thresholds, size ratio, unit factor and mirror flag as
``shapeidx duplicates``, never a second copy of them. Pairs of tier ``identical``, ``same``
or ``converted`` are *duplicates* (``converted`` only with the candidate closest to the new part
of its format and unit, as ``duplicates`` pairs each entry with its closest conversion); the
other candidates are *look-alikes* (``similar``, ``near`` or a plain neighbour), nearest first.

A file that the store holds under the same path with the same content is not news (it is
reported as ``unchanged`` and checked no further). ``exclude_self`` leaves the file's own
entry out of the answer: "checked as new against the store without it".
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from ..errors import ShapeidxError
from ..io.base import file_hash
from ..distance.metrics import default_metric
from ..store.candidates import OVERFETCH
from .duplicates import DEFAULT_TIERS, TIERS, fingerprint_vectors, pair_tiers

#: Nearest entries looked at per new part.
CANDIDATES = 20
#: Look-alikes reported per new part.
LOOK_ALIKES = 5


def _text(digest) -> str:
    """A stored hash as text (HDF5 gives bytes)."""
    return digest.decode() if isinstance(digest, bytes) else str(digest)


def _guest_table(entry, store_table, rows):
    """A FamilyTable of the new part (row 0, named by ``entry.path``, whose suffix gives its file
    format for the tier ``converted``) and the store table's ``rows``."""
    from ..store.layout import entries_to_columns, handedness_columns
    from ..signing.angles import ANGLE_BINS, ANGLE_HISTOGRAMS, angle_probabilities
    from ..signing.parameters import HISTOGRAMS
    from .table import FamilyTable, RaggedHistograms
    from ..ragged import offsets_of

    columns, counts = entries_to_columns([entry])
    part = store_table.subset(np.asarray(rows, dtype=np.int64))
    hists = {}
    for name, ragged in part.histograms.items():
        flat, lengths = counts[name]
        guest = RaggedHistograms.from_counts(flat, lengths)
        hists[name] = RaggedHistograms(np.concatenate([guest.p, ragged.p]),
                                       offsets_of(np.concatenate([guest.lengths, ragged.lengths])))
    means = np.array([[columns[f"histograms/{h}/mean"][0] for h in HISTOGRAMS]])
    angles = None
    if part.angles is not None:
        raw = columns["entries/angles"].reshape(1, len(ANGLE_HISTOGRAMS), ANGLE_BINS)
        angles = np.concatenate([angle_probabilities(raw), part.angles])

    def join(name, values):
        return None if values is None else np.concatenate([columns[name].reshape(1, -1), values])

    return FamilyTable(
        paths=np.concatenate([np.array([entry.path], dtype=object), part.paths]),
        rows=np.concatenate([[-1], part.rows]), histograms=hists,
        fractions=join("entries/fractions", part.fractions), means=np.concatenate([means, part.means]),
        hashes=np.concatenate([columns["entries/hash"], part.hashes]),
        extents=join("entries/extents", part.extents),
        handedness=None if part.handedness is None else np.concatenate([handedness_columns(columns.__getitem__),
                                                                         part.handedness]),
        missing_columns=part.missing_columns, bounds=join("entries/bounds", part.bounds),
        moments=join("entries/moments", part.moments), angles=angles)


class Checker:
    """A store opened to check new parts against (``with Checker(store) as c: c.check(path)``)."""

    def __init__(self, store, metric: str = default_metric("check-new"), scale: str = "invariant",
                 parts: bool = False):
        from ..distance import METRIC_HISTOGRAMS
        from ..search.sharded import open_searcher
        from ..store import open_store
        from ..store.reader import member_stores
        from .table import FamilyTable

        self.metric, self.scale, self.parts = metric, scale, parts
        self.searcher = open_searcher(store, parts=parts)  # an ordinary store, or every shard of a sharded one
        try:
            self.table = FamilyTable.load_store(store, METRIC_HISTOGRAMS[metric], parts)
            self.stored = {}  # every file's hash, failed ones too: a file not changed is not news
            for path in member_stores(store):
                with open_store(path) as reader:
                    self.stored.update(zip(reader.paths.tolist(), (_text(h) for h in reader.column("entries/hash"))))
        except BaseException:
            self.searcher.close()
            raise
        self.by_hash: dict[str, list[int]] = {}
        if parts:
            # a sub-part holds its file's hash: tiered by its geometry alone, as duplicates --parts does
            self.table = dataclasses.replace(self.table, hashes=np.array(
                [h + b"#" + str(p).encode("utf-8", "surrogatepass") if len(h) else h
                 for h, p in zip(self.table.hashes, self.table.paths)], dtype=object))
            return
        for row, digest in enumerate(self.table.hashes):
            self.by_hash.setdefault(_text(digest), []).append(row)

    def _moment_neighbours(self, entry, count: int) -> list[int]:
        """The rows whose exact surface moments are nearest the new part's (``duplicates``'
        second candidate list, :func:`~shapeidx.families.duplicates.fingerprint_vectors`): a
        twin whose sampled distance is noisy, or a conversion, is found by its moments. As
        ``duplicates`` looks, :data:`~shapeidx.store.candidates.OVERFETCH` times the candidates."""
        if not hasattr(self, "_vectors"):
            self._vectors = fingerprint_vectors(self.table)
        if self._vectors is None or count <= 0:
            return []
        mine = fingerprint_vectors(_guest_table(entry, self.table, []))
        if mine is None:
            return []
        d = np.linalg.norm(self._vectors - mine[0], axis=1)
        count = min(count, len(d))
        near = np.argpartition(d, count - 1)[:count]
        return near[np.argsort(d[near], kind="stable")].tolist()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.searcher.close()

    def check(self, path: str, exclude_self: bool = False, candidates: int = CANDIDATES,
              look_alikes: int = LOOK_ALIKES, seed: int | None = None) -> dict:
        """The report on one file: ``file``, ``status`` (``unchanged``, ``duplicate``, ``new``),
        ``duplicates`` and ``look_alikes`` (each: ``path``, ``tier``, ``distance``,
        ``size_ratio``, ``unit``, ``mirrored``, ``words``). ``seed``: the new part's points drawn
        with this seed rather than the store's (studies: no stored entry shares its points)."""
        from ..search.searcher import Filters
        from ..store.layout import Entry

        digest = file_hash(path)
        entry_name = self.searcher.entry_path_of(path)
        if not exclude_self and entry_name is not None and self.stored.get(entry_name) == digest:
            return {"file": path, "entry": entry_name, "status": "unchanged", "duplicates": [], "look_alikes": []}
        query = self.searcher.query_of_part(path, seed=seed)
        own = query.entry if exclude_self else None
        # the file's own sub-parts are not its entry to the search (FILE#n): left out here
        mine = set() if not (self.parts and exclude_self and entry_name) else {
            p for p in self.table.paths.tolist() if str(p).rpartition("#")[0] == entry_name}
        answer = self.searcher.search(query, top=candidates + len(mine), metric=self.metric,
                                      filters=Filters(exclude_self=exclude_self))
        rows = [self.table.index_of(h.relative_path) for h in answer.hits if h.relative_path not in mine]
        rows = [r for r in rows if r is not None][:candidates]
        rows += [r for r in self.by_hash.get(digest, []) if r not in rows]
        solid = query.solid
        st = os.stat(path)
        entry = Entry.indexed("\0new/" + os.path.basename(path), digest, st.st_size, st.st_mtime_ns, query.signature, solid.describe(),
                              solid.facts)
        rows += [r for r in self._moment_neighbours(entry, OVERFETCH * candidates) if r not in rows]
        rows = [r for r in rows if (own is None or self.table.paths[r] != own) and self.table.paths[r] not in mine]
        dups, looks = [], []
        if rows:
            table = _guest_table(entry, self.table, rows)
            b = np.arange(1, len(rows) + 1)
            facts = pair_tiers(table, np.zeros(len(rows), np.int64), b, self.metric, self.scale, closest=True)
            root = self.searcher.root
            for k, r in enumerate(rows):
                tier = str(facts["tier"][k])
                ratio, unit = float(facts["size_ratio"][k]), float(facts["unit"][k])
                item = {"path": os.path.join(root, str(self.table.paths[r])) if root else str(self.table.paths[r]),
                        "relative_path": str(self.table.paths[r]), "tier": tier or "look-alike",
                        "distance": float(facts["distance"][k]),
                        "size_ratio": ratio if np.isfinite(ratio) else None,
                        "unit": unit if np.isfinite(unit) else None, "mirrored": bool(facts["mirrored"][k]),
                        "words": TIER_WORDS.get(tier, TIER_WORDS[""])}
                (dups if tier in DEFAULT_TIERS else looks).append(item)
        order = lambda i: (TIERS.index(i["tier"]) if i["tier"] in TIERS else len(TIERS), i["distance"], i["path"])
        dups.sort(key=order)
        looks.sort(key=lambda i: (i["distance"], i["path"]))
        return {"file": path, "entry": query.entry, "status": "duplicate" if dups else "new",
                "duplicates": dups, "look_alikes": looks[:look_alikes]}


TIER_WORDS = {
    "identical": "the same file",
    "same": "the same part (same surface)",
    "converted": "the same part from another program (another format or other units)",
    "similar": "one body, details may differ (a series sibling)",
    "near": "a near duplicate",
    "": "a look-alike worth a look",
}


def git_changed(rev: str, cwd: str = ".") -> list[str]:
    """The part files a commit range added or changed (``REV`` alone: ``REV^..REV``; ``A..B``; the
    staged files for ``--git --cached``-like ``:staged``), absolute paths."""
    import subprocess

    from ..io.formats import SUFFIXES

    if rev == ":staged":
        args = ["git", "diff", "--cached", "--name-only", "--diff-filter=AM", "-z"]
    else:
        span = rev if ".." in rev else f"{rev}^..{rev}"
        args = ["git", "diff", "--name-only", "--diff-filter=AM", "-z", span]
    try:
        top = subprocess.run(["git", "rev-parse", "--show-toplevel"], cwd=cwd, capture_output=True, text=True,
                             check=True).stdout.strip()
        out = subprocess.run(args, cwd=cwd, capture_output=True, check=True).stdout.decode("utf-8", "surrogateescape")
    except FileNotFoundError:
        raise ShapeidxError("git is not installed")
    except subprocess.CalledProcessError as exc:
        raise ShapeidxError(f"git cannot list the files of {rev!r}: {exc.stderr.decode(errors='replace').strip()}")
    suffixes = tuple(s for group in SUFFIXES.values() for s in group)
    names = [n for n in out.split("\0") if n]
    return [os.path.join(top, n) for n in names
            if n.lower().removesuffix(".gz").endswith(suffixes)]
