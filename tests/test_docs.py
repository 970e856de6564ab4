"""The README tells the truth: its command table, its set-up commands and its Python example."""

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
