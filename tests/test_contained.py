"""OpenCASCADE crashes and hangs cost one error line in every command, not the process.

The files are made as the attack made them: a real kicad6 STEP file with one ``)`` taken
out of one entity (some such files crash OpenCASCADE 7/8 with SIGSEGV), and a real file
whose one EDGE_LOOP lists tens of thousands of edges (OpenCASCADE then reads for minutes).
Each load runs in a separate Python process, so that a crash before the containment shows
as a failed test, not as a dead test run.
"""

from __future__ import annotations

import json
import random
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from clitools import shapeidx_command

SEED_PART = "Capacitor_THT/C_Axial_L5.1mm_D3.1mm_P10.00mm_Horizontal.step"

LOAD_EACH = """
import json, sys
from shapeidx.errors import LoadError
from shapeidx.io import LoadLimits, load
for path in sys.argv[2:]:
    try:
        mesh = load(path, LoadLimits(max_seconds=float(sys.argv[1])))
        print(json.dumps({"path": path, "mesh": len(mesh.face_sizes)}), flush=True)
    except LoadError as exc:
        print(json.dumps({"path": path, "error": str(exc)}), flush=True)
"""


def _load_each(paths, seconds=120.0, timeout=600):
    """Load every file in one fresh process; its exit status and one outcome per file."""
    run = subprocess.run([sys.executable, "-c", LOAD_EACH, str(seconds), *map(str, paths)],
                         capture_output=True, text=True, timeout=timeout)
    return run, [json.loads(line) for line in run.stdout.splitlines()]


def missing_parenthesis(source: bytes, count: int, seed: int = 1) -> list[bytes]:
    """``count`` copies of a STEP file, each with one ``)`` deleted from one entity."""
    lines = source.split(b"\n")
    rng = random.Random(seed)
    entities = [i for i, line in enumerate(lines) if line.startswith(b"#") and b")" in line]
    out = []
    for _ in range(count):
        i = rng.choice(entities)
        line = lines[i]
        j = rng.choice([k for k, c in enumerate(line) if c == ord(")")])
        out.append(b"\n".join(lines[:i] + [line[:j] + line[j + 1:]] + lines[i + 1:]))
    return out


@pytest.fixture(scope="module")
def mutated(data_dir, tmp_path_factory) -> list[Path]:
    folder = tmp_path_factory.mktemp("mutated")
    source = (data_dir / "kicad6-step" / SEED_PART).read_bytes()
    paths = []
    for k, content in enumerate(missing_parenthesis(source, 11)):
        paths.append(folder / f"case{k}.step")
        paths[-1].write_bytes(content)
    return paths


@pytest.fixture(scope="module")
def loaded(mutated):
    return _load_each(mutated)


@pytest.fixture(scope="module")
def crashing(loaded) -> Path:
    run, outcomes = loaded
    found = [Path(o["path"]) for o in outcomes if "crashed" in o.get("error", "")]
    assert found, outcomes
    return found[0]


def test_a_crash_of_opencascade_is_one_error_line(mutated, loaded):
    run, outcomes = loaded
    assert run.returncode == 0, f"the process died ({run.returncode}) after {len(outcomes)} files: {run.stderr[-500:]}"
    assert len(outcomes) == len(mutated)
    crashed = [o for o in outcomes if "error" in o and "OpenCASCADE crashed reading it (signal 11, SIGSEGV)" in o["error"]]
    assert crashed, outcomes  # the class of input does crash OpenCASCADE: the test sees containment
    for outcome in outcomes:
        assert "mesh" in outcome or outcome["error"].startswith(outcome["path"] + ": "), outcome
    assert any("mesh" in o for o in outcomes)  # and the process is still good for the files after


@pytest.mark.parametrize("command", ["signature", "inspect"])
def test_commands_survive_a_crashing_file(crashing, command):
    result = subprocess.run(shapeidx_command(command, crashing), capture_output=True, text=True, timeout=300)
    assert result.returncode > 0, result
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and str(crashing) in lines[0] and "OpenCASCADE crashed reading it" in lines[0], result.stderr


def test_compare_survives_a_crashing_file(data_dir, crashing):
    good = data_dir / "kicad6-step" / SEED_PART
    result = subprocess.run(shapeidx_command("compare", good, crashing), capture_output=True, text=True, timeout=300)
    assert result.returncode > 0 and "Traceback" not in result.stderr
    assert "OpenCASCADE crashed reading it" in result.stderr and str(crashing) in result.stderr


def _long_edge_loop(source: str, edges: int) -> str:
    match = re.search(r"#(\d+) = EDGE_LOOP\('',\((#[^)]*)\)\);", source)
    refs = ",".join([match.group(2).split(",")[0]] * edges)
    return source.replace(match.group(0), f"#{match.group(1)} = EDGE_LOOP('',({match.group(2)},{refs}));")


def test_a_hang_is_stopped_by_the_time_limit(data_dir, tmp_path):
    """An EDGE_LOOP of 15,000 edges (under the parameter limit): OpenCASCADE reads for
    many seconds; the contained read stops at the limit and says so."""
    source = (data_dir / "kicad6-step" / SEED_PART).read_text()
    slow = tmp_path / "slow.step"
    slow.write_text(_long_edge_loop(source, 15_000))
    started = time.monotonic()
    run, outcomes = _load_each([slow], seconds=1.0)
    assert run.returncode == 0, run.stderr
    assert outcomes[0]["error"] == f"{slow}: OpenCASCADE took longer than 1 s reading it (stopped)"
    assert time.monotonic() - started < 60


def test_an_entity_of_too_many_parameters_is_refused_before_reading(data_dir, tmp_path):
    from shapeidx.errors import LoadError
    from shapeidx.io import load
    from shapeidx.io.step import MAX_STEP_PARAMETERS

    source = (data_dir / "kicad6-step" / SEED_PART).read_text()
    huge = tmp_path / "huge.step"
    huge.write_text(_long_edge_loop(source, 200_000))
    started = time.process_time()
    with pytest.raises(LoadError, match=r"has an entity \(#\d+\) of 200,00\d parameters, more than the limit"):
        load(huge)
    assert time.process_time() - started < 5
    # the limit leaves every real part alone: the most in the KiCad library is 3,095
    assert MAX_STEP_PARAMETERS > 5 * 3_095
    ok = tmp_path / "ok.step"
    ok.write_text(_long_edge_loop(source, 10))
    assert len(load(ok).face_sizes) > 0


def test_build_workers_read_in_their_own_process(loaded, crashing, tmp_path):
    """A build's worker is a container already: the crash kills the worker (and costs the
    file), it is not read in a second child process per file."""
    import shutil

    from shapeidx.store import STATUS_FAILED, STATUS_OK, open_store
    from storetools import FAST_POINTS

    run, outcomes = loaded
    good = next(Path(o["path"]) for o in outcomes if "mesh" in o)
    tree = tmp_path / "parts"
    tree.mkdir()
    shutil.copy(crashing, tree / "crash.step")
    shutil.copy(good, tree / "good.step")
    store = tmp_path / "s.h5"
    build = subprocess.run(shapeidx_command("build", tree, "--store", store, "--points", FAST_POINTS, "--workers", "1"),
                           capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stderr
    with open_store(store) as reader:
        status = dict(zip(reader.paths, reader.column("entries/status")))
        reasons = dict(zip(reader.paths, reader.column("entries/reason")))
    assert status["good.step"] == STATUS_OK
    assert status["crash.step"] == STATUS_FAILED
    assert reasons["crash.step"] == "worker process died (SIGSEGV) while indexing this file", reasons


def _iges_of(step: Path, out: Path, mode: int = 1) -> Path:
    """A real kicad6 part written as IGES by OpenCASCADE's own writer (in a child process)."""
    code = ("import sys\n"
            "from OCP.STEPControl import STEPControl_Reader\n"
            "from OCP.IGESControl import IGESControl_Writer\n"
            "r = STEPControl_Reader(); r.ReadFile(sys.argv[1]); r.TransferRoots()\n"
            "w = IGESControl_Writer('MM', int(sys.argv[3])); w.AddShape(r.OneShape()); w.ComputeModel()\n"
            "assert w.Write(sys.argv[2])\n")
    subprocess.run([sys.executable, "-c", code, str(step), str(out), str(mode)], check=True, timeout=300,
                   capture_output=True)
    return out


def test_an_iges_directory_line_missing_is_a_contained_crash_with_its_cause(data_dir, tmp_path):
    """One line of the Directory section deleted: OpenCASCADE dies on it; the line says so
    and names the damaged numbering (the numbering alone does not refuse a file:
    OpenCASCADE reads many such files all the same)."""
    whole = _iges_of(data_dir / "kicad6-step" / SEED_PART, tmp_path / "whole.igs")
    lines = whole.read_bytes().split(b"\n")
    directory = [i for i, line in enumerate(lines) if len(line) >= 73 and line[72:73] == b"D"]
    rng = random.Random(2)
    paths = []
    for k in range(3):
        i = rng.choice(directory[1:])
        paths.append(tmp_path / f"cut{k}.igs")
        paths[-1].write_bytes(b"\n".join(lines[:i] + lines[i + 1:]))
    run, outcomes = _load_each([whole, *paths])
    assert run.returncode == 0 and "mesh" in outcomes[0], outcomes
    for outcome in outcomes[1:]:
        assert re.search(r"OpenCASCADE crashed reading it \(signal 11, SIGSEGV\); its Directory section is damaged: "
                         r"line \d+ is numbered \d+ \(a line missing or out of place\)$", outcome["error"]), outcome


def test_the_web_server_survives_an_upload_that_crashes_opencascade(data_dir, crashing, tmp_path):
    """A real ``shapeidx serve``: the crashing upload is a 422 with the line, and the server
    goes on answering (the same upload killed it before)."""
    import socket
    import shutil

    import httpx

    from storetools import FAST_POINTS

    tree = tmp_path / "parts"
    tree.mkdir()
    good = data_dir / "kicad6-step" / SEED_PART
    shutil.copy(good, tree / "good.step")
    store = tmp_path / "s.shapeidx"
    subprocess.run(shapeidx_command("build", tree, "--store", store, "--points", FAST_POINTS, "--workers", "1"),
                   check=True, capture_output=True, timeout=600)
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = subprocess.Popen(shapeidx_command("serve", "--store", store, "--port", port),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                if httpx.get(f"{base}/api/store", timeout=5).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert server.poll() is None and time.monotonic() < deadline, server.stderr.read() if server.poll() else "no answer"
            time.sleep(0.5)
        answer = httpx.post(f"{base}/api/query", files={"file": ("crash.step", crashing.read_bytes())}, timeout=300)
        assert answer.status_code == 422, answer.text
        assert "OpenCASCADE crashed reading it (signal 11, SIGSEGV)" in answer.json()["error"]
        assert server.poll() is None
        again = httpx.post(f"{base}/api/query", files={"file": ("good.step", good.read_bytes())}, data={"top": "1"},
                           timeout=300)
        assert again.status_code == 200, again.text
    finally:
        server.terminate()
        server.wait(timeout=30)


def test_what_the_child_does_becomes_one_line(tmp_path):
    """The mechanism on its own, with real deeds of the child: a result, an abort, a hang,
    an unforeseen exception (no traceback, no exception name)."""
    import os

    from shapeidx.errors import LoadError
    from shapeidx.io.contained import run_contained

    where = tmp_path / "f.step"
    assert run_contained(divmod, (7, 2), where) == (3, 1)
    with pytest.raises(LoadError, match=r"f.step: OpenCASCADE crashed reading it \(signal 6, SIGABRT\)$"):
        run_contained(os.abort, (), where)
    started = time.monotonic()
    with pytest.raises(LoadError, match=r"f.step: OpenCASCADE took longer than 0.5 s reading it \(stopped\)$"):
        run_contained(time.sleep, (60,), where, seconds=0.5)
    assert time.monotonic() - started < 30
    with pytest.raises(LoadError) as caught:
        run_contained(int, ("x",), where)
    assert str(caught.value).startswith(f"{where}: cannot be read: it holds a value of the wrong form")
    assert "ValueError" not in str(caught.value)


def test_a_long_b_spline_is_read_but_a_long_edge_loop_is_refused(tmp_path):
    """A B-spline's parameters are control points and knots, which OpenCASCADE reads in linear
    time: a real solid written out alone by OpenCASCADE has a curve of 36,310 (docs/assemblies.md);
    topology as long (an edge loop) is what takes it minutes."""
    from shapeidx.errors import LoadError
    from shapeidx.io.step import MAX_STEP_PARAMETERS, MAX_STEP_SPLINE_PARAMETERS, _check_step_entities

    refs = ",".join(f"#{k}" for k in range(100, 100 + 36_300))
    spline = f"#7 = B_SPLINE_CURVE_WITH_KNOTS('',3,({refs}),.UNSPECIFIED.,.F.,.F.,(4,4),(0.,1.),.UNSPECIFIED.);\n"
    _check_step_entities(tmp_path / "spline.step", spline.encode())
    loop = f"#7 = EDGE_LOOP('',({refs}));\n"
    with pytest.raises(LoadError, match=r"#7\) of 36,301 parameters, more than the limit of 20,000"):
        _check_step_entities(tmp_path / "loop.step", loop.encode())
    huge = f"#7 = B_SPLINE_CURVE_WITH_KNOTS('',3,({','.join(['#1'] * 250_000)}),.U.,.F.,.F.,(4,4),(0.,1.),.U.);\n"
    with pytest.raises(LoadError, match=r"more than the limit of 200,000"):
        _check_step_entities(tmp_path / "huge.step", huge.encode())
    assert MAX_STEP_PARAMETERS < 36_310 < MAX_STEP_SPLINE_PARAMETERS
