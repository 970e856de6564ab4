"""Check issue 15's promises against the installed ``shapeidx`` command, as a user would.

Runs every item (scripts, cron, the store, the walk, option values, environment errors)
with real processes on real parts copied from the shared data into a scratch folder, and
prints PASS or FAIL per item with what was seen. Exit status 0 when every item passes.

    python scripts/check_cli.py                       # the shapeidx beside this Python, else on PATH
    python scripts/check_cli.py --command /usr/local/bin/shapeidx --data ../shared/data
    python scripts/check_cli.py --only pipe,store     # items whose name contains a word

Items that need root (a read-only bind mount, an unreadable file for a non-root user) run
as root and otherwise report SKIP.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import re
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ITEMS = []
LOG_LINE = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d[+-]\d{4} shapeidx build: ")
BROKEN = "mesh-wild/openscad-testdata/testdata/stl/unparseable.stl"
BYTES_REASON = "mesh-wild/openscad-testdata/testdata/stl/invalidvertex.stl"
CUBE = "mesh-wild/trimesh-models/unit_cube.STL"


class Skip(Exception):
    pass


def item(name):
    def register(function):
        ITEMS.append((name, function))
        return function

    return register


class Workspace:
    """A scratch folder with a tree of real parts and its store, built once."""

    def __init__(self, command: list[str], data: Path, scratch: Path):
        self.command, self.data, self.dir = command, data, scratch
        self.tree = scratch / "parts"
        for folder in ("LED_SMD", "Diode_SMD"):
            shutil.copytree(data / "kicad6" / folder, self.tree / folder)
        for path in [self.tree, *self.tree.rglob("*")]:
            path.chmod(path.stat().st_mode | 0o200)
        self.store = scratch / "parts.shapeidx"
        built = self.run("build", self.tree, "--store", self.store, "--points", "128", "-q")
        if built.returncode:
            raise SystemExit(f"cannot build the workspace's store: {built.stderr}")
        self.part = sorted((self.tree / "LED_SMD").iterdir())[0]

    def run(self, *args, input=None, cwd=None, env=None, timeout=600, **kwargs):
        return subprocess.run([*self.command, *map(str, args)], capture_output=True, text=input is None or
                              isinstance(input, str), input=input, cwd=cwd, timeout=timeout,
                              env={**os.environ, **(env or {})}, **kwargs)

    def fresh_tree(self, name: str, folders=("LED_SMD",)) -> Path:
        target = self.dir / name
        for folder in folders:
            shutil.copytree(self.tree / folder, target / folder)
        return target


def one_line_error(proc, status: int, name: str) -> tuple[bool, str]:
    lines = proc.stderr.strip().splitlines()
    ok = proc.returncode == status and len(lines) == 1 and name in lines[0] and "Traceback" not in proc.stderr
    return ok, f"status {proc.returncode}, stderr {proc.stderr.strip()[:160]!r}"


# ---------------------------------------------------------------------------------- scripts

@item("pipe: query | head -1 ends quietly with status 0")
def _(w):
    proc = subprocess.run(f"{' '.join(w.command)} query {w.tree} --store {w.store} --top 20 | head -1;"
                          " echo \"status=${PIPESTATUS[0]}\"", shell=True, executable="/bin/bash",
                          capture_output=True, text=True, timeout=600)
    return proc.stdout.strip().endswith("status=0") and proc.stderr == "", f"{proc.stdout[-40:]!r} {proc.stderr[:120]!r}"


@item("paths: hits are absolute paths that open from another directory")
def _(w):
    proc = w.run("query", w.part, "--store", w.store, "--top", "3", cwd="/")
    paths = [line.split()[-1] for line in proc.stdout.splitlines()]
    return proc.returncode == 0 and len(paths) == 3 and all(Path(p).is_absolute() and Path(p).is_file() for p in paths), paths


@item("paths: JSON carries path, relative_path and the store's root")
def _(w):
    data = json.loads(w.run("query", w.part, "--store", w.store, "--top", "2", "--json").stdout)
    hit = data["hits"][0]
    ok = {"query", "metric", "store", "root", "hits"} <= data.keys() and Path(data["root"], hit["relative_path"]) == Path(hit["path"])
    return ok, {k: data[k] for k in ("metric", "root")} | {"hit": hit}


@item("paths: --id takes a relative entry, an absolute path, a path from here")
def _(w):
    rel = w.part.relative_to(w.tree).as_posix()
    answers = [w.run("query", "--id", given, "--store", w.store.resolve(), "--top", "3", "--json", cwd=cwd)
               for given, cwd in ((rel, None), (w.part.resolve(), None), (w.part.name, w.part.parent))]
    hits = [json.loads(a.stdout)["hits"] if a.returncode == 0 else a.stderr for a in answers]
    return hits[0] == hits[1] == hits[2], [str(h)[:80] for h in hits]


@item("query: several files, a directory and '-' give one block per query")
def _(w):
    parts = sorted((w.tree / "Diode_SMD").iterdir())[:2]
    several = json.loads(w.run("query", *parts, "--store", w.store, "--top", "1", "--json").stdout)
    folder = json.loads(w.run("query", w.tree / "LED_SMD", "--store", w.store, "--top", "1", "--json").stdout)
    stdin = w.run("query", "-", "--type", "vrml", "--store", w.store, "--top", "1", "--json", input=w.part.read_bytes())
    piped = json.loads(stdin.stdout)
    table = w.run("query", *parts, "--store", w.store, "--top", "2").stdout
    ok = (len(several) == 2 and len(folder) == 10 and piped["query"] == "-" and piped["hits"][0]["distance"] == 0.0
          and table.count("\nquery ") + table.startswith("query ") == 2)
    return ok, f"{len(several)} blocks, {len(folder)} for the folder, stdin hit {piped['hits'][0]['relative_path']}"


@item("formats: table, csv, tsv, json, jsonl on query, compare, stats, check")
def _(w):
    seen = {}
    cube = w.data / CUBE
    for args in (("query", w.part, "--store", w.store, "--top", "3"), ("compare", cube, cube, "--points", "64"),
                 ("stats", "--store", w.store), ("check", "--store", w.store)):
        for fmt in ("table", "csv", "tsv", "json", "jsonl"):
            proc = w.run(*args, "--format", fmt)
            text = proc.stdout
            try:
                if fmt == "csv":
                    list(csv.reader(io.StringIO(text)))
                elif fmt == "tsv":
                    assert all("\t" in line for line in text.splitlines()[:1])
                elif fmt == "json":
                    json.loads(text)
                elif fmt == "jsonl":
                    [json.loads(line) for line in text.splitlines()]
                seen[(args[0], fmt)] = proc.returncode == 0
            except (ValueError, AssertionError):
                seen[(args[0], fmt)] = False
    json_same = w.run("stats", "--store", w.store, "--json").stdout == w.run("stats", "--store", w.store, "--format", "json").stdout
    bad = [k for k, v in seen.items() if not v]
    return not bad and json_same, f"failed: {bad}" if bad else f"{len(seen)} combinations parse"


@item("query: --exclude-self and --max-distance")
def _(w):
    all_hits = json.loads(w.run("query", w.part, "--store", w.store, "--top", "5", "--json").stdout)["hits"]
    without = json.loads(w.run("query", w.part, "--store", w.store, "--top", "4", "--exclude-self", "--json").stdout)["hits"]
    limit = all_hits[2]["distance"]
    near = json.loads(w.run("query", w.part, "--store", w.store, "--top", "5", "--max-distance", limit, "--json").stdout)["hits"]
    ok = ([h["path"] for h in without] == [h["path"] for h in all_hits[1:5]] and all(h["distance"] <= limit for h in near)
          and len(near) >= 3)
    return ok, f"{len(without)} without self, {len(near)} within {limit:.4g}"


@item("exit statuses: documented table; usage 2, bad file 1, locked 4, bug 70 distinct")
def _(w):
    docs = Path(__file__).resolve().parents[1] / "docs/cli.md"
    text = docs.read_text() if docs.exists() else ""
    codes = set(map(int, re.findall(r"^\| (\d+) \|", text, re.M)))
    usage = w.run("query", "--top", "x").returncode
    bad = w.run("inspect", w.dir / "nope.stl").returncode
    return codes >= {0, 1, 2, 3, 4, 5, 70, 130} and usage == 2 and bad == 1, f"documented {sorted(codes)}, usage {usage}, bad file {bad}"


@item("unreadable: an unreadable file is one line with status 1 (as a non-root user)")
def _(w):
    secret = w.dir / "secret.wrl"
    shutil.copy(w.part, secret)
    secret.chmod(0)
    command = [*w.command, "inspect", str(secret)]
    if os.geteuid() == 0:
        w.dir.chmod(0o755)
        command = ["setpriv", "--reuid=nobody", "--regid=nogroup", "--clear-groups", *command]
        probe = subprocess.run(command[:4] + [*w.command, "--version"], capture_output=True)
        if probe.returncode:
            raise Skip("cannot run the command as nobody")
    proc = subprocess.run(command, capture_output=True, text=True, timeout=120)
    return one_line_error(proc, 1, "secret.wrl")


@item("unreadable: a directory as FILE, a file as DIR: one line, status 1, every command")
def _(w):
    folder = w.dir / "folder.stl"
    folder.mkdir(exist_ok=True)
    results = [one_line_error(w.run(*args), 1, name)[0] for args, name in (
        (("inspect", folder), "folder.stl"), (("signature", folder), "folder.stl"),
        (("compare", folder, folder), "folder.stl"), (("query", folder, "--store", w.store), "folder.stl"),
        (("build", w.part, "--store", w.dir / "x.shapeidx"), w.part.name),
        (("evaluate", w.part, "--store", w.dir / "x.shapeidx"), w.part.name), (("stats", "--store", w.dir), str(w.dir)))]
    return all(results), results


@item("start-up: --version and --help under 0.3 s (median of 9)")
def _(w):
    """Wall time, unless the machine is so loaded that a bare Python start takes over 0.1 s:
    then CPU time (user + system, from wait4), which other load hardly changes."""

    def median_run(command):
        walls, cpus = [], []
        for _ in range(9):
            started = time.perf_counter()
            proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            _, _, usage = os.wait4(proc.pid, 0)
            walls.append(time.perf_counter() - started)
            cpus.append(usage.ru_utime + usage.ru_stime)
        return statistics.median(walls), statistics.median(cpus)

    baseline, _ = median_run([sys.executable, "-c", "pass"])
    loaded = baseline > 0.1
    timings = {" ".join(args): median_run([*w.command, *args]) for args in (["--version"], ["--help"], ["query", "--help"])}
    ok = all((cpu if loaded else wall) < 0.3 for wall, cpu in timings.values())
    seen = {k: f"wall {wall:.3f} s, CPU {cpu:.3f} s" for k, (wall, cpu) in timings.items()}
    seen["judged by"] = f"CPU time (loaded machine: python -c pass takes {baseline:.3f} s)" if loaded else "wall time"
    return ok, seen


@item("help: every command's --help has an example; bare shapeidx prints the help, status 0")
def _(w):
    bare = w.run()
    names = re.findall(r"^  (\w+)\s", bare.stdout.split("Commands:")[-1], re.M)
    missing = [n for n in names if "Example:" not in w.run(n, "--help").stdout]
    return bare.returncode == 0 and len(names) >= 7 and not missing, f"commands {names}, without example {missing}"


@item("help: shell completion and SHAPEIDX_DEBUG are documented and work")
def _(w):
    text = w.run("--help").stdout
    completion = w.run(env={"_SHAPEIDX_COMPLETE": "bash_source"})
    return ("_SHAPEIDX_COMPLETE" in text and "SHAPEIDX_DEBUG" in text and completion.returncode == 0
            and "complete" in completion.stdout), completion.stdout[:60]


@item("evaluate: --metric all is plain D2 in the help; in-sample figures are marked")
def _(w):
    helptext = " ".join(w.run("evaluate", "--help").stdout.split())
    kicad6 = w.dir / "kicad6"
    for folder in ("LED_SMD", "Diode_SMD"):
        shutil.copytree(w.tree / folder, kicad6 / folder, dirs_exist_ok=True)
    proc = w.run("evaluate", kicad6, "--store", w.dir / "kicad6.shapeidx", "--points", "128", "-q")
    return ("plain D2" in helptext and "not every metric" in helptext and "combined (in-sample)" in proc.stdout
            and "in-sample" in proc.stdout), proc.stdout.strip().splitlines()[-1][:120] if proc.stdout else proc.stderr


# ---------------------------------------------------------------------------------- cron

@item("cron: -q prints a first failure as one line; --strict says why it exits 3")
def _(w):
    tree = w.fresh_tree("cron")
    store = w.dir / "cron.shapeidx"
    first = w.run("build", tree, "--store", store, "--points", "128", "-q")
    shutil.copy(w.data / BROKEN, tree / "broken.stl")
    second = w.run("build", tree, "--store", store, "-q", "--strict")
    third = w.run("build", tree, "--store", store, "-q")
    lines = second.stderr.splitlines()
    ok = (first.stderr == "" and second.returncode == 3 and len(lines) == 2 and "failed broken.stl" in lines[0]
          and "--strict" in lines[1] and third.stderr == "" and third.returncode == 0)
    return ok, lines


@item("cron: log lines carry a timestamp and the prefix; no bytes repr in reasons")
def _(w):
    tree = w.fresh_tree("logs")
    shutil.copy(w.data / BYTES_REASON, tree / "bytes.stl")
    proc = w.run("build", tree, "--store", w.dir / "logs.shapeidx", "--points", "128", "-v")
    lines = proc.stderr.splitlines()
    bad = [line for line in lines if not LOG_LINE.match(line)]
    return not bad and "b'" not in proc.stderr and any("failed bytes.stl" in line for line in lines), bad[:2] or lines[-1]


@item("cron: build --json and stats --failed")
def _(w):
    tree = w.fresh_tree("json")
    shutil.copy(w.data / BROKEN, tree / "broken.stl")
    summary = json.loads(w.run("build", tree, "--store", w.dir / "json.shapeidx", "--points", "128", "--json", "-q").stdout)
    failed = json.loads(w.run("stats", "--store", w.dir / "json.shapeidx", "--failed", "--json").stdout)["failed"]
    ok = summary["indexed"] == 10 and summary["failed"] == 1 and [f["relative_path"] for f in failed] == ["broken.stl"]
    return ok and Path(failed[0]["path"]).is_file(), failed


@item("cron: --wait-timeout gives up after its time with status 4")
def _(w):
    holder = subprocess.Popen([sys.executable, "-c", "import fcntl, os, sys, time\n"
                               f"fd = os.open({str(w.store / 'lock')!r}, os.O_RDWR | os.O_CREAT)\n"
                               "fcntl.flock(fd, fcntl.LOCK_EX); os.write(fd, b'pid holder'); print('held', flush=True)\n"
                               "time.sleep(60)"], stdout=subprocess.PIPE, text=True)
    try:
        holder.stdout.readline()
        started = time.monotonic()
        proc = w.run("build", w.tree, "--store", w.store, "--wait-timeout", "2")
        waited = time.monotonic() - started
    finally:
        holder.kill()
        holder.wait()
    return proc.returncode == 4 and 2 <= waited < 30, f"status {proc.returncode} after {waited:.1f} s"


@item("cron: evaluate without classes refuses before a store appears; an empty folder is refused")
def _(w):
    flat = w.dir / "flat"
    shutil.copytree(w.tree / "LED_SMD", flat)
    work = w.dir / "cwd"
    work.mkdir()
    evaluate = w.run("evaluate", flat, cwd=work)
    (w.dir / "empty").mkdir()
    empty = w.run("build", w.dir / "empty", "--store", w.dir / "empty.shapeidx")
    ok = (one_line_error(evaluate, 1, "flat")[0] and not list(work.iterdir())
          and one_line_error(empty, 1, "empty")[0] and "no part files" in empty.stderr and not (w.dir / "empty.shapeidx").exists())
    return ok, [evaluate.stderr.strip()[:100], empty.stderr.strip()[:100]]


# ---------------------------------------------------------------------------------- the store

def damaged_copy(w, name: str) -> Path:
    """A copy of the workspace's store (a directory) with 4 KiB of its main file overwritten."""
    copy = w.dir / name
    shutil.copytree(w.store, copy)
    main = copy / "main.h5"
    size = main.stat().st_size
    with open(main, "r+b") as f:
        f.seek(size // 2)
        f.write(bytes(range(256)) * 16)  # 4 KiB in the middle
    return copy


@item("store: 4 KiB overwritten: check exits 5 naming it; query one line, never a wrong answer")
def _(w):
    copy = damaged_copy(w, "damaged.shapeidx")
    check = w.run("check", "--store", copy)
    query = w.run("query", "--id", w.part.relative_to(w.tree), "--store", copy)
    good = w.run("query", "--id", w.part.relative_to(w.tree), "--store", w.store)
    answered_right = query.returncode == 0 and query.stdout == good.stdout
    refused = query.returncode == 5 and len(query.stderr.strip().splitlines()) == 1 and "--repair" in query.stderr
    return check.returncode == 5 and "problem:" in check.stderr and (refused or answered_right), check.stderr.splitlines()[:1]


@item("store: build refuses a damaged store; --repair rebuilds it; check passes after")
def _(w):
    copy = damaged_copy(w, "repair.shapeidx")
    refused = w.run("build", w.tree, "--store", copy)
    repaired = w.run("build", w.tree, "--store", copy, "--repair", "-q")
    check = w.run("check", "--store", copy, "--files")
    same = w.run("query", "--id", w.part.relative_to(w.tree), "--store", copy).stdout == \
        w.run("query", "--id", w.part.relative_to(w.tree), "--store", w.store).stdout
    return refused.returncode == 5 and repaired.returncode == 0 and check.returncode == 0 and same, \
        [refused.returncode, repaired.returncode, check.stdout.strip()]


@item("store: check --files finds a file changed since it was indexed")
def _(w):
    tree = w.fresh_tree("changed")
    store = w.dir / "changed.shapeidx"
    w.run("build", tree, "--store", store, "--points", "128", "-q")
    target = sorted((tree / "LED_SMD").iterdir())[3]
    with open(target, "ab") as f:
        f.write(b"\n# edited\n")
    proc = w.run("check", "--store", store, "--files")
    return proc.returncode == 5 and target.name in proc.stderr and "changed" in proc.stderr, proc.stderr.strip()[:120]


@item("store: a damaged journal batch is refused (status 5) by readers and redone by the next build")
def _(w):
    tree = w.fresh_tree("journal", ("LED_SMD", "Diode_SMD"))
    store = w.dir / "journal.shapeidx"
    proc = subprocess.Popen([*w.command, "build", str(tree), "--store", str(store), "--points", "128", "-v",
                             "--commit-interval", "0.05", "--workers", "1"], stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:
        if "committed batch 2 " in line:
            proc.send_signal(signal.SIGKILL)
            break
    proc.wait()
    batches = sorted((store / "journal").glob("batch-*.h5"))
    if len(batches) < 2:
        return False, f"the killed build left {len(batches)} batches"
    data = bytearray(batches[0].read_bytes())
    data[len(data) // 2 : len(data) // 2 + 4096] = b"\0" * 4096
    batches[0].write_bytes(bytes(data))
    query = w.run("query", "--id", "LED_SMD/" + sorted(os.listdir(tree / "LED_SMD"))[0], "--store", store)
    again = w.run("build", tree, "--store", store, "--json")
    summary = json.loads(again.stdout) if again.returncode == 0 else {}
    refused = query.returncode == 5 and len(query.stderr.strip().splitlines()) == 1 and "Traceback" not in query.stderr
    ok = (refused and again.returncode == 0 and "dropped the damaged" in again.stderr
          and w.run("check", "--store", store).returncode == 0 and summary.get("store", {}).get("ok") == 20)
    return ok, f"query {query.returncode}: {query.stderr.strip()[:100]}; rebuild indexed {summary.get('indexed')}"


@item("store: readers racing merges never fail (1,000 opens during a merging build)")
def _(w):
    tree = w.fresh_tree("race", ("LED_SMD", "Diode_SMD"))
    store = w.dir / "race.shapeidx"
    w.run("build", tree, "--store", store, "--points", "128", "-q")
    for path in tree.rglob("*.wrl"):
        os.utime(path)  # every file to look at again: commits and merges all the way
    reader = subprocess.Popen([sys.executable, "-c", "import sys, shapeidx\nfailures = 0\n"
                               "for _ in range(1000):\n    try:\n"
                               f"        with shapeidx.open_store({str(store)!r}) as r: len(r.paths)\n"
                               "    except Exception as e:\n        failures += 1; print(type(e).__name__, e, file=sys.stderr)\n"
                               "print(failures)"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while reader.poll() is None:
        w.run("build", tree, "--store", store, "--rehash", "--commit-interval", "0.05", "--merge-after", "1", "-q")
        for path in list(tree.rglob("*.wrl"))[:5]:
            os.utime(path)
    out, err = reader.communicate()
    return out.strip() == "0", f"failures: {out.strip()} {err[:120]!r}"


# ---------------------------------------------------------------------------------- walk, options, environment

@item("walk: a link to /etc/passwd is not followed; nothing of it reaches the store or the log")
def _(w):
    tree = w.fresh_tree("links")
    (tree / "x.wrl").symlink_to("/etc/passwd")
    store = w.dir / "links.shapeidx"
    proc = w.run("build", tree, "--store", store, "--points", "128")
    failed = w.run("stats", "--store", store, "--failed", "--json").stdout
    ok = proc.returncode == 0 and "x.wrl" not in failed and "root:" not in proc.stderr + failed and "link out" in proc.stderr
    return ok, [line for line in proc.stderr.splitlines() if "x.wrl" in line][:1]


@item("options: nan, inf and negative values are usage errors")
def _(w):
    statuses = {" ".join(o): w.run("build", w.tree, "--store", w.dir / "opt.shapeidx", *o).returncode for o in (
        ("--timeout", "nan"), ("--timeout", "inf"), ("--commit-interval", "nan"), ("--seed", "-1"),
        ("--timeout", "-1"), ("--wait-timeout", "nan"))}
    statuses["query --max-distance nan"] = w.run("query", w.part, "--max-distance", "nan").returncode
    return all(s == 2 for s in statuses.values()) and not (w.dir / "opt.shapeidx").exists(), statuses


def tree_bytes(folder: Path) -> dict[str, bytes]:
    """A store's entries: its files by relative path, leaving out its bookkeeping (the lock, the
    record of the last build, which now says it stopped, and the cache of verified files)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name not in ("lock", "build.json", "verified")}


@item("environment: a full disk (ulimit -f) is one line with status 1; the store is unchanged")
def _(w):
    copy = w.dir / "full.shapeidx"
    shutil.copytree(w.store, copy)
    before = tree_bytes(copy)
    for path in w.tree.rglob("*.wrl"):
        os.utime(path)

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (128 << 10, 128 << 10))

    proc = w.run("build", w.tree, "--store", copy, "--rehash", preexec_fn=limit)
    errors = [line for line in proc.stderr.splitlines() if "error" in line]
    ok = proc.returncode == 1 and len(errors) == 1 and "Traceback" not in proc.stderr and tree_bytes(copy) == before
    return ok, errors


@item("environment: a read-only file system is one line with status 1")
def _(w):
    if os.geteuid() != 0:
        raise Skip("a read-only bind mount needs root")
    source, mount = w.dir / "rw", w.dir / "ro"
    source.mkdir()
    mount.mkdir()
    shutil.copytree(w.store, source / "s.shapeidx")
    if subprocess.run(["mount", "--bind", str(source), str(mount)], capture_output=True).returncode:
        raise Skip("mount --bind is not allowed here")
    try:
        subprocess.run(["mount", "-o", "remount,ro,bind", str(mount)], check=True, capture_output=True)
        query = w.run("query", w.part, "--store", mount / "s.shapeidx", "--top", "1")
        build = w.run("build", w.tree, "--store", mount / "s.shapeidx")
    finally:
        subprocess.run(["umount", str(mount)], capture_output=True)
    ok, seen = one_line_error(build, 1, "s.shapeidx")
    return ok and query.returncode == 0 and "ead-only" in build.stderr, seen


def default_command() -> list[str]:
    beside = Path(sys.executable).with_name("shapeidx")
    if beside.exists():
        return [str(beside)]
    found = shutil.which("shapeidx")
    if not found:
        raise SystemExit("no shapeidx command found: install the package or give --command")
    return [found]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--command", help="the shapeidx command to check [default: beside this Python, else PATH]")
    parser.add_argument("--data", type=Path, default=Path(os.environ.get("SHAPEIDX_DATA", Path(__file__).resolve().parents[2] / "shared/data")))
    parser.add_argument("--only", help="comma-separated words: run the items whose name contains one")
    parser.add_argument("--keep", action="store_true", help="keep the scratch folder")
    parser.add_argument("--verbose", action="store_true", help="print what was seen for passing items too")
    args = parser.parse_args()
    command = [args.command] if args.command else default_command()
    scratch = Path(tempfile.mkdtemp(prefix="check_cli-"))
    scratch.chmod(0o755)
    print(f"checking {' '.join(command)} with the data in {args.data} (scratch {scratch})")
    w = Workspace(command, args.data, scratch)
    words = args.only.split(",") if args.only else None
    tally = {"PASS": 0, "FAIL": 0, "SKIP": 0}
    try:
        for name, check in ITEMS:
            if words and not any(word in name for word in words):
                continue
            started = time.monotonic()
            try:
                ok, seen = check(w)
                verdict = "PASS" if ok else "FAIL"
            except Skip as why:
                verdict, seen = "SKIP", str(why)
            except Exception as exc:  # the check itself broke: a failure of the item
                verdict, seen = "FAIL", f"{type(exc).__name__}: {exc}"
            tally[verdict] += 1
            print(f"{verdict}  {name}  ({time.monotonic() - started:.1f} s)")
            if verdict != "PASS" or args.verbose or name.startswith("start-up"):
                print(f"      seen: {seen}")
    finally:
        if not args.keep:
            shutil.rmtree(scratch, ignore_errors=True)
    print(f"{tally['PASS']} passed, {tally['FAIL']} failed, {tally['SKIP']} skipped")
    return 1 if tally["FAIL"] else 0


if __name__ == "__main__":
    sys.exit(main())
