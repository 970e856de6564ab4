"""The imports run one way: no import circle (between rooms or modules), no import from a lower
layer up, and no private name taken from another module.

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


def _compiled(package: str, name: str) -> bool:
    """Whether ``package.name`` is a compiled module (its C source lies in the package)."""
    return (PACKAGE.parent / package.replace(".", "/") / f"{name}.c").is_file()


def import_statements(path: Path, name: str | None = None):
    """(module, names taken from it, line) for every import of a shapeidx module in ``path``,
    at any depth of its code (``from . import x`` of a module x: that module, no names);
    ``name``: the module ``path`` is read as (default: its own, by its place in the package)."""
    name = name or module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if not target.startswith("shapeidx"):
                continue
            taken = []
            for alias in node.names:
                if (PACKAGE.parent / (target.replace(".", "/") + f"/{alias.name}.py")).exists() or _compiled(target, alias.name):
                    yield f"{target}.{alias.name}", (), node.lineno
                else:
                    taken.append(alias.name)
            yield target, tuple(taken), node.lineno
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("shapeidx"):
                    yield alias.name, (), node.lineno


def imports_of(path: Path, name: str | None = None) -> set[str]:
    """The shapeidx modules ``path`` imports (absolute names), at any depth of its code
    (``name``: as :func:`import_statements`)."""
    return {target for target, _, _ in import_statements(path, name)}


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
    copy = tmp_path / "_layering_probe.py"  # read as a module of shapeidx.store, never written into the package
    copy.write_text(text)
    found = imports_of(copy, "shapeidx.store._layering_probe")
    assert "shapeidx.search" in found and LAYER_OF["search"] > LAYER_OF["store"]


def module_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports. A module's own packages (their __init__) run
    before it whatever it does: an import of one of them is no edge of a circle."""
    modules = {module_name(p): p for p in all_modules()}
    return {name: {t for t in imports_of(path) if t in modules and t != name and not name.startswith(t + ".")}
            for name, path in modules.items()}


def circles_of(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan's, without recursion)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    for root in sorted(edges):
        if root in index:
            continue
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        work = [(root, iter(sorted(edges[root])))]
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges.get(child, ())))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while not component or component[-1] != node:
                        component.append(stack.pop())
                        on_stack.discard(component[-1])
                    if len(component) > 1:
                        found.append(sorted(component))
    return found


def test_the_circle_finder_finds_a_circle():
    assert circles_of({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}) == [["a", "b", "c"]]
    assert circles_of({"a": {"b"}, "b": set()}) == []


def test_the_module_graph_holds_imports_made_inside_functions():
    edges = module_graph()
    assert "shapeidx.io.step" in edges["shapeidx.io.parts"]  # imported inside split_parts' helpers only
    assert "shapeidx.store.lock" in edges["shapeidx.store.reader"]


def test_no_import_circle_between_modules():
    """Not even one broken at run time by an import inside a function: the two modules still need
    each other (the store's reader, writer and checker once did; the lock is now a module of its own)."""
    circles = circles_of(module_graph())
    assert not circles, "import circles: " + "; ".join(" <-> ".join(c) for c in circles)


def test_no_module_takes_a_private_name_from_another():
    borrowed = [f"{path.relative_to(PACKAGE.parent)}:{line} takes {item} from {target}"
                for path in all_modules() for target, taken, line in import_statements(path)
                for item in taken if item.startswith("_") and not item.startswith("__")]
    assert not borrowed, "\n".join(borrowed)


def test_every_module_imports_first():
    """Each module can be the first one a process imports: no import order that works by luck."""
    import subprocess
    import sys

    failed = []
    for name in sorted(module_name(p) for p in all_modules()):
        done = subprocess.run([sys.executable, "-c", f"import {name}"], capture_output=True, text=True, timeout=300)
        if done.returncode:
            failed.append(f"{name}: {(done.stderr.strip().splitlines() or ['?'])[-1]}")
    assert not failed, "modules that fail when imported first:\n" + "\n".join(failed)
