"""What the scripts share: where the shared data is, the machine they ran on, a quiet build.

Scripts run from a checkout (``python scripts/NAME.py``), so this folder is on ``sys.path``
and ``import _common`` finds this module.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: The shared real data (read-only): ../shared/data beside the checkout, or $SHAPEIDX_DATA.
DATA = Path(os.environ.get("SHAPEIDX_DATA", REPO.parent / "shared" / "data"))
#: The labelled collections of docs/results.md (classes: each part's first folder, as
#: ``shapeidx evaluate`` reads them): scripts/results.py's tables and scripts/peers.py's kinds.
COLLECTIONS = {
    "kicad6": DATA / "kicad6",
    "kicad-mcad": DATA / "vrml-wild" / "kicad-mcad",
    "kicad-2017/freecad-coin": DATA / "vrml-wild" / "kicad-2017" / "freecad-coin",
    "kicad-2017/wings3d": DATA / "vrml-wild" / "kicad-2017" / "wings3d",
    "kicad-wrz": DATA / "vrml-wild" / "kicad-wrz",
}


def machine() -> str:
    """One line for a benchmark's report: processor, cores, memory, system and library versions."""
    import embreex
    import numpy as np
    import trimesh

    cpu = platform.processor() or "unknown cpu"
    try:
        with open("/proc/cpuinfo") as info:
            cpu = next((line.split(":", 1)[1].strip() for line in info if line.startswith("model name")), cpu)
    except OSError:
        pass
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return (
        f"{cpu}, {os.cpu_count()} cores, {memory:.0f} GiB; {platform.system()} {platform.release()}; "
        f"Python {platform.python_version()}, numpy {np.__version__}, "
        f"embreex {getattr(embreex, '__version__', '?')}, trimesh {trimesh.__version__}"
    )


def quiet_build(directory, store, **options) -> Path:
    """Bring ``store`` up to date with ``directory`` (as ``shapeidx build -q``); returns the store."""
    from shapeidx.index.build import BuildOptions, run_build
    from shapeidx.index.progress import BuildReporter

    run_build(directory, store, BuildOptions(**options), BuildReporter(quiet=True))
    return Path(store)
