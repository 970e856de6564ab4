"""How commands print rows: ``--format table|csv|tsv|json|jsonl`` (``--json`` = ``--format json``).

* ``table``: aligned columns for people (each command lays out its own).
* ``csv``, ``tsv``: a header row, then a row per record (csv quoted as RFC 4180 says;
  tsv with tabs and newlines inside a field escaped as ``\\t``, ``\\n``).
* ``json``: one document (each command documents its shape in docs/cli.md).
* ``jsonl``: one JSON object per record and line, for streaming into other tools.

A reader that closes the pipe early (``| head -1``) ends the command quietly with status 0,
as git and ripgrep do: see :func:`quiet_broken_pipe`.
"""

from __future__ import annotations

import csv
import io
import json
import os
import sys

import click

FORMATS = ("table", "csv", "tsv", "json", "jsonl")


def format_options(function):
    """``--format`` and its shorthand ``--json`` on a command; the command gets ``output_format``."""
    function = click.option(
        "--json", "as_json", is_flag=True, help="Same as --format json."
    )(function)
    function = click.option(
        "--format", "output_format", type=click.Choice(FORMATS), default=None,
        help="Output: table (for people, the default), csv, tsv, json, jsonl (a JSON object per line).",
    )(function)
    return function


def chosen_format(output_format: str | None, as_json: bool) -> str:
    if as_json and output_format not in (None, "json"):
        raise click.UsageError(f"--json and --format {output_format} ask for two formats; give one")
    return "json" if as_json else (output_format or "table")


def emit_json(data) -> None:
    click.echo(json.dumps(data, indent=2, ensure_ascii=False))


def emit_jsonl(records) -> None:
    for record in records:
        click.echo(json.dumps(record, ensure_ascii=False))


def emit_rows(fmt: str, columns: list[str], records: list[dict], header: bool = True) -> None:
    """``records`` (dicts with at least ``columns``) as csv, tsv or jsonl (``header``: csv/tsv's first row)."""
    if fmt == "jsonl":
        emit_jsonl(records)
        return
    buffer = io.StringIO()
    if fmt == "csv":
        writer = csv.writer(buffer, lineterminator="\n")
        if header:
            writer.writerow(columns)
        for record in records:
            writer.writerow([_cell(record.get(c)) for c in columns])
    elif fmt == "tsv":
        if header:
            buffer.write("\t".join(columns) + "\n")
        for record in records:
            buffer.write("\t".join(_tsv_cell(record.get(c)) for c in columns) + "\n")
    else:
        raise ValueError(f"emit_rows does not print {fmt!r}")
    click.echo(buffer.getvalue(), nl=False)


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def _tsv_cell(value) -> str:
    return _cell(value).replace("\\", "\\\\").replace("\t", "\\t").replace("\n", "\\n").replace("\r", "\\r")


def quiet_broken_pipe() -> None:
    """After a BrokenPipeError on stdout: point stdout at /dev/null so that Python's final
    flush cannot complain, as the Python documentation's signal notes advise."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass
