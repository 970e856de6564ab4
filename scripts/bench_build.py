#!/usr/bin/env python3
"""Build throughput on the full KiCad 6 library: parts per second, peak memory, and the floor.

Usage::

    python scripts/bench_build.py [--cache DIR] [--subset N] [--seed S] [--workers 2] [--scheduler ADDRESS] [--floor-jobs J]

The library is Debian's ``kicad-packages3d`` (6,227 VRML models of KiCad 6): fetched once
with ``apt-get download kicad-packages3d`` into ``--cache`` and unpacked there with
``dpkg-deb`` (only the ``.wrl`` files are kept; the STEP files of the package are not
used). ``--subset N`` builds a random subset of N of them (hard links in the cache), for a
machine that is busy. Not part of the tests: it takes minutes.

Measured, in one run on one machine:

* ``wall``: the whole ``shapeidx build TREE --workers W`` command at the default 1024 points,
  into a new store (a real process, as a user runs it), and the parts per second it makes;
* peak memory: the largest resident set of the build's processes together (sampled every
  0.1 s), and of any one of them (the kernel's high-water mark);
* the floor: for every part the build indexed, the bare Embree occlusion query over the
  same number of segments between its sample points (``scripts/bench.py``'s
  ``bare_query``: one thread, BVH built outside the timing), summed over the parts and
  divided by the workers. ``wall / floor`` is the ratio the issue asks to keep at most 1.2;
* the same ratio in CPU time: the CPU seconds of the build's processes together over the
  floor's CPU seconds. On a machine that other work shares, wall times stretch with the
  load; this one does much less;
* where the per-file work goes: each built part hashed, loaded, made a solid, signed and
  measured (the facts an entry keeps beside its signature) again on one thread, in CPU
  seconds over the floor's CPU seconds (what the build would cost with no overhead of its
  own); ``--floor-only`` leaves this out, ``--floor-jobs J`` shares it (and the floor)
  among J processes;
* whether the per-file passes slow each other down when they run at once (``--concurrent N``):
  the same N parts' stages timed in one process alone, then in ``--workers`` processes at
  once, each over all N (started together); each stage's CPU at once over its CPU alone.
  A build's workers whose stages cost more than the floor's own measure while this stays near
  1.0 are slowed by something else than the passes' memory traffic (the machine, the build);
* the CPU time the hypervisor took from this machine (``steal`` in ``/proc/stat``) during the
  build and during the floor: on a shared virtual machine it is charged to nobody's process,
  yet stretches every wall time.

With ``--scheduler`` the build runs on that Dask cluster (``--workers`` is then only the
floor's divisor: give the cluster's thread count; the memory and CPU figures are then those of
the build's machine only, not of the workers).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shlex
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import bench  # noqa: E402  (this folder is on sys.path when run as a script)
from _common import REPO, machine  # noqa: E402

PACKAGE = "kicad-packages3d"
TARGET = 1.2


def library(cache: Path) -> Path:
    """The unpacked VRML models of the package under ``cache`` (fetched and unpacked once)."""
    models = cache / "usr" / "share" / "kicad" / "3dmodels"
    if models.is_dir():
        return models
    cache.mkdir(parents=True, exist_ok=True)
    debs = sorted(cache.glob(f"{PACKAGE}_*.deb"))
    if not debs:
        print(f"fetching {PACKAGE} with apt-get download into {cache} ...", flush=True)
        subprocess.run(["apt-get", "download", PACKAGE], cwd=cache, check=True)
        debs = sorted(cache.glob(f"{PACKAGE}_*.deb"))
    print(f"unpacking the VRML models of {debs[-1].name} ...", flush=True)
    tar = subprocess.Popen(["dpkg-deb", "--fsys-tarfile", str(debs[-1])], stdout=subprocess.PIPE)
    subprocess.run(["tar", "-x", "-C", str(cache), "--wildcards", "*.wrl"], stdin=tar.stdout, check=True)
    if tar.wait() != 0:
        raise SystemExit(f"dpkg-deb could not unpack {debs[-1]}")
    return models


def subset_tree(models: Path, cache: Path, n: int | None, seed: int) -> Path:
    """A tree of ``n`` models picked at random, or of all of them (hard links, same relative paths).

    Only the VRML models: a cache unpacked by hand may also hold the package's STEP files,
    which a build of the models' folder would index too (twice the files, a third of the
    time spent in OpenCASCADE), measuring something else than the floor's VRML parts.
    """
    files = sorted(p.relative_to(models) for p in models.rglob("*.wrl"))
    picked = files if n is None else random.Random(seed).sample(files, min(n, len(files)))
    tree = cache / ("vrml-only" if n is None else f"subset-{n}-seed{seed}")
    for rel in picked:
        target = tree / rel
        if not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            os.link(models / rel, target)
    return tree


def _tree_rss(root: int) -> int:
    """Resident bytes of ``root`` and all its descendants now."""
    parents, rss = {}, {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        parents[int(entry.name)] = int(fields[1])
        rss[int(entry.name)] = int(fields[21]) * os.sysconf("SC_PAGE_SIZE")
    members, frontier = {root}, [root]
    while frontier:
        pid = frontier.pop()
        children = [child for child, parent in parents.items() if parent == pid]
        members.update(children)
        frontier.extend(children)
    return sum(rss.get(pid, 0) for pid in members)


def timed_build(tree: Path, store: Path, workers: int, scheduler: str | None) -> dict:
    """Run ``shapeidx build`` as a process; wall time, its JSON record, peak memory."""
    command = [sys.executable, "-m", "shapeidx.cli", "build", str(tree), "--store", str(store), "--json", "-q"]
    command += ["--scheduler", scheduler] if scheduler else ["--workers", str(workers)]
    import resource

    peak = [0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    done = threading.Event()

    loads = []  # the 1-minute load average, once a second

    def sample():
        ticks = 0
        while not done.is_set():
            peak[0] = max(peak[0], _tree_rss(proc.pid))
            if ticks % 10 == 0:
                loads.append(os.getloadavg()[0])
            ticks += 1
            done.wait(0.1)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    out, err = proc.communicate()
    wall = time.perf_counter() - started
    done.set()
    sampler.join()
    if proc.returncode != 0:
        raise SystemExit(f"the build failed: {err.strip()[-800:]}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    largest = after.ru_maxrss * 1024  # kB on Linux
    return {"wall": wall, "cpu": cpu, "record": json.loads(out), "peak_total": peak[0], "peak_process": largest,
            "command": shlex.join(command), "loads": loads}


def floor_seconds(tree: Path, store: Path, points: int, jobs: int = 1, stages: bool = True) -> dict:
    """The floor, and where a part's time goes, over every ok entry's part, on one thread.

    Returns the bare Embree query's summed wall and CPU seconds, the part count, and the
    summed CPU seconds of each stage of the build's own per-file work (hash, load, solid,
    signature, and the facts an entry keeps beside it: what ``index_file`` does), so ``stages / bare`` says how far above the floor
    the per-file work is by itself, whatever runs it.

    ``jobs > 1`` shares the parts among that many processes, each timing its parts on one
    thread as above (every figure is a sum of per-part, per-process times), so that the
    whole library's floor takes a fraction of the time on as many cores. ``stages=False``
    times only the floor (each part is still loaded and made a solid, untimed).
    """
    from shapeidx.store import STATUS_OK, open_store

    with open_store(store) as reader:
        paths = list(reader.paths[reader.column("entries/status") == STATUS_OK])
    if jobs <= 1:
        return _floor_of(tree, paths, points, stages)
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    shares = [paths[k::jobs] for k in range(jobs)]
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        parts = list(pool.map(_floor_of, [tree] * jobs, shares, [points] * jobs, [stages] * jobs))
    return {key: sum(part[key] for part in parts) for key in parts[0]}


def _floor_of(tree: Path, paths: list, points: int, stages: bool = True) -> dict:
    """:func:`floor_seconds` over these paths, in this process."""
    import hashlib

    from shapeidx.io import load
    from shapeidx.signing.moments import shape_facts
    from shapeidx.signing.pipeline import signature_of_solid
    from shapeidx.signing.solid import make_solid
    from shapeidx.system import keep_freed_memory

    keep_freed_memory()  # as the build's workers do
    found = {"bare": 0.0, "bare_cpu": 0.0, "hash": 0.0, "load": 0.0, "solid": 0.0, "signature": 0.0, "facts": 0.0,
             "parts": len(paths)}
    clock = time.process_time  # CPU of every thread (Embree builds its BVH on several)

    def timed(stage, fn):
        started = clock()
        result = fn()
        found[stage] += clock() - started
        return result

    for k, rel in enumerate(paths):
        path = tree / rel
        timed("hash", lambda: hashlib.sha256(path.read_bytes()).hexdigest())
        polygons = timed("load", lambda: load(path))
        solid = timed("solid", lambda: make_solid(polygons, path))
        if stages:
            timed("signature", lambda: signature_of_solid(solid, points))
            timed("facts", lambda: (solid.describe(), shape_facts(solid.vertices, solid.faces)))  # the entry's other facts
        query = bare_query_of(solid, points)
        started, started_cpu = time.perf_counter(), clock()
        query()
        found["bare"] += time.perf_counter() - started
        found["bare_cpu"] += clock() - started_cpu
        if (k + 1) % 500 == 0:
            print(f"  floor: {k + 1}/{len(paths)} parts, {found['bare']:.1f} s so far", flush=True)
    return found


def concurrent_stages(tree: Path, store: Path, points: int, parts: int, jobs: int) -> tuple[dict, list[dict]]:
    """The stages of the same ``parts`` parts (a fixed random sample of the ok entries) timed
    in one process alone, then in ``jobs`` processes at once, each over all of them."""
    import multiprocessing

    from shapeidx.store import STATUS_OK, open_store

    with open_store(store) as reader:
        paths = list(reader.paths[reader.column("entries/status") == STATUS_OK])
    sample = random.Random(0).sample(paths, min(parts, len(paths)))
    context = multiprocessing.get_context("spawn")
    runs = []
    for count in (1, jobs):
        results, start = context.Queue(), context.Barrier(count)
        processes = [context.Process(target=_floor_at_once, args=(tree, sample, points, start, results))
                     for _ in range(count)]
        for process in processes:
            process.start()
        runs.append([results.get() for _ in processes])
        for process in processes:
            process.join()
    return runs[0][0], runs[1]


def _floor_at_once(tree: Path, paths: list, points: int, start, results) -> None:
    """:func:`_floor_of` in a process of its own, started when every process of its run has
    imported what it needs; its figures go to ``results``."""
    from shapeidx.signing import pipeline  # noqa: F401 (the imports outside the timing)

    start.wait()
    results.put(_floor_of(tree, paths, points))


def steal_ticks() -> int:
    """The CPU ticks the hypervisor took from this machine so far (0 where unknown)."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
        return int(fields[8])
    except (OSError, IndexError, ValueError):
        return 0


def bare_query_of(solid, points: int):
    return bench.bare_query(solid, points)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cache", type=Path, default=REPO / ".bench-cache" / PACKAGE,
                        help="where the package is fetched and unpacked")
    parser.add_argument("--subset", type=int, help="build a random subset of this many models")
    parser.add_argument("--seed", type=int, default=1, help="of the subset")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--scheduler", help="build on this Dask cluster")
    parser.add_argument("--work", type=Path, default=REPO / ".bench-cache", help="where the store is written")
    parser.add_argument("--floor-only", action="store_true",
                        help="after the build, time only the floor, not the per-file stages (half the time)")
    parser.add_argument("--floor-jobs", type=int, default=1,
                        help="processes that time the floor and the stages after the build (each on one thread)")
    parser.add_argument("--concurrent", type=int, default=0, metavar="N",
                        help="time N parts' stages alone, then in --workers processes at once (0: not)")
    args = parser.parse_args()
    print(f"machine: {machine()}")
    print(f"command: {shlex.join([sys.executable, *sys.argv])}")
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    models = library(args.cache.resolve())
    vrml_only = all(p.suffix == ".wrl" for p in models.rglob("*") if p.is_file())
    tree = (subset_tree(models, args.cache.resolve(), args.subset, args.seed) if args.subset
            else models if vrml_only else subset_tree(models, args.cache.resolve(), None, args.seed))
    files = sum(1 for _ in tree.rglob("*.wrl"))
    print(f"tree: {tree} ({files} VRML models{', a random subset' if args.subset else ''})")
    args.work.mkdir(parents=True, exist_ok=True)
    store = args.work / f"bench-build-{os.getpid()}.shapeidx"
    try:
        steal_started = steal_ticks()
        build = timed_build(tree, store, args.workers, args.scheduler)
        steal_build = steal_ticks() - steal_started
        record = build["record"]
        print(f"build: {build['command']}")
        print(f"  {record['indexed']} indexed, {record['failed']} failed in {build['wall']:.1f} s:"
              f" {record['indexed'] / build['wall']:.1f} parts/s")
        print(f"  peak memory: {build['peak_total'] / 2**20:.0f} MiB all processes together,"
              f" {build['peak_process'] / 2**20:.0f} MiB the largest one")
        loads = build["loads"] or [float("nan")]
        print(f"load average during the build (1-minute, sampled every second): mean {sum(loads) / len(loads):.2f},"
              f" max {max(loads):.2f}")
        print(f"load average after the build: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
        steal_started = steal_ticks()
        found = floor_seconds(tree, store, 1024, args.floor_jobs, not args.floor_only)
        steal_floor = steal_ticks() - steal_started
        print(f"load average after the floor: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
        floor, floor_cpu, parts = found["bare"], found["bare_cpu"], found["parts"]
        ratio = build["wall"] / (floor / args.workers)
        print(f"floor: bare Embree occlusion {floor:.1f} s ({floor_cpu:.1f} s CPU) over {parts} parts on one thread,"
              f" / {args.workers} = {floor / args.workers:.1f} s")
        print(f"wall / floor: {ratio:.2f} (target at most {TARGET}){'' if ratio <= TARGET else ' OVER TARGET'}")
        print(f"CPU / floor CPU: {build['cpu']:.1f} s / {floor_cpu:.1f} s = {build['cpu'] / floor_cpu:.2f}"
              f" (the build's processes together)")
        tick = os.sysconf("SC_CLK_TCK")
        print(f"CPU taken by the hypervisor (steal): {steal_build / tick:.1f} s during the build,"
              f" {steal_floor / tick:.1f} s during the floor")
        stages = ("hash", "load", "solid", "signature", "facts")
        if not args.floor_only:
            where = "on one thread" if args.floor_jobs <= 1 else f"on one thread in each of {args.floor_jobs} processes at once"
            print(f"per-file work {where}, CPU over the floor's CPU: "
                  + ", ".join(f"{stage} {found[stage] / floor_cpu:.2f}" for stage in stages)
                  + f"; together {sum(found[stage] for stage in stages) / floor_cpu:.2f}")
        profile = record.get("profile")
        if profile:
            cpu = profile["cpu_seconds"]
            print("the build's CPU by process and stage (build --json's profile), over the floor's CPU:")
            print("  parent: " + ", ".join(f"{k} {v / floor_cpu:.3f}" for k, v in cpu["parent"].items())
                  + f"; together {cpu['parent_total'] / floor_cpu:.3f}")
            if cpu["workers_total"] is not None:
                print("  workers: " + ", ".join(f"{k} {v / floor_cpu:.3f}" for k, v in cpu["workers"].items())
                      + f"; together {cpu['workers_total'] / floor_cpu:.3f} ({profile['workers_started']} processes started)")
        if args.concurrent:
            alone, together = concurrent_stages(tree, store, 1024, args.concurrent, args.workers)
            print(f"the same {alone['parts']} parts' stages in {args.workers} processes at once, CPU over their CPU alone"
                  f" (alone: {sum(alone[s] for s in stages):.1f} s):")
            for k, at_once in enumerate(together):
                print(f"  process {k + 1}: " + ", ".join(f"{s} {at_once[s] / max(alone[s], 1e-9):.2f}" for s in (*stages, "bare"))
                      + f"; together {sum(at_once[s] for s in stages) / sum(alone[s] for s in stages):.2f}")
        print(f"load average at the end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    finally:
        shutil.rmtree(store, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
