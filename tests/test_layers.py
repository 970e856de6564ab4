"""The imports run one way: no import circle, and no import from a lower layer up.

The layers, bottom up (docs and README, *How the code is laid out*): the base modules
(errors, system, ...), io, signing, distance, store, index, search, families / pictures /
web, evaluation, api, and the command line (cli and console). A module may import modules
of its own layer or of a layer below. Checked on the source with the ``ast`` module, so it
sees imports inside functions too.
"""

from __future__ import annotations

import ast
from pathlib import Path

import shapeidx

PACKAGE = Path(shapeidx.__file__).parent

LAYERS = [
    {"", "errors", "oserrors", "ragged", "system", "_lazy"},
    {"io"},
    {"signing"},
    {"distance"},
    {"store"},
    {"index"},
    {"search"},
    {"families", "pictures", "web"},
    {"evaluation"},
    {"api"},
    {"cli", "console"},
]
LAYER_OF = {name: level for level, names in enumerate(LAYERS) for name in names}


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> set[str]:
    """The shapeidx modules ``path`` imports (absolute names), at any depth of its code."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.startswith("shapeidx"):
                found.add(target)
                # "from . import x" imports the module x
                found.update(f"{target}.{alias.name}" for alias in node.names if (PACKAGE.parent / (target.replace(".", "/") + f"/{alias.name}.py")).exists())
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.startswith("shapeidx"))
    return found


def top_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def all_modules():
    return sorted(PACKAGE.rglob("*.py"))


def test_every_room_has_a_layer():
    rooms = {top_of(module_name(p)) for p in all_modules()}
    assert rooms <= set(LAYER_OF), f"rooms without a layer: {sorted(rooms - set(LAYER_OF))}"


def test_no_import_from_a_lower_layer_up():
    wrong = []
    for path in all_modules():
        mine = module_name(path)
        for target in imports_of(path):
            if LAYER_OF[top_of(target)] > LAYER_OF[top_of(mine)]:
                wrong.append(f"{mine} imports {target}")
    assert not wrong, "imports from a lower layer up:\n" + "\n".join(wrong)


def test_no_import_circle_between_rooms():
    edges = {}
    for path in all_modules():
        mine = top_of(module_name(path))
        for target in imports_of(path):
            if top_of(target) != mine:
                edges.setdefault(mine, set()).add(top_of(target))

    def reaches(start, goal, seen=()):
        return any(nxt == goal or (nxt not in seen and reaches(nxt, goal, seen + (nxt,))) for nxt in edges.get(start, ()))

    circles = [f"{a} <-> {b}" for a in edges for b in edges[a] if reaches(b, a)]
    assert not circles, f"import circles between rooms: {circles}"


def test_the_checker_sees_a_violation(tmp_path):
    """The checker can fail: an upward import written into a copy of a module is found."""
    source = PACKAGE / "store" / "layout.py"
    text = source.read_text() + "\n\ndef _up():\n    from ..search import Searcher\n"
    copy = PACKAGE / "store" / "_layering_probe.py"
    copy.write_text(text)
    try:
        found = imports_of(copy)
        assert "shapeidx.search" in found and LAYER_OF["search"] > LAYER_OF["store"]
    finally:
        copy.unlink()
