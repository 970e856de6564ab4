#!/usr/bin/env python3
"""What a big store costs: a one-off query, and a commit and merge of a small change.

Usage::

    python scripts/bench_store.py query PART STORE... [--repeat R] [--top K]
    python scripts/bench_store.py commit STORE... [--files 100] [--rounds R]
    python scripts/bench_store.py recall STORE [--queries Q] [--top K] [--metric M]
    python scripts/bench_store.py build STORE... --old-code DIR --work DIR [--files 100] [--rounds R]

``query`` times the whole ``shapeidx query PART --store STORE`` command (a fresh process:
Python's start, the imports, the query part's signature, opening the store, ranking and
printing) on each store, the stores interleaved round after round so that the machine's
load falls on all of them alike, after one warm-up run each (the page cache then holds the
files, as it does on a machine that queries its store). Medians, and the ratio of each
store's median to the first store's.

``commit`` changes ``--files`` entries of each store (new signatures, taken from other
entries, for existing paths) per round, through shapeidx's own :class:`StoreWriter`: the
time of the commit (a journal batch) and of the size-tiered merge after it
(:meth:`StoreWriter.compact`), over ``--rounds`` rounds, and the journal's segments after
them; ``--full`` merges everything into the main file instead (what every merge did before
layout 3). THE STORES ARE CHANGED: run it on copies made with scripts/make_store.py.

``recall`` checks the pruned ranking (lower bounds, then exact distances) against the full
exact ranking of every entry, with entries of the store as queries: recall@K (1.0 is what
the bounds guarantee), whether the distances are equal bit for bit, and both times.

``build`` times a whole ``shapeidx build`` that changes ``--files`` files of a big store, in
a fresh process from its start to its last commit, with this checkout's shapeidx ("new") and
with the one at ``--old-code`` (a copy of an older tree's ``shapeidx/`` package, e.g.
``git archive main shapeidx | tar -x -C DIR``; "old"), interleaved round after round on
their own copies of each store (made in ``--work``; the given stores are not changed). The
copies' recorded root is a folder in ``--work``; the walk of the tree is replaced by the
store's own paths, sizes and times (a tree of 10^6 files would cost the same walk to old and
new), of which ``--files`` per round are changed: each points at the real part the synthetic
entry was made from (``synthetic/NNNNNNN-PATH`` -> ``SOURCE_ROOT/PATH``, ``--parts``) with a
new modification time, so the build hashes and signs it for real. Reported: the whole wall
time, the writer's opening (lock, damage check, journal) and the plan, medians over the
rounds after a first, untimed one per copy (its figures are printed apart: the new code
verifies a copied main file whole once, as it would any file it has not verified).

All print a Markdown table and the load average before and after.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def _entries(store: Path) -> int:
    from shapeidx.store import open_store

    with open_store(store) as reader:
        return len(reader)


def bench_query(part: Path, stores: list, repeat: int, top: int) -> None:
    command = [sys.executable, "-m", "shapeidx.cli"]
    if not Path(sys.executable).with_name("shapeidx").exists():
        raise SystemExit("run with the venv's python (its shapeidx command is used)")
    command = [str(Path(sys.executable).with_name("shapeidx"))]
    times = {store: [] for store in stores}
    print(f"load average before: {_load()}", flush=True)
    for round_ in range(repeat + 1):
        for store in stores:
            started = time.perf_counter()
            run = subprocess.run([*command, "query", str(part), "--store", str(store), "--top", str(top)],
                                 capture_output=True, text=True)
            elapsed = time.perf_counter() - started
            if run.returncode:
                raise SystemExit(f"{store}: {run.stderr.strip()}")
            if round_:  # round 0 warms the page cache
                times[store].append(elapsed)
    print(f"load average after: {_load()}\n")
    print("| store | entries | layout | whole command, median of %d (s) | min-max (s) | / first store |" % repeat)
    print("|---|---|---|---|---|---|")
    base = statistics.median(times[stores[0]])
    for store in stores:
        import h5py

        with h5py.File(store, "r") as f:
            layout = int(f.attrs["schema_version"])
        median = statistics.median(times[store])
        print(f"| {store.name} | {_entries(store):,} | {layout} | {median:.2f} | {min(times[store]):.2f}-{max(times[store]):.2f}"
              f" | {median / base:.2f} |")


def bench_commit(stores: list, files: int, rounds: int, full: bool = False) -> None:
    from shapeidx.store import Batch, Entry, StoreWriter, open_store
    from shapeidx.store.files import batch_files

    print(f"load average before: {_load()}", flush=True)
    rows = []
    for store in stores:
        with open_store(store) as reader:
            params, root, n = reader.params, reader.attrs["root"], len(reader)
            rng = np.random.default_rng(len(reader))
            picks = rng.choice(n, files * rounds, replace=False)
            donors = rng.choice(n, files * rounds, replace=False)
            paths = reader.paths[picks]  # reading every path: this script's own cost, not timed
            signatures = [reader.signature(int(i)) for i in donors]
        started = time.perf_counter()
        writer = StoreWriter(store, params, root)
        opened = time.perf_counter() - started
        commits, merges = [], []
        with writer:
            for r in range(rounds):
                entries = [Entry(path=str(paths[r * files + k]), hash=f"{r:032x}{k:032x}", size=1, mtime_ns=r + 1,
                                 triangles=12, area=1.0, watertight=True,
                                 fractions=tuple(s.fractions[c] for c in ("in", "out", "mixed")),
                                 histograms=dict(s.histograms))
                           for k, s in enumerate(signatures[r * files:(r + 1) * files])]
                t0 = time.perf_counter()
                writer.commit(Batch(entries=entries))
                t1 = time.perf_counter()
                writer.merge() if full else writer.compact()  # --full: what every merge did before layout 3
                t2 = time.perf_counter()
                commits.append(t1 - t0)
                merges.append(t2 - t1)
        with open_store(store) as reader:
            segments = [len(s) for s in reader._sources[1:]]
        rows.append((store, n, opened, commits, merges, segments, len(batch_files(store))))
    print(f"load average after: {_load()}\n")
    print(f"| store | entries | commit of {files} files, median / max (s) | merge after it, median / max (s) |"
          f" journal segments after {rounds} rounds (entries) | writer open (s) |")
    print("|---|---|---|---|---|---|")
    for store, n, opened, commits, merges, segments, _ in rows:
        print(f"| {store.name} | {n:,} | {statistics.median(commits):.3f} / {max(commits):.3f} |"
              f" {statistics.median(merges):.3f} / {max(merges):.3f} | {len(segments)} ({', '.join(map(str, segments))}) |"
              f" {opened:.1f} |")


class _Chunk:
    """Entries ``rows`` of a store, as much of a FamilyTable as :func:`embed` reads."""

    def __init__(self, reader, rows, histograms, fractions, means):
        from shapeidx.families.table import RaggedHistograms

        self.histograms = {h: RaggedHistograms.from_counts(*reader.counts(h, rows)) for h in histograms}
        self.fractions, self.means, self.rows = fractions[rows], means[rows], rows

    def __len__(self) -> int:
        return len(self.rows)


def store_embedding(reader, metric: str, chunk: int = 50_000) -> np.ndarray:
    """The candidate embedding of every entry of a merged store of ok entries, chunk by chunk
    (the vectors :func:`shapeidx.store.candidates.embed` makes of the whole store at once: each
    entry's vector is its own, so chunks give the same ones)."""
    from shapeidx.distance import METRIC_HISTOGRAMS
    from shapeidx.signing.parameters import HISTOGRAMS
    from shapeidx.store.candidates import embed

    histograms = METRIC_HISTOGRAMS[metric] if metric not in ("combined", "combined-angle") else HISTOGRAMS
    fractions = reader.column("entries/fractions")
    means = np.stack([reader.column(f"histograms/{h}/mean") for h in HISTOGRAMS], axis=1)
    parts = [embed(_Chunk(reader, np.arange(lo, min(lo + chunk, len(reader))), histograms, fractions, means), metric)
             for lo in range(0, len(reader), chunk)]
    return np.concatenate(parts)


def bench_recall(store: Path, queries: int, top: int, metric: str, embedding: str | None = None,
                 overfetch: int | None = None) -> None:
    """The pruned query's top ``top`` against the full exact ranking of every entry, for
    ``queries`` entries of the store as queries: recall, equal distances, time of each."""
    from shapeidx.search.distances import distances, nearest
    from shapeidx.store import open_store
    from shapeidx.store.ranked import ranked_view

    print(f"load average before: {_load()}", flush=True)
    found = total = 0
    same = True
    pruned_s, full_s, exact_n = [], [], []
    faiss_found, faiss_s = 0, []
    with open_store(store) as reader:
        view = ranked_view(reader)
        index = None
        if embedding:
            from shapeidx.store.candidates import OVERFETCH, CandidateIndex

            OVERFETCH = overfetch or OVERFETCH  # noqa: N806  (candidates per neighbour wanted)

            if len(reader._sources) != 1 or len(view) != len(reader):
                raise SystemExit(f"{store}: --embedding needs a merged store of ok entries (view positions = rows)")
            t0 = time.perf_counter()
            vectors = store_embedding(reader, metric)
            t1 = time.perf_counter()
            index = CandidateIndex(vectors, embedding)
            t2 = time.perf_counter()
            print(f"# embedding of {len(vectors):,} entries ({vectors.shape[1]} dimensions): {t1 - t0:.1f} s;"
                  f" {embedding} index built in {t2 - t1:.1f} s (load {_load()})", flush=True)
        rng = np.random.default_rng(11)
        for position in rng.choice(len(view), queries, replace=False).tolist():
            signature = view.signature(view.locate(position), reader.params)
            t0 = time.perf_counter()
            chosen, exact = nearest(view, signature, metric, top)
            t1 = time.perf_counter()
            everything = distances(view, signature, metric)
            t2 = time.perf_counter()
            best = set(np.argsort(everything, kind="stable")[:top].tolist())
            mine = set(chosen[np.argsort(exact, kind="stable")[:top]].tolist())
            found += len(best & mine)
            total += top
            same &= bool(np.array_equal(everything[chosen], exact))
            pruned_s.append(t1 - t0)
            full_s.append(t2 - t1)
            exact_n.append(len(chosen))
            if index is not None:  # the embedding's candidates, each given its exact distance
                t3 = time.perf_counter()
                _, proposed = index.search(index.vectors[position : position + 1], OVERFETCH * top)
                proposed = proposed[0][proposed[0] >= 0]
                exact_proposed = distances(view, signature, metric, proposed)
                faiss_s.append(time.perf_counter() - t3)
                faiss_found += len(best & set(proposed[np.argsort(exact_proposed, kind="stable")[:top]].tolist()))
    print(f"load average after: {_load()}\n")
    if index is not None:
        print(f"| store | entries | queries | embedding ({index.method}) + exact re-ranking of {OVERFETCH * top}: recall@{top} |"
              " its time per query, median (s) |")
        print("|---|---|---|---|---|")
        print(f"| {store.name} | {len(view):,} | {queries} | {faiss_found / total:.4f} | {statistics.median(faiss_s):.3f} |\n")
    print(f"| store | entries | queries | recall@{top} | distances equal | pruned ranking, median (s) |"
          " full exact ranking, median (s) | exact distances computed, median |")
    print("|---|---|---|---|---|---|---|---|")
    print(f"| {store.name} | {len(view):,} | {queries} | {found / total:.4f} | {'yes' if same else 'NO'} |"
          f" {statistics.median(pruned_s):.2f} | {statistics.median(full_s):.2f} | {int(statistics.median(exact_n)):,} |")


def _walk_file(store: Path, work: Path, parts: Path) -> Path:
    """The store's paths, sizes and times (what the walk would find), pickled once per store."""
    import pickle

    out = work / f"{store.stem}.walk.pkl"
    if not out.exists():
        from shapeidx.store import open_store

        with open_store(store) as reader:
            listing = (list(reader.paths), reader.column("entries/size").tolist(),
                       reader.column("entries/mtime_ns").tolist())
        sources = [str(parts / p.split("-", 1)[1]) for p in listing[0]]
        out.write_bytes(pickle.dumps((*listing, sources)))
    return out


def build_once(store: Path, tree: Path, walk_file: Path, round_: int, files: int) -> None:
    """One build (run in a fresh process by ``build``): prints its timings as JSON."""
    import json
    import pickle

    started = time.perf_counter()
    import shapeidx
    import shapeidx.index.build as build
    from shapeidx.index.progress import BuildReporter
    from shapeidx.index.walk import FoundFile, Walk

    paths, sizes, mtimes, sources = pickle.loads(walk_file.read_bytes())
    rng = np.random.default_rng(len(paths))
    picks = rng.permutation(len(paths))[: files * (round_ + 1)]  # rounds 0..r: each changes its own files
    absolute = [str(tree / p) for p in paths]
    for k in picks.tolist():
        absolute[k], mtimes[k] = sources[k], mtimes[k] + 1
    walk = Walk(files=[FoundFile(p, a, s, m) for p, a, s, m in zip(paths, absolute, sizes, mtimes)])
    del paths, absolute, sizes, mtimes, sources
    build.walk_parts = lambda root, follow_outside_links=False: walk
    timed = {}

    def timing(name, fn):
        def wrapper(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                timed[name] = time.perf_counter() - t0
        return wrapper

    original_init = build.StoreWriter.__init__
    build.StoreWriter.__init__ = timing("writer_open", original_init)
    build.make_plan = timing("plan", build.make_plan)
    ready = time.perf_counter()
    summary = build.run_build(tree, store, build.BuildOptions(), BuildReporter(quiet=True))
    timed.update(setup=ready - started, build=time.perf_counter() - ready, indexed=summary.indexed,
                 unchanged=summary.unchanged, code=str(Path(shapeidx.__file__).parent))
    print(json.dumps(timed))


def bench_build(stores: list, old_code: Path, work: Path, files: int, rounds: int, parts: Path) -> None:
    import json
    import shutil

    import h5py

    work.mkdir(parents=True, exist_ok=True)
    versions = {"old": str(old_code.resolve()), "new": str(Path(__file__).resolve().parents[1])}
    copies = {}
    for store in stores:
        walk_file = _walk_file(store, work, parts)
        for version in versions:
            copy, tree = work / f"{version}-{store.name}", work / f"tree-{store.stem}"
            tree.mkdir(exist_ok=True)
            for leftover in work.glob(f"{version}-{store.name}*"):
                shutil.rmtree(leftover) if leftover.is_dir() else leftover.unlink()
            shutil.copyfile(store, copy)
            with h5py.File(copy, "r+") as f:  # the copy indexes the bench's own (empty) folder
                f.attrs["root"] = str(tree.resolve())
            copies[store, version] = (copy, tree.resolve(), walk_file)
    print(f"load average before: {_load()}", flush=True)
    results = {key: [] for key in copies}
    for round_ in range(rounds + 1):
        for key, (copy, tree, walk_file) in copies.items():
            env = {**os.environ, "PYTHONPATH": versions[key[1]]}
            t0 = time.perf_counter()
            run = subprocess.run([sys.executable, __file__, "build-once", str(copy), str(tree), str(walk_file),
                                  str(round_), str(files)], capture_output=True, text=True, env=env)
            wall = time.perf_counter() - t0
            if run.returncode:
                raise SystemExit(f"{copy}: {run.stderr.strip()[-2000:]}")
            timed = json.loads(run.stdout.strip().splitlines()[-1])
            if not timed["code"].startswith(versions[key[1]]):
                raise SystemExit(f"{key[1]} ran the shapeidx at {timed['code']}, not {versions[key[1]]}")
            if timed["indexed"] != files:
                raise SystemExit(f"{copy}: round {round_} indexed {timed['indexed']} files, not {files}")
            timed["wall"] = wall
            results[key].append(timed)
            print(f"# round {round_} {key[1]} {key[0].name}: wall {wall:.2f} s, writer open {timed['writer_open']:.2f} s,"
                  f" plan {timed['plan']:.2f} s (load {_load()})", flush=True)
    print(f"load average after: {_load()}\n")
    print(f"| store | entries | code | whole build of {files} changed files, median of {rounds} (s) | writer open (s) |"
          " plan (s) | first build after the copy: whole / writer open (s) |")
    print("|---|---|---|---|---|---|---|")
    for (store, version), runs in results.items():
        later = runs[1:]
        print(f"| {store.name} | {_entries(store):,} | {version} | {statistics.median(r['wall'] for r in later):.2f} |"
              f" {statistics.median(r['writer_open'] for r in later):.2f} | {statistics.median(r['plan'] for r in later):.2f} |"
              f" {runs[0]['wall']:.2f} / {runs[0]['writer_open']:.2f} |")
    for key, (copy, _, _) in copies.items():
        for leftover in work.glob(f"{copy.name}*"):
            shutil.rmtree(leftover) if leftover.is_dir() else leftover.unlink()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    q = sub.add_parser("query")
    q.add_argument("part", type=Path)
    q.add_argument("stores", type=Path, nargs="+")
    q.add_argument("--repeat", type=int, default=5)
    q.add_argument("--top", type=int, default=10)
    c = sub.add_parser("commit")
    c.add_argument("stores", type=Path, nargs="+")
    c.add_argument("--files", type=int, default=100)
    c.add_argument("--rounds", type=int, default=10)
    c.add_argument("--full", action="store_true", help="merge everything into the main file after each commit"
                   " (the merge of layout 2), for comparison")
    r = sub.add_parser("recall")
    r.add_argument("store", type=Path)
    r.add_argument("--queries", type=int, default=10)
    r.add_argument("--top", type=int, default=10)
    r.add_argument("--metric", default="weighted")
    r.add_argument("--overfetch", type=int, help="embedding candidates per neighbour wanted (default: OVERFETCH, 3)")
    r.add_argument("--embedding", choices=("exact", "hnsw"), help="also the candidate embedding's recall"
                   " (shapeidx.store.candidates: FAISS flat or HNSW, then the exact distance of its candidates)")
    b = sub.add_parser("build")
    b.add_argument("stores", type=Path, nargs="+")
    b.add_argument("--old-code", type=Path, required=True, help="a folder holding an older shapeidx/ package")
    b.add_argument("--work", type=Path, required=True, help="where the store copies go (removed after)")
    b.add_argument("--files", type=int, default=100)
    b.add_argument("--rounds", type=int, default=3)
    b.add_argument("--parts", type=Path, default=Path("/work/shared/data/kicad6"),
                   help="the root of the real store the synthetic stores were made from")
    once = sub.add_parser("build-once")
    for name in ("store", "tree", "walk_file"):
        once.add_argument(name, type=Path)
    once.add_argument("round", type=int)
    once.add_argument("files", type=int)
    args = parser.parse_args()
    if args.what == "build-once":
        build_once(args.store, args.tree, args.walk_file, args.round, args.files)
        return 0
    print(f"machine: {os.uname().machine}, {os.cpu_count()} cores, {os.uname().sysname} {os.uname().release},"
          f" Python {sys.version.split()[0]}, numpy {np.__version__}")
    if args.what == "query":
        bench_query(args.part, args.stores, args.repeat, args.top)
    elif args.what == "recall":
        bench_recall(args.store, args.queries, args.top, args.metric, args.embedding, args.overfetch)
    elif args.what == "build":
        bench_build(args.stores, args.old_code, args.work, args.files, args.rounds, args.parts)
    else:
        bench_commit(args.stores, args.files, args.rounds, args.full)
    return 0


if __name__ == "__main__":
    sys.exit(main())
