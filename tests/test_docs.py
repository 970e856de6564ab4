"""The README and docs tell the truth: the command table, the set-up commands, the Python example,
the layout of the code, and every file, module, function and option they name."""

from __future__ import annotations

import re
from pathlib import Path

import click

from shapeidx.cli import main

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_block(marker: str) -> str:
    """The fenced code block right after ``<!-- marker -->``."""
    text = README.read_text()
    match = re.search(rf"<!-- {marker} -->\s*```\w*\n(.*?)```", text, re.S)
    assert match, f"README has no block after <!-- {marker} -->"
    return match.group(1)


def test_the_command_table_lists_every_command_and_no_other():
    text = README.read_text()
    table = text[text.index("## Commands") :]
    table = table[: table.index("\n## ", 4)]
    documented = set(re.findall(r"^\| `shapeidx (\w[\w-]*)", table, re.M))
    ctx = click.Context(main)
    commands = {name for name in main.list_commands(ctx) if not main.get_command(ctx, name).hidden}
    assert documented == commands - {"info"}, (documented ^ (commands - {"info"}))


def test_the_options_in_the_table_exist():
    text = README.read_text()
    table = text[text.index("## Commands") :]
    table = table[: table.index("\n## ", 4)]
    ctx = click.Context(main)
    for name, usage in re.findall(r"^\| `shapeidx (\w[\w-]*)([^`]*)`", table, re.M):
        options = {o for p in main.get_command(ctx, name).params for o in p.opts}
        for option in re.findall(r"--[\w-]+", usage):
            assert option in options, f"README: shapeidx {name} has no option {option}"


def test_the_python_example_runs(data_dir, tmp_path, monkeypatch):
    from storetools import build, small_kicad

    tree = small_kicad(data_dir, tmp_path, ["Battery", "LED_SMD"])
    assert build(tree, tmp_path / "kicad6.shapeidx").exit_code == 0
    code = readme_block("api-example").replace("../shared/data/kicad6", str(tree))
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README.md", "exec"), {})


def test_the_h5py_example_runs_on_the_store_the_set_up_command_makes(data_dir, tmp_path, monkeypatch):
    """The set-up command's store is its main file alone: h5py reads it without shapeidx."""
    from storetools import build, small_kicad

    tree = small_kicad(data_dir, tmp_path, ["Battery"])
    command = readme_block("main-command")
    assert "--store kicad6.shapeidx" in command
    assert build(tree, tmp_path / "kicad6.shapeidx").exit_code == 0
    assert not (tmp_path / "kicad6.shapeidx" / "journal").exists()  # folded into main.h5
    monkeypatch.chdir(tmp_path)
    exec(compile(readme_block("h5py-example"), "README.md", "exec"), {})


def test_the_metric_tables_are_the_registrys():
    """README.md and docs/cli.md hold the table scripts/docs_tables.py makes from the registry."""
    from shapeidx.distance.metrics import REGISTRY, markdown_table

    for doc in (README, README.parent / "docs" / "cli.md"):
        text = doc.read_text()
        block = re.search(r"<!-- metrics-table -->\n(.*?)<!-- /metrics-table -->", text, re.S)
        assert block and block.group(1) == markdown_table(), f"{doc.name}: run scripts/docs_tables.py"
        assert all(f"| `{name}` |" in block.group(1) for name in REGISTRY)


def test_every_metric_is_a_choice_and_in_the_help():
    from shapeidx.distance.metrics import REGISTRY

    ctx = click.Context(main)
    for command in ("query", "classify"):
        option = next(p for p in main.get_command(ctx, command).params if p.name == "metric")
        assert tuple(option.type.choices) == tuple(REGISTRY)
        assert all(m.summary in option.help for m in REGISTRY.values())


def test_the_set_up_commands_name_real_paths():
    main_command = readme_block("main-command")
    for path in re.findall(r"\.\./shared/data/\S+", main_command):
        assert (README.parent / path).exists(), path


DOCS = [README, *sorted((README.parent / "docs").glob("*.md"))]
PACKAGE = README.parent / "shapeidx"


def test_the_layout_names_every_module_and_only_modules_that_exist():
    """README's *How the code is laid out* names each module in its room's paragraph, and every
    ``name.py`` it names is a module of the package."""
    block = readme_block("layout")
    paragraphs = re.split(r"\n(?=shapeidx/)", block)
    missing = []
    for path in sorted(PACKAGE.rglob("*.py")):
        relative = path.relative_to(PACKAGE)
        if len(relative.parts) == 1:  # a module beside the package's __init__: named anywhere
            if path.name not in block:
                missing.append(str(relative))
            continue
        if path.name == "__init__.py":
            continue
        room = relative.parts[0] + "/"
        # the room's paragraph: the one it heads, or the first that names it (console/ under cli.py)
        paragraph = next((p for p in paragraphs if p.startswith("shapeidx/" + room)), None) or \
            next((p for p in paragraphs if room in p), "")
        # a room's module by its file name; a module of a folder inside a room (io/vrml/) by its name
        named = path.name if len(relative.parts) == 2 else path.stem
        if not re.search(rf"(?<![\w]){re.escape(named)}(?![\w])", paragraph):
            missing.append(str(relative))
    assert not missing, f"modules the layout does not name: {missing}"
    modules = {p.name for p in PACKAGE.rglob("*.py")}
    gone = sorted(set(re.findall(r"[\w]+\.py", block)) - modules)
    assert not gone, f"the layout names modules that do not exist: {gone}"


def test_every_file_the_docs_name_exists():
    gone = [f"{doc.name}: {path}" for doc in DOCS
            for path in sorted(set(re.findall(r"(?<![\w/.])((?:shapeidx|scripts|tests|docs)/[\w/.-]*\w\.(?:py|md|json|js|html|css))\b",
                                              doc.read_text())))
            if not (README.parent / path).exists()]
    assert not gone, gone


def _resolves(dotted: str) -> bool:
    """Whether ``shapeidx.a.b.c`` is a module, or an attribute of the longest module it starts with."""
    import importlib

    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        try:
            found = importlib.import_module(".".join(parts[:k]))
        except ImportError:
            continue
        for attribute in parts[k:]:
            if not hasattr(found, attribute):
                return False
            found = getattr(found, attribute)
        return True
    return False


def test_every_module_function_and_class_the_docs_name_exists():
    assert _resolves("shapeidx.search.distances.nearest") and not _resolves("shapeidx.search.distances.gone")
    gone = [f"{doc.name}: {name}" for doc in DOCS
            for name in sorted(set(re.findall(r"(?<![\w/.])shapeidx(?:\.\w+)+", doc.read_text())))
            if not _resolves(name)]
    assert not gone, gone


def test_every_option_the_docs_give_a_command_exists():
    """``shapeidx CMD ... --option`` in inline code and code blocks: CMD has --option."""
    context = click.Context(main)
    commands = {name: main.get_command(context, name) for name in main.list_commands(context)}
    wrong, seen = [], 0
    for doc in DOCS:
        text = re.sub(r"\\\n\s*", " ", doc.read_text())  # continued lines
        fragments = re.findall(r"`([^`\n]+)`", text) + [line for block in re.findall(r"```\w*\n(.*?)```", text, re.S)
                                                        for line in block.splitlines()]
        for fragment in fragments:
            for use in re.finditer(r"(?<![\w.-])shapeidx(?:\.cli)?\s+([a-z][a-z-]*)((?:\s+(?!\||&&|;|>|2>)[^\s|;&>]+)*)", fragment):
                name, rest = use.groups()
                if name not in commands:
                    if "--" in rest:
                        wrong.append(f"{doc.name}: no command {name!r} in {fragment!r}")
                    continue
                seen += 1
                known = {o for p in commands[name].params for o in p.opts + p.secondary_opts} | {"--help"}
                wrong += [f"{doc.name}: {name} has no {option} ({fragment!r})"
                          for option in re.findall(r"(?<![\w-])(--[a-z][\w-]*)", rest) if option not in known]
    assert seen > 100  # the docs show commands: the pattern finds them
    assert not wrong, "\n".join(wrong)


def test_each_package_docstring_lists_its_modules():
    """Each folder's ``__init__.py`` lists its modules (README: in the order they run)."""
    import ast

    missing = []
    for init in sorted(PACKAGE.rglob("__init__.py")):
        if init.parent == PACKAGE:
            continue
        doc = ast.get_docstring(ast.parse(init.read_text())) or ""
        missing += [str(p.relative_to(PACKAGE)) for p in sorted(init.parent.glob("*.py"))
                    if p.name != "__init__.py" and not re.search(rf"(?<![\w]){re.escape(p.name)}(?![\w])", doc)]
    assert not missing, f"modules their package's docstring does not list: {missing}"
