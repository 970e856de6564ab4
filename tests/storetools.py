"""Helpers of the store, build and query tests: real part trees in tmp_path, real commands."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import analytic
import numpy as np

from clitools import cli
from shapeidx.io import load

REPO = Path(__file__).resolve().parents[1]
#: Small KiCad class folders (10 VRML parts each) for fast builds.
SMALL_KICAD = ("Capacitor_Tantalum_SMD", "Diode_SMD", "LED_SMD")
#: Points for tests where the signature itself is not what is tested.
FAST_POINTS = "128"


def copy_tree(source: Path, target: Path, folders=None) -> Path:
    """A writable copy of ``source`` (or of some of its folders) at ``target``."""
    target.mkdir(parents=True, exist_ok=True)
    for name in folders or [p.name for p in source.iterdir()]:
        src = source / name
        if src.is_dir():
            shutil.copytree(src, target / name)
        else:
            shutil.copy2(src, target / name)
    for path in [target, *target.rglob("*")]:
        path.chmod(path.stat().st_mode | 0o200)
    return target


def small_kicad(data_dir: Path, tmp_path: Path, folders=SMALL_KICAD) -> Path:
    return copy_tree(data_dir / "kicad6", tmp_path / "parts", folders)


def build(tree, store, *extra):
    """``shapeidx build`` through CliRunner with the fast test parameters."""
    return cli("build", tree, "--store", store, "--points", FAST_POINTS, *extra)


def summary_counts(output: str) -> dict:
    """The numbers of the final summary line: indexed, unchanged, removed, failed."""
    line = [ln for ln in output.splitlines() if " indexed, " in ln][-1]
    words = line.split(": ", 1)[1].split(" in ")[0].split(", ")
    return {w.split()[1]: int(w.split()[0]) for w in words}


def slow_assembly(data_dir: Path, path: Path, copies: int = 16) -> Path:
    """A pathological real file: ``copies``² copies of a real part side by side in one STL.

    Hundreds of bodies and ~0.7 M triangles keep cleaning and uniting busy for seconds, as
    an assembly exported as a single mesh does.
    """
    mesh = load(data_dir / "mesh-wild/voron2/Tools/pulley_jig.stl")
    faces = mesh.face_indices.reshape(-1, 3)
    step = 1.5 * float(np.ptp(mesh.vertices, axis=0).max())
    shifts = [(i * step, j * step, 0.0) for i in range(copies) for j in range(copies)]
    vertices = np.concatenate([mesh.vertices + np.array(shift) for shift in shifts])
    faces = np.concatenate([faces + k * len(mesh.vertices) for k in range(len(shifts))])
    analytic.write_stl(path, vertices, faces)
    return path


def load_script(name: str):
    """Import ``scripts/NAME.py`` as a module."""
    spec = importlib.util.spec_from_file_location(name, REPO / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process (all its threads)."""
    import os

    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
