"""The ``shapeidx`` command: click commands only; the work is in the library.

Start-up stays fast (``--version`` and ``--help`` import click and :mod:`shapeidx.console`
only): each command imports the library it needs inside its body.
"""

from __future__ import annotations

import os
import sys

import click

from . import __version__
from .console import exits
from .console.output import chosen_format, emit_json, emit_rows, format_options, quiet_broken_pipe
from .console.params import (
    DEFAULT_COMMIT_INTERVAL,
    DEFAULT_POINTS,
    DEFAULT_SEED,
    DEFAULT_STORE,
    DEFAULT_TIMEOUT,
    MAX_SEED,
    MERGE_AFTER,
    METRICS,
    PART_FORMATS,
    STORE_ENV,
    FiniteFloat,
    default_metric,
    duplicate_metrics,
    metric_help,
)
from .errors import plain_reason
from .errors import printable

CONTEXT = {"help_option_names": ["-h", "--help"], "max_content_width": 100}


def _error_line(exc: BaseException) -> str:
    """One line for an error that ends the command (see :mod:`shapeidx.console.exits`)."""
    from .errors import NoAnswer, ShapeidxError

    if isinstance(exc, NoAnswer):
        return f"shapeidx: {plain_reason(exc)}"
    if isinstance(exc, ShapeidxError):
        return f"shapeidx: error: {plain_reason(exc)}"
    reason = exits.environment_reason(exc)
    where = getattr(exc, "filename", None)
    if where is None:
        import re

        match = re.search(r"filename = '([^']*)'", str(exc))
        where = match.group(1) if match else None
    where = f"{printable(where)}: " if where else ""
    return f"shapeidx: error: {where}{reason}"


class _Group(click.Group):
    """Every error becomes one line on stderr and the status of docs/cli.md, never a traceback."""

    def invoke(self, ctx):
        from .errors import ShapeidxError

        try:
            return super().invoke(ctx)
        except (click.exceptions.Exit, click.ClickException, click.Abort):
            raise
        except BrokenPipeError:  # the reader went away (| head): not an error
            quiet_broken_pipe()
            ctx.exit(exits.OK)
        except KeyboardInterrupt:
            click.echo("shapeidx: interrupted", err=True)
            ctx.exit(exits.INTERRUPTED)
        except ShapeidxError as exc:
            click.echo(_error_line(exc), err=True)
            ctx.exit(exits.status_of(exc))
        except Exception as exc:
            if exits.environment_reason(exc) is not None and not os.environ.get("SHAPEIDX_DEBUG"):
                click.echo(_error_line(exc), err=True)
                ctx.exit(exits.ERROR)
            if os.environ.get("SHAPEIDX_DEBUG"):  # a bug: one line, unless debugging is asked for
                raise
            message = plain_reason(f"{type(exc).__name__}: {exc}")
            click.echo(f"shapeidx: internal error: {message} (set SHAPEIDX_DEBUG=1 for details)", err=True)
            ctx.exit(exits.INTERNAL)

    def main(self, *args, **kwargs):
        try:
            return super().main(*args, **kwargs)
        except BrokenPipeError:  # while click itself wrote (--help | head -1)
            quiet_broken_pipe()
            sys.exit(exits.OK)


@click.group(cls=_Group, invoke_without_command=True, context_settings=CONTEXT)
@click.version_option(__version__, "--version", "-V", prog_name="shapeidx")
@click.pass_context
def main(ctx):
    """Search CAD parts by shape: IN/OUT/MIXED D2 shape distributions (Ip et al. 2002).

    \b
    Example:
      shapeidx build parts/ --store parts.shapeidx
      shapeidx query bracket.stl --store parts.shapeidx --top 5

    \b
    Exit status: 0 ok, 1 error (bad file, unusable store, disk full), 2 usage error,
    3 build --strict found failed files, 4 store locked by another build, 5 store damaged,
    70 internal error (SHAPEIDX_DEBUG=1 shows the traceback), 130 interrupted.
    Shell completion: eval "$(_SHAPEIDX_COMPLETE=bash_source shapeidx)" (zsh_source, fish_source).
    """
    if ctx.invoked_subcommand is None:
        click.echo(ctx.get_help())
        ctx.exit(exits.OK)
    from .system import keep_freed_memory

    keep_freed_memory()


points_option = click.option(
    "--points", default=DEFAULT_POINTS, show_default=True, type=click.IntRange(2, 8192), help="Surface samples."
)
seed_option = click.option(
    "--seed", default=DEFAULT_SEED, show_default=True, type=click.IntRange(0, MAX_SEED), help="Sampling seed (>= 0)."
)
json_option = click.option("--json", "as_json", is_flag=True, help="Machine-readable output (docs/cli.md).")


def _deflection_options(defaults: bool):
    """``--linear-deflection`` / ``--angular-deflection``: faceting of STEP and IGES files."""
    from .io.faceting import (ANGULAR_DEFLECTION_RANGE, DEFAULT_ANGULAR_DEFLECTION, DEFAULT_LINEAR_DEFLECTION,
                              LINEAR_DEFLECTION_RANGE)

    linear_help = "STEP/IGES faceting: largest facet-to-surface distance, as a fraction of the part's diagonal"
    angular_help = "STEP/IGES faceting: largest angle (radians) between neighbouring facets"
    if not defaults:  # build: the store's own, else the defaults
        linear_help += f" [default: the store's, else {DEFAULT_LINEAR_DEFLECTION}]."
        angular_help += f" [default: the store's, else {DEFAULT_ANGULAR_DEFLECTION}]."

    def decorate(command):
        command = click.option("--angular-deflection", type=click.FloatRange(*ANGULAR_DEFLECTION_RANGE),
                               default=DEFAULT_ANGULAR_DEFLECTION if defaults else None, show_default=defaults,
                               help=angular_help + ("." if defaults else ""))(command)
        return click.option("--linear-deflection", type=click.FloatRange(*LINEAR_DEFLECTION_RANGE),
                            default=DEFAULT_LINEAR_DEFLECTION if defaults else None, show_default=defaults,
                            help=linear_help + ("." if defaults else ""))(command)

    return decorate


@main.command(context_settings=CONTEXT)
@click.argument("file")
@_deflection_options(defaults=True)
@json_option
def inspect(file, linear_deflection, angular_deflection, as_json):
    """What the loader sees in FILE: size, shells, watertightness, warnings (and the
    faceting, for STEP and IGES: tolerances, triangles, measured chordal error).

    \b
    Example:
      shapeidx inspect bracket.stl
      shapeidx inspect bracket.stl --json | jq .triangles
    """
    from .api import load
    from .io import LoadLimits
    from .io.faceting import Faceting

    faceting = Faceting(linear_deflection, angular_deflection)
    facts = load(file, limits=LoadLimits(faceting=faceting)).describe()
    if facts["format"] in ("step", "iges"):  # read again to measure the faceting against the exact surfaces
        from .io.step import faceting_report

        facts["faceting"] = faceting_report(file, faceting)
    if as_json:
        emit_json(facts)
        return
    lo, hi = facts["bounds"]
    click.echo(f"{printable(file)}")
    click.echo(f"  format      {facts['format']}, {facts['polygons']:,} polygons -> {facts['triangles']:,} triangles")
    click.echo(f"  area        {facts['area']:.6g}")
    volume = "n/a (not watertight)" if facts["volume"] is None else f"{facts['volume']:.6g}"
    click.echo(f"  volume      {volume}")
    click.echo(f"  size        {hi[0] - lo[0]:.6g} x {hi[1] - lo[1]:.6g} x {hi[2] - lo[2]:.6g}")
    solid = facts["solid"]
    click.echo(
        f"  shells      {facts['shells']} read; {solid['closed_shells']} closed, {solid['open_shells']} open,"
        f" {solid['cavities']} cavities{', united' if solid['united'] else ''}"
    )
    if solid["walls_removed"]:
        click.echo(f"  walls       {solid['walls_removed']:,} triangles where separately written bodies touch, removed")
    click.echo(f"  watertight  {'yes' if facts['watertight'] else 'no'}")
    if "faceting" in facts:
        f = facts["faceting"]
        units = ", ".join(f["file_units"]) or "not stated"
        click.echo(f"  faceting    linear deflection {f['linear_deflection']:g} of the diagonal ({f['deflection_mm']:.4g} mm),"
                   f" angular {f['angular_deflection']:g} rad -> {f['triangles']:,} triangles")
        click.echo(f"  chordal     measured max {f['max_chordal_error_mm']:.4g} mm ({f['max_chordal_error']:.3g} of the diagonal)"
                   f" at {f['measured_points']:,} points of curved faces")
        click.echo(f"  units       file: {units}; coordinates in mm")
        if f.get("faces_unwound"):
            faces = f"{f['faces_unwound']:,} face" + ("s" if f["faces_unwound"] != 1 else "")
            click.echo(f"  repaired    {faces} going round their surface more than once, meshed as one turn")
    for warning in facts["warnings"]:
        click.echo(f"  warning     {warning}")


@main.command(context_settings=CONTEXT)
@click.argument("file")
@points_option
@seed_option
@json_option
def signature(file, points, seed, as_json):
    """The IN/OUT/MIXED D2 signature of FILE.

    \b
    Example:
      shapeidx signature bracket.stl --points 512
      shapeidx signature bracket.wrl --json > bracket.json
    """
    from .api import load, signature as signature_of

    solid = load(file)
    sig = signature_of(solid, points, seed)
    if as_json:
        emit_json({**sig.to_dict(), "mesh": solid.describe()})
        return
    fractions = sig.fractions
    click.echo(f"{printable(file)}: {points} points, {sig.histograms['all'].total:,} pairs, seed {seed}")
    click.echo("  " + "  ".join(f"{name.upper()} {100 * share:5.1f}%" for name, share in fractions.items()))
    for name, h in sig.histograms.items():
        click.echo(f"  {name:6s} mean {h.mean:10.4g}  bin {h.bin_width:10.4g}  {len(h.counts):4d} bins")
    if not solid.watertight:
        click.echo("  note: not watertight; inside/outside judged by generalized winding numbers")


@main.command(context_settings=CONTEXT)
@click.argument("a")
@click.argument("b")
@points_option
@seed_option
@format_options
@click.option("--sheet", type=click.Path(dir_okay=False, path_type=str), help="Also write an HTML sheet of the two parts.")
def compare(a, b, points, seed, output_format, as_json, sheet):
    """Every distance between parts A and B (0 = same shape): the paper's four, then ours.

    \b
    Example:
      shapeidx compare a.wrl b.wrl
      shapeidx compare a.stl b.stl --format csv
    """
    from .api import signature as signature_of
    from .distance import compare as distances_between

    fmt = chosen_format(output_format, as_json)
    sig_a, sig_b = signature_of(a, points, seed), signature_of(b, points, seed)
    distances = distances_between(sig_a, sig_b)
    if sheet:
        from .pictures.sheet import compare_sheet

        compare_sheet(sheet, a, b, sig_a, sig_b, distances)
        click.echo(f"shapeidx: wrote {sheet}", err=True)
    if fmt == "json":
        emit_json({"a": a, "b": b, **distances, "fractions": {"a": sig_a.fractions, "b": sig_b.fractions}})
        return
    if fmt != "table":
        emit_rows(fmt, ["metric", "distance"], [{"metric": m, "distance": d} for m, d in distances.items()])
        return
    from .distance.metrics import label

    width = max(len(label(name)) for name in distances) + 2
    for name, value in distances.items():
        click.echo(f"{label(name):{width}s} {value:.6g}")


# --------------------------------------------------------------------------- the store

store_option = click.option(
    "--store",
    default=DEFAULT_STORE,
    show_default=True,
    envvar=STORE_ENV,
    show_envvar=True,
    help="The signature store (HDF5 file).",
)
#: Exit status of ``build --strict`` when the store holds failed files.
EXIT_FAILED_FILES = exits.FAILED_FILES


def _size(n: int) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000


def _store_path(store):
    from .store.check import usable_store_path

    return usable_store_path(store)


@main.command(context_settings=CONTEXT)
@click.argument("directory")
@store_option
@click.option("--points", type=click.IntRange(2, 8192), help="Surface samples [default: the store's, else 1024].")
@_deflection_options(defaults=False)
@click.option("--seed", type=click.IntRange(0, MAX_SEED), help="Sampling seed, >= 0 [default: the store's, else the fixed default].")
@click.option("--workers", "-j", type=click.IntRange(1), help="Worker processes [default: one per core].")
@click.option("--full", is_flag=True, help="Recompute every file, changed or not.")
@click.option("--rehash", is_flag=True, help="Hash every file, even when its size and time are unchanged.")
@click.option("--retry-failed", is_flag=True, help="Try failed files again even if unchanged.")
@click.option("--timeout", type=FiniteFloat(0), default=DEFAULT_TIMEOUT, show_default=True,
              help="Seconds one file may take before it is recorded as failed (0: no limit).")
@click.option("--worker-memory", type=click.FloatRange(0), metavar="GIB",
              help="Memory limit of each worker process in GiB; a file that needs more fails as out of memory "
                   "(0: no limit) [default: its share of 80% of the memory, at most 8].")
@click.option("--commit-interval", type=FiniteFloat(0.05), default=DEFAULT_COMMIT_INTERVAL, show_default=True,
              help="Seconds between commits: the most work a crash can lose.")
@click.option("--wait", is_flag=True, help="If another build holds the store, wait for it instead of exiting.")
@click.option("--wait-timeout", type=FiniteFloat(0), metavar="SECONDS",
              help=f"Wait at most this long for another build's lock (implies --wait), then exit {exits.LOCKED}.")
@click.option("--strict", is_flag=True, help=f"Exit with status {EXIT_FAILED_FILES} if the store holds failed files.")
@click.option("--repair", is_flag=True, help="Rebuild the damaged entries of a damaged store (see shapeidx check).")
@click.option("--follow-outside-links", is_flag=True,
              help="Also follow symbolic links that lead out of DIRECTORY (not followed by default).")
@click.option("--metadata", metavar="TABLE.csv",
              help="A CSV joined to the parts for --where: a path column (path, file or filename) and any others"
                   " (part number, material, project, ...). Read again by every build given it; no part is signed"
                   " again for it. Without it the store keeps the table it has.")
@click.option("--parts", is_flag=True,
              help="Also sign each file's sub-parts (the solids of a STEP assembly, the bodies of a mesh) as entries"
                   " FILE#n of their own, for where-used and query --parts (docs/assemblies.md).")
@click.option("--quiet", "-q", is_flag=True, help="Print only warnings, errors and files that failed for the first time.")
@click.option("--verbose", "-v", is_flag=True, help="A line per indexed file and per commit.")
@click.option("--dry-run", is_flag=True, help="Only say what a build would do: walk and plan, change nothing.")
@json_option
@click.option("--scheduler", envvar="SHAPEIDX_SCHEDULER", metavar="ADDRESS",
              help="Index the files on this dask.distributed cluster (env SHAPEIDX_SCHEDULER) [default: locally].")
@click.option("--worker-root", metavar="PATH", help="Where the cluster's workers see DIRECTORY [default: the same path].")
@click.option("--shards", type=click.IntRange(1), metavar="N",
              help="Shard the store by path key into N ordinary stores (STORE/shards/K); with --scheduler each"
                   " shard is built on a worker of the cluster. A sharded store is queried as one (docs/scaling.md).")
@click.option("--merge-after", type=click.IntRange(1), default=MERGE_AFTER, hidden=True)
@click.pass_context
def build(ctx, directory, store, points, seed, linear_deflection, angular_deflection, workers, full, rehash,
          retry_failed, timeout, worker_memory, commit_interval, wait, wait_timeout, strict, repair,
          follow_outside_links, metadata, parts, quiet, verbose, dry_run, as_json, scheduler, worker_root, shards,
          merge_after):
    """Index every part file under DIRECTORY into the store (incremental).

    \b
    Example:
      shapeidx build parts/ --store parts.shapeidx
      shapeidx build parts/ --store parts.shapeidx -q --strict   # in a crontab
      shapeidx build parts/ --store parts.shapeidx --metadata parts.csv
    """
    from .index.build import BuildOptions, run_build
    from .index.progress import BuildReporter, duration

    options = BuildOptions(points=points, seed=seed, workers=workers or 0, full=full, rehash=rehash,
                           retry_failed=retry_failed, timeout=timeout, wait=wait or wait_timeout is not None,
                           wait_timeout=wait_timeout, commit_interval=commit_interval, merge_after=merge_after,
                           dry_run=dry_run, repair=repair, follow_outside_links=follow_outside_links,
                           linear_deflection=linear_deflection, angular_deflection=angular_deflection,
                           worker_memory=None if worker_memory is None else int(worker_memory * (1 << 30)),
                           scheduler=scheduler or None, worker_root=worker_root, metadata=metadata, parts=parts)
    reporter = BuildReporter(quiet=quiet, verbose=verbose)
    store_path = _store_path(store)
    try:
        from .store.shards import is_sharded

        if shards or is_sharded(store_path):
            from .index.shards import run_sharded_build
            from .store.shards import shard_count

            summary = run_sharded_build(directory, store_path, options, reporter,
                                        shards or shard_count(store_path))
        else:
            summary = run_build(directory, store_path, options, reporter)
    finally:
        reporter.close()
    if as_json:
        emit_json(summary.to_dict(store_path, dry_run))
    elif dry_run:
        from .index.plan import older_words

        older = sum(summary.older.values())
        click.echo(f"shapeidx build: would index {summary.planned - older} new or changed"
                   + (f", {older_words(summary.older)}" if older else "")
                   + f", {summary.unchanged} unchanged, remove {summary.removed}"
                   + (f"; sub-parts: make those of {summary.parts_planned} files"
                      + (f" ({older_words(summary.older_parts, 'made')})" if summary.older_parts else "")
                      + f", remove {summary.parts_removed} sub-entries" if summary.parts_planned is not None else "")
                   + " (dry run: nothing changed)")
    elif not quiet:
        click.echo(
            f"shapeidx build: {summary.line()} in {duration(summary.seconds)};"
            f" store: {summary.store_ok} ok, {summary.store_failed} failed, {_size(summary.store_bytes)}"
            + (f"; parts: {summary.parts_indexed} signed"
               + (f", {summary.parts_removed} removed" if summary.parts_removed else "")
               + f", {summary.parts_entries} in the store"
               if summary.parts_entries is not None else "")
            + summary.older_line()
        )
    if strict and summary.store_failed:
        reporter.say(
            f"exit status {EXIT_FAILED_FILES} (--strict): the store holds {summary.store_failed} failed file(s);"
            f" 'shapeidx stats --failed --store {printable(str(store_path))}' lists them"
        )
        ctx.exit(EXIT_FAILED_FILES)


def metric_option(task: str, choices=None):
    """``--metric``: its choices, help and ``task``'s default come from the metric registry
    (shapeidx.distance.metrics)."""
    return click.option("--metric", type=click.Choice(choices or METRICS), default=default_metric(task),
                        show_default=True, help=metric_help())


where_option = click.option(
    "--where", "where", multiple=True, metavar="COND",
    help="Only entries whose metadata satisfy COND: KEY=VALUE, KEY!=VALUE, KEY<N, KEY<=N, KEY>N, KEY>=N,"
         " KEY~GLOB, KEY!~GLOB (keys: the build's --metadata table, title, product_id, path). Repeatable:"
         " all must hold.")


@main.command(context_settings=CONTEXT)
@click.argument("files", nargs=-1, metavar="[FILE|DIR|-]...")
@store_option
@click.option("--top", "-k", default=10, show_default=True, type=click.IntRange(1), help="How many hits per query.")
@metric_option("query")
@click.option("--id", "entries", metavar="PATH", multiple=True,
              help="Query with an entry of the store: its path relative to the indexed folder, or a path"
                   " (absolute or from here) of a file inside it. May be repeated.")
@click.option("--type", "file_type", type=click.Choice(PART_FORMATS), metavar="FORMAT",
              help=f"Format of '-' (standard input): {', '.join(PART_FORMATS)}.")
@where_option
@click.option("--exclude-self", is_flag=True, help="Leave out the query's own entry when it is in the store.")
@click.option("--max-distance", type=FiniteFloat(0), metavar="D", help="Leave out hits farther than D.")
@click.option("--scale", type=click.Choice(("invariant", "sensitive")), default="invariant", show_default=True,
              help="sensitive: leave out parts whose size differs by more than a factor 2 (docs/families.md).")
@click.option("--same-part", is_flag=True,
              help="Ask 'is this the same part?': order the hits by the distance and the gap of the exact"
                   " measures (size in any unit, proportions, area), which no sampling noise blurs"
                   " (docs/sampling.md); each hit shows its shape_gap.")
@click.option("--relative", is_flag=True, help="Print paths relative to the indexed folder (table, csv, tsv).")
@click.option("--parts", is_flag=True,
              help="Rank the store's sub-parts (FILE#n, built with build --parts) instead of its files; each hit"
                   " names its parent file and how many times that file holds it.")
@format_options
@click.option("--sheet", metavar="OUT.html",
              help="Also write the answer as one self-contained HTML file (thumbnails, histograms, words).")
@click.option("--thumbnails", default=200, show_default=True, type=click.IntRange(0),
              help="With --sheet: thumbnails for the first N hits (each new one is rendered and cached).")
@click.option("--scheduler", metavar="ADDRESS",
              help="A sharded store (build --shards): rank each shard on a worker of this dask.distributed"
                   " cluster and merge their exact top k [default: here, shard by shard].")
def query(files, store, top, metric, entries, file_type, where, exclude_self, max_distance, scale, same_part, relative,
          parts, output_format, as_json, sheet, thumbnails, scheduler):
    """The store's parts nearest to each FILE (or every part of DIR, or '-': a part on
    standard input; or --id PATH), nearest first: one result block per query.

    Exits 6 when a query has no hit (filters that match nothing, --max-distance), saying why.

    \b
    Example:
      shapeidx query bracket.stl --store parts.shapeidx --top 5
      shapeidx query bracket.stl --store parts.shapeidx --where material=steel --where 'revision>=3'
      shapeidx query new-parts/ --store parts.shapeidx --exclude-self --format csv
      shapeidx query export-2017.wrl --store parts.shapeidx --same-part --metric all-angle
      cat part.stl | shapeidx query - --type stl --json
      shapeidx query --id Battery/holder.wrl --metric combined-angle --sheet holder.html
    """
    from .console.queries import query_inputs
    from .errors import LoadError, NoAnswer, ShapeidxError, StoreDamagedError
    from .search import Filters, open_searcher, parse_where
    from .system import available_cores

    fmt = chosen_format(output_format, as_json)
    if not files and not entries:
        raise click.UsageError("give either FILE or --id PATH")
    if file_type and "-" not in files:
        raise click.UsageError("--type names the format of '-' (standard input); give '-' or leave --type out")
    several = len(files) + len(entries) > 1 or any(f != "-" and os.path.isdir(f) for f in files)
    if sheet and several:
        raise click.UsageError("--sheet draws one query: give one FILE, one '-' or one --id PATH")
    if sheet and not os.path.isdir(os.path.dirname(os.path.abspath(sheet))):
        from .errors import ShapeidxError

        raise ShapeidxError(f"{sheet}: no folder {os.path.dirname(os.path.abspath(sheet))} to write the sheet in")
    filters = Filters(exclude_self, max_distance, scale, parse_where(where), same_part)
    store_path = _store_path(store)
    failures = empty = 0
    blocks = []
    with open_searcher(store_path, scheduler or None, parts=parts) as searcher:
        inputs = query_inputs(files, [searcher.resolve_entry(e) for e in entries], file_type)
        keys = searcher.present_metadata_keys() if fmt in ("csv", "tsv") else ()
        for number, item in enumerate(inputs):
            try:
                if item.entry is not None:
                    question = searcher.query_of_entry(item.entry)
                else:  # a one-off query shares its ray queries among all cores
                    question = searcher.query_of_part(item.part, file_type if item.label == "-" else None,
                                                      label=item.label, threads=available_cores())
                answer = searcher.search(question, top, metric, filters)
            except StoreDamagedError:
                raise
            except (LoadError, ShapeidxError) as exc:
                if not several:
                    raise
                click.echo(_error_line(exc), err=True)
                failures += 1
                continue
            if answer.reason is not None:
                empty += 1
                if not several and fmt == "table" and not sheet:
                    raise NoAnswer(f"no answer for {item.label}: {answer.reason}")
                click.echo(f"shapeidx: no answer for {printable(item.label)}: {answer.reason}", err=True)
            if sheet:
                from .pictures.sheet import answer_sheet

                answer_sheet(searcher, answer, question, sheet, thumbnails)
                click.echo(f"shapeidx: wrote {sheet}", err=True)
            block = answer.to_dict()
            if answer.reason is not None:
                block["reason"] = answer.reason
            _print_block(block, fmt, several, first=number == 0, relative=relative, keys=keys, parts=parts,
                         same_part=same_part)
            if fmt == "json":
                blocks.append(block)
    if fmt == "json":
        emit_json(blocks if several else blocks[0] if blocks else {})
    if failures:
        sys.exit(exits.ERROR)
    if empty:
        sys.exit(exits.NO_ANSWER)


QUERY_COLUMNS = ["query", "rank", "distance", "path", "relative_path"]


PART_COLUMNS = ["parent", "count"]


def _print_block(block: dict, fmt: str, several: bool, first: bool, relative: bool, keys=(), parts: bool = False,
                 same_part: bool = False) -> None:
    if fmt == "json":
        return
    columns = QUERY_COLUMNS + (PART_COLUMNS if parts else []) + (["shape_gap"] if same_part else [])
    named = {key: (key if key not in columns + ["metric"] else f"metadata.{key}") for key in keys}
    rows = [{"query": block["query"], **{k: v for k, v in hit.items() if k != "metadata"},
             **{named[key]: hit["metadata"].get(key, "") for key in keys}} for hit in block["hits"]]
    if fmt == "jsonl":
        emit_rows(fmt, columns, [{**row, "metric": block["metric"]} for row in rows])
        return
    if relative:
        rows = [{**row, "path": row["relative_path"]} for row in rows]
    if fmt in ("csv", "tsv"):
        emit_rows(fmt, columns + list(named.values()), rows, header=first)
        return
    if several:
        click.echo(("" if first else "\n") + f"query {printable(block['query'])}")
    for row, hit in zip(rows, block["hits"]):
        shown = "  ".join(f"{key}={printable(value)}" for key, value in hit["metadata"].items())
        if parts:  # the sub-part first: the path is its file
            shown = f"part={printable(hit['relative_path'])} x{hit['count']}" + (f"  {shown}" if shown else "")
        if same_part and hit.get("shape_gap") is not None:
            shown = f"shape_gap={hit['shape_gap']:.3g}" + (f"  {shown}" if shown else "")
        click.echo(f"{row['rank']:>4}  {row['distance']:<11.6g} {printable(row['path'])}" + (f"  {shown}" if shown else ""))


@main.command("where-used", context_settings=CONTEXT)
@click.argument("part", required=False)
@store_option
@click.option("--id", "entry", metavar="PATH",
              help="Ask about an entry of the store instead of PART: a sub-part FILE#n, or a file of the indexed folder"
                   " (one part: its FILE#1; several: the whole file).")
@click.option("--top", "-k", default=10, show_default=True, type=click.IntRange(1), help="How many files.")
@metric_option("where-used")
@click.option("--max-distance", type=FiniteFloat(0), metavar="D",
              help="Only sub-parts within D; each file's count is then of all its sub-parts within D.")
@click.option("--scale", type=click.Choice(("sensitive", "invariant")), default="sensitive", show_default=True,
              help="sensitive: only sub-parts of PART's size (principal radii within --same-size); invariant: any size.")
@click.option("--same-size", type=FiniteFloat(0), default=0.05, show_default=True, metavar="SHARE",
              help="With --scale sensitive: the largest relative difference of principal radii.")
@format_options
@click.option("--sheet", metavar="OUT.html",
              help="Also write the answer as one self-contained HTML file (each file's picture, its nearest"
                   " sub-part and count).")
def where_used(part, store, entry, top, metric, max_distance, scale, same_size, output_format, as_json, sheet):
    """The files that hold a sub-part like PART (or --id PATH), nearest first: how far their
    nearest sub-part is, which it is, and how many times the file holds it. The store must be
    built with --parts (docs/assemblies.md).

    Exits 6 when no file answers (--max-distance), saying why.

    \b
    Example:
      shapeidx build library/ --store lib.shapeidx --parts
      shapeidx where-used pin.step --store lib.shapeidx --top 5
      shapeidx where-used --id Connector/conn_2x10.step#3 --store lib.shapeidx --max-distance 0.05 --format csv
      shapeidx where-used pin.step --store lib.shapeidx --sheet pin-uses.html
    """
    from .errors import NoAnswer
    from .search import open_searcher
    from .system import available_cores

    fmt = chosen_format(output_format, as_json)
    if bool(part) == bool(entry):
        raise click.UsageError("give either PART or --id PATH")
    if sheet and not os.path.isdir(os.path.dirname(os.path.abspath(sheet))):
        from .errors import ShapeidxError

        raise ShapeidxError(f"{sheet}: no folder {os.path.dirname(os.path.abspath(sheet))} to write the sheet in")
    with open_searcher(_store_path(store), parts=True) as searcher:
        if entry:
            question = searcher.question_of_entry(entry)
        else:
            question = searcher.query_of_part(part, label=part, threads=available_cores())
        answer = searcher.where_used(question, top, metric, max_distance, scale, same_size)
        if sheet:
            from .pictures.sheet import where_used_sheet

            where_used_sheet(searcher, answer, question, sheet)
            click.echo(f"shapeidx: wrote {sheet}", err=True)
    if answer.reason is not None:
        raise NoAnswer(f"no answer for {answer.query}: {answer.reason}")
    if fmt == "json":
        emit_json(answer.to_dict())
        return
    rows = [use.to_dict() for use in answer.uses]
    if fmt in ("csv", "tsv", "jsonl"):
        emit_rows(fmt, ["rank", "distance", "count", "path", "relative_path", "part", "title"],
                  [{**row, "parts": " ".join(row["parts"])} for row in rows])
        return
    for use in answer.uses:
        title = f"  title={printable(use.title)}" if use.title else ""
        click.echo(f"{use.rank:>4}  {use.distance:<11.6g} x{use.count:<4} {printable(use.path)}  part={printable(use.part)}{title}")


@main.command(context_settings=CONTEXT)
@click.argument("parts", nargs=-1)
@click.option("--output", "-o", required=True, type=click.Path(dir_okay=False, path_type=str),
              help="The figure: .png, .svg or .pdf.")
@click.option("--id", "entries", multiple=True, metavar="PATH", help="An entry of --store (repeatable).")
@store_option
@click.option("--label", "labels", multiple=True, help="Names for the parts, in order: PARTS, then --id entries (repeatable).")
@click.option("--title", help="A first line for the figure's title.")
@click.option("--points", type=click.IntRange(2, 8192), help="Surface samples for PARTS [default: the store's with --id, else 1024].")
@click.option("--seed", type=click.IntRange(0, MAX_SEED),
              help="Sampling seed for PARTS [default: the store's with --id, else the fixed default].")
@click.option("--parts", "sub_parts", is_flag=True,
              help="--id names sub-parts of --store (FILE#n, a store built with build --parts).")
def plot(parts, output, entries, store, labels, title, points, seed, sub_parts):
    """The ALL, IN, OUT and MIXED histograms of PARTS (and --id entries), overlaid (the paper's Figure 3/4).

    \b
    Example:
      shapeidx plot a.wrl b.wrl -o ab.png
      shapeidx plot --id Battery/holder.wrl --id Battery/clip.wrl --store parts.shapeidx -o pair.pdf
      shapeidx plot --id boards/six.step#2 --store lib.shapeidx --parts -o pin.png
    """
    from .api import signature as signature_of
    from .pictures.plot import check_format, labels_for, plot_signatures

    check_format(output)
    if not parts and not entries:
        raise click.UsageError("give one or more PARTS or --id PATH")
    if len(labels) > len(parts) + len(entries):
        raise click.UsageError(f"{len(labels)} --label for {len(parts) + len(entries)} parts")
    if sub_parts and not entries:
        raise click.UsageError("--parts names the sub-parts that --id gives: give --id FILE#n")
    signatures = []
    if entries:
        from .search import open_searcher

        with open_searcher(_store_path(store), parts=sub_parts) as searcher:
            stored = [searcher.query_of_entry(entry).signature for entry in entries]
            points, seed = points or searcher.params.points, searcher.params.seed if seed is None else seed
    for part in parts:
        signatures.append(signature_of(part, points or DEFAULT_POINTS, DEFAULT_SEED if seed is None else seed))
    if entries:
        signatures += stored
    names = list(labels) + labels_for(list(parts) + list(entries))[len(labels):]
    plot_signatures(list(zip(names, signatures)), output, title)
    click.echo(f"wrote {output}")


@main.command(context_settings=CONTEXT)
@store_option
@click.option("--failed", "list_failed", is_flag=True, help="List every failed file with its reason.")
@format_options
def stats(store, list_failed, output_format, as_json):
    """Entries by status, parameters and size of the store (of every shard of a sharded store).

    \b
    Example:
      shapeidx stats --store parts.shapeidx
      shapeidx stats --store parts.shapeidx --failed --format tsv
    """
    from .store import describe_store, open_store
    from .store.reader import member_stores
    from .store.shards import is_sharded
    from .store.stats import describe_sharded

    fmt = chosen_format(output_format, as_json)
    store_path = _store_path(store)
    if is_sharded(store_path):
        facts = describe_sharded(store_path)
        failed = []
        if list_failed:
            for path in (p for p in member_stores(store_path) if p.exists()):  # a shard not built yet: none
                with open_store(path) as reader:
                    failed += _failed_entries(reader)
    else:
        with open_store(store_path) as reader:
            facts = describe_store(reader)
            failed = _failed_entries(reader) if list_failed else None
    if list_failed:
        if not failed:
            click.echo(f"shapeidx: no failed file in {printable(facts['store'])} ({facts['entries']:,} entries)", err=True)
        if fmt == "json":
            emit_json({"store": facts["store"], "root": facts["root"], "failed": failed})
        elif fmt == "table":
            for item in failed:
                click.echo(f"{printable(item['path'])}: {item['reason']}")
        else:
            emit_rows(fmt, ["path", "relative_path", "reason"], failed)
        return
    if fmt == "json":
        emit_json(facts)
        return
    if fmt != "table":
        emit_rows(fmt, ["count", "reason"], facts["failure_reasons"])
        return
    p = facts["parameters"]
    click.echo(f"{facts['store']}: {_size(facts['bytes'])}, updated {facts['updated']}")
    click.echo(f"  root        {facts['root']}")
    click.echo(f"  entries     {facts['entries']:,}: {facts['ok']:,} ok, {facts['failed']:,} failed")
    if "shards" in facts:
        click.echo(f"  shards      {len(facts['shards']) + len(facts['shards_not_built'])} (build --shards): "
                   + ", ".join(f"{s['entries']:,}" for s in facts["shards"]) + " entries"
                   + ("; their parameters differ: shard 0's shown" if facts["parameters_differ"] else "")
                   + (f"; {len(facts['shards_not_built'])} not built yet (the next build makes them)"
                      if facts["shards_not_built"] else ""))
    click.echo(f"  parameters  {p['points']} points, bin divisor {p['bin_divisor']}, seed {p['seed']} ({p['seed_policy']})")
    click.echo(f"  faceting    STEP/IGES: linear deflection {p['linear_deflection']:g} of the diagonal,"
               f" angular {p['angular_deflection']:g} rad")
    click.echo(f"  versions    signature {p['signature_version']}, layout {facts['schema_version']},"
               f" shapeidx {facts['shapeidx_version']}")
    build = facts.get("build") or {}
    if build:
        state = build.get("state")
        counts = ", ".join(f"{build[k]:,} {k}" for k in ("indexed", "unchanged", "removed", "failed") if k in build)
        when = {"running": f"running since {build.get('started')} (pid {build.get('pid')} on {build.get('host')})",
                "finished": f"finished {build.get('at')}" + (f": {counts}" if counts else ""),
                "interrupted": f"interrupted {build.get('at')}, after committing its work; the next build goes on",
                "stopped": f"stopped before it finished (killed?), started {build.get('started')};"
                           " everything it committed is kept, the next build does the rest"}.get(state, state)
        click.echo(f"  last build  {when}")
    if facts["journal_batches"]:
        click.echo(f"  journal     {facts['journal_batches']} segment(s) beside the main file"
                   " (folded in as the store grows)")
    older = facts.get("older_reader") or {}
    if older:
        counts = ", ".join(f"{count:,} {label}" for label, count in older.items())
        click.echo(f"  readers     {counts} entries signed by an older reader: the next build signs them again")
    parts = facts.get("parts")
    if parts:
        click.echo(f"  sub-parts   {parts['entries']:,} entries ({parts['instances']:,} counted as the files hold them)"
                   f" of {parts['files']:,} files, {parts['several']:,} with several (build --parts; STORE/parts)")
    table = facts.get("metadata")
    if table:
        click.echo(f"  metadata    {table['rows']:,} rows, keys {', '.join(table['keys'])} (from {table['source']})")
    for item in facts["failure_reasons"][:5]:
        click.echo(f"  failed      {item['count']:>5}  {item['reason']}")
    if facts["failed"]:
        click.echo("  (shapeidx stats --failed lists every failed file)")


@main.command(context_settings=CONTEXT)
@store_option
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to listen on (the default: this machine only).")
@click.option("--port", default=8765, show_default=True, type=click.IntRange(1, 65535), help="Port to listen on.")
@click.option("--max-upload", default=64, show_default=True, type=click.IntRange(1), help="Largest part file accepted, MB.")
@click.option("--scheduler", metavar="ADDRESS",
              help="A sharded store (build --shards): rank each shard on a worker of this dask.distributed"
                   " cluster, kept open and warm there [default: here].")
def serve(store, host, port, max_upload, scheduler):
    """A local web page and JSON API over the store: query by example, compare, browse.

    \b
    Example:
      shapeidx serve --store parts.shapeidx                 # then open http://127.0.0.1:8765/
      shapeidx serve --store parts.shapeidx --port 9000 --max-upload 200
      shapeidx serve --store sharded.shapeidx --scheduler tcp://10.0.0.5:8786
    """
    from .errors import ShapeidxError

    try:
        import uvicorn

        from .web.app import create_app, open_service
    except ImportError as exc:
        raise ShapeidxError(f"shapeidx serve needs the web extra ({exc.name} is missing): pip install 'shapeidx[web]'") from None
    service = open_service(_store_path(store), scheduler or None)
    from .web.guard import header_timeout_protocol

    app = create_app(service, max_upload * 1024 * 1024, host=host)
    click.echo(f"shapeidx serve: {len(service.searcher):,} parts of {service.store} on http://{host}:{port}/ (Ctrl-C stops)")
    try:
        uvicorn.run(app, host=host, port=port, log_level="warning", access_log=False, http=header_timeout_protocol())
    finally:
        service.close()


def _failed_entries(reader) -> list[dict]:
    from .store import STATUS_FAILED

    root = reader.attrs.get("root") or ""
    status = reader.column("entries/status")
    reasons = reader.column("entries/reason")
    return [
        {"path": os.path.join(root, str(p)), "relative_path": str(p), "reason": plain_reason(r)}
        for p, r, s in zip(reader.paths, reasons, status)
        if s == STATUS_FAILED
    ]


main.add_command(click.Command("info", callback=stats.callback, params=stats.params,
                               help="Same as stats.\n\n\b\nExample:\n  shapeidx info --store parts.shapeidx",
                               context_settings=CONTEXT))


@main.command(context_settings=CONTEXT)
@store_option
@click.option("--files", "check_files", is_flag=True, help="Also hash every entry's file and compare with the store.")
@click.option("--repair", is_flag=True, help="Rebuild damaged or missing ranking arrays (written before layout 3) from the checked entries; takes the store's lock.")
@format_options
def check(store, check_files, repair, output_format, as_json):
    """Verify a store and its sub-parts (build --parts), or every shard of a sharded store (build
    --shards): structure, offsets, totals, checksums (and with --files, that every entry's file
    still hashes the same). Exits 5 naming the first problems. --repair rebuilds the ranking
    arrays (derived data) of files where they are damaged or missing.

    \b
    Example:
      shapeidx check --store parts.shapeidx
      shapeidx check --store parts.shapeidx --files --json
      shapeidx check --store parts.shapeidx --repair
    """
    from .store.check import check_store

    fmt = chosen_format(output_format, as_json)
    if repair:
        from .store.check import repair_ranking
        from .store.reader import member_stores

        path = _store_path(store)
        check_store(path)  # no store, not a store: one line, before taking the lock
        for one in member_stores(path):
            for line in repair_ranking(one):
                click.echo(line, err=True)
    report = check_store(_store_path(store), files=check_files)
    if fmt == "json":
        emit_json(report.to_dict())
    elif fmt != "table":
        emit_rows(fmt, ["file", "what", "problem"], [p.to_dict() for p in report.problems])
    else:
        for problem in report.problems[:20]:
            click.echo(f"problem: {problem.line()}", err=True)
        if len(report.problems) > 20:
            click.echo(f"problem: ... and {len(report.problems) - 20} more (--json lists all)", err=True)
        for note in report.notes:
            click.echo(f"note: {note}", err=True)
        click.echo(report.summary())
    if report.problems:
        sys.exit(exits.DAMAGED)



@main.command(context_settings=CONTEXT)
@click.argument("directory")
@store_option
@click.option("--metric", "metrics", multiple=True, type=click.Choice(METRICS),
              help="A distance to score, may be repeated [default: every one]. 'all' is the paper's ALL"
                   " distance (plain D2 of the ALL histograms), not every metric.")
@click.option("--per-class", is_flag=True, help="Also each class's figures.")
@click.option("--cross-validate", is_flag=True, help="Also learn the combined metric on this collection (class-wise cross-validated).")
@click.option("--points", type=click.IntRange(2, 8192), help="Surface samples for a new store [default: 1024].")
@click.option("--query-seed", "query_seeds", multiple=True, type=click.IntRange(0, MAX_SEED),
              help="Sign every query again with this seed, may be repeated (figures: the mean over the seeds; 'copy':"
                   " how often the query's own entry comes first) [default: the stored signatures, which share"
                   " their points with the entries].")
@click.option("--workers", "-j", type=click.IntRange(1), help="Worker processes for the build [default: one per core].")
@click.option("--quiet", "-q", is_flag=True, help="No build progress.")
@click.option("--follow-outside-links", is_flag=True, help="Also follow symbolic links that lead out of DIRECTORY.")
@format_options
def evaluate(directory, store, metrics, per_class, cross_validate, points, query_seeds, workers, quiet,
             follow_outside_links, output_format, as_json):
    """Retrieval quality on DIRECTORY, whose sub-folders are the classes: NN, FT, ST, E, DCG.

    Figures of the combined metric on the collection its weights were learned on are
    in-sample (they flatter) and marked so; --cross-validate gives honest ones.

    \b
    Example:
      shapeidx evaluate ../shared/data/kicad6 --store kicad6.h5
      shapeidx evaluate labelled/ --metric weighted --metric all --format csv
      shapeidx evaluate ../shared/data/kicad6 --query-seed 7 --query-seed 8 --query-seed 9
    """
    from .evaluation.evaluate import check_labelled_tree, evaluate as evaluate_store
    from .index.build import BuildOptions, run_build
    from .index.progress import BuildReporter
    from .distance.metrics import label as metric_label
    from .search import Searcher

    fmt = chosen_format(output_format, as_json)
    store_path = _store_path(store)
    check_labelled_tree(directory, follow_outside_links)  # before a store appears in the working directory
    reporter = BuildReporter(quiet=quiet)
    try:
        options = BuildOptions(points=points, workers=workers or 0, follow_outside_links=follow_outside_links)
        run_build(directory, store_path, options, reporter)
    finally:
        reporter.close()
    with Searcher(store_path) as searcher:
        result = evaluate_store(searcher, metrics or METRICS, per_class=per_class, cross_validated=cross_validate,
                                query_seeds=query_seeds)
    if fmt == "json":
        emit_json({"collection": directory, "store": str(store_path), **result})
        return
    scores = ("nn", "ft", "st", "e", "dcg") + (("copy", "copy_same_part") if query_seeds else ())
    family = ("knn", "nmi", "ari")  # classification and clustering agreement: the whole collection's only
    if fmt != "table":
        rows = []
        for name, figures in result["metrics"].items():
            rows.append({"metric": name, "class": "", **{s: figures.get(s, "") for s in scores},
                         **{s: figures.get(s, "") for s in family}, "in_sample": bool(figures.get("in_sample", False))})
            for cls, per in figures.get("per_class", {}).items():
                rows.append({"metric": name, "class": cls, **{s: per.get(s, "") for s in scores}, **{s: "" for s in family},
                             "in_sample": bool(figures.get("in_sample", False))})
        emit_rows(fmt, ["metric", "class", *scores, *family, "in_sample"], rows)
        return
    click.echo(
        f"{directory}: {result['models']} models in {result['classes']} classes, {result['points']} points"
        + (f" ({result['unlabelled']} files outside class folders left out)" if result["unlabelled"] else "")
    )
    labels = {name: metric_label(name) + (" (in-sample)" if figures.get("in_sample") else "")
              for name, figures in result["metrics"].items()}
    width = max([30, *map(len, labels.values())] + [len(c) + 2 for f in result["metrics"].values() for c in f.get("per_class", {})])
    if query_seeds:
        click.echo(f"queries signed again with seed {', '.join(map(str, query_seeds))} (figures: their mean);"
                   " copy: the query's own entry first; same: so in the same-part order (query --same-part)")
    heads = {"copy_same_part": "SAME"}
    click.echo(f"{'distance':{width}s} " + " ".join(f"{heads.get(s, s.upper()):>6s}" for s in scores)
               + f"   {'kNN':>6s} {'NMI':>6s} {'ARI':>6s}")
    for name, figures in result["metrics"].items():
        agreement = "   " + " ".join(f"{figures[s]:6.3f}" for s in family) if "knn" in figures else ""
        click.echo(f"{labels[name]:{width}s} " + " ".join(_figure(figures.get(s)) for s in scores) + agreement)
        for cls, per in figures.get("per_class", {}).items():
            click.echo(f"  {printable(cls):{width - 2}s} " + " ".join(_figure(per.get(s)) for s in scores))
    for name, figures in result["metrics"].items():
        if figures.get("in_sample"):
            click.echo(f"note: {metric_label(name)}'s weights were learned on this collection"
                       f" ({figures['learned_on']}): its figures are in-sample and flatter it;"
                       + (" its (cross-validated) row gives out-of-sample ones" if cross_validate
                          else " --cross-validate gives out-of-sample ones"))


def _figure(value) -> str:
    """A score in evaluate's table (a dash where a row has none: a cross-validated row's copy)."""
    return f"{value:6.3f}" if value is not None else f"{'-':>6s}"


# --------------------------------------------------------------------------- families (classify, cluster, duplicates)

scale_option = click.option(
    "--scale", type=click.Choice(("invariant", "sensitive")), default="invariant", show_default=True,
    help="invariant: the paper's (size does not count); sensitive: parts whose sizes differ by more than"
         " a factor 2 are kept apart.")


def _family_table(store, metric=None, parts: bool = False):
    """The store's ok entries (``parts``: sub-entries) for pair work (the histograms ``metric``
    reads; all without one), with one line on stderr for an old store's missing columns."""
    from .distance import METRIC_HISTOGRAMS
    from .families.table import FamilyTable
    from .signing.parameters import HISTOGRAMS

    table = FamilyTable.load_store(_store_path(store), METRIC_HISTOGRAMS[metric] if metric else HISTOGRAMS, parts)
    if table.missing_columns:
        only_axial = table.missing_columns == ["entries/axial_handedness"]
        what = ("the axial handedness column", "the mirroring of parts with two principal radii alike") if only_axial \
            else ("the size and handedness columns", "sizes and mirroring")
        click.echo(f"shapeidx: warning: {_store_path(store)} predates {what[0]} ({', '.join(table.missing_columns)}):"
                   f" {what[1]} unknown for its older entries; rebuild with 'shapeidx build DIR --full' to fill them",
                   err=True)
    return table


def _table_keep(store, table, where, parts: bool = False):
    """``--where`` as a keep-mask over the table's entries (None: no condition)."""
    if not where:
        return None
    import numpy as np

    from .search import Searcher, parse_where
    from .search.where import keep_mask
    from .store.reader import member_stores

    kept = set()
    for one in member_stores(_store_path(store), parts):  # a sharded store: each shard's metadata
        with Searcher(one) as searcher:
            mask = keep_mask(parse_where(where), searcher.metadata_column, searcher.metadata_keys())
            if mask is None:
                return None
            kept.update(map(str, searcher.metadata_column("path")[mask]))
    return np.array([str(p) in kept for p in table.paths], dtype=bool)


def _empty_store_error(store, parts: bool = False):
    """No entry to work on: no answer (status 6), with why (as the search road says it)."""
    from .errors import NoAnswer
    from .search import open_searcher

    with open_searcher(_store_path(store), parts=parts) as searcher:  # a sharded store: every shard's rows
        return NoAnswer(f"store {_store_path(store)} has no indexed entries: {searcher.empty_reason()}")


@main.command(context_settings=CONTEXT)
@click.argument("parts", nargs=-1, required=True)
@store_option
@click.option("--k", "-k", "k", default=None, type=click.IntRange(1), help="Voters [default: 3, measured on kicad6].")
@metric_option("classify")
@click.option("--label-depth", default=1, show_default=True, type=click.IntRange(1),
              help="An entry's label is its first N folders.")
@click.option("--labels", "labels_file", metavar="FILE.csv",
              help="CSV of path,label (paths as in the store) instead of folders.")
@where_option
@scale_option
@click.option("--parts", "sub_parts", is_flag=True,
              help="Vote with the store's sub-parts (FILE#n, a store built with build --parts) instead of its files:"
                   " labelled by their file's folders, or by --labels rows naming FILE#n; a file of the tree is"
                   " not voted for by its own sub-parts.")
@format_options
def classify(parts, store, k, metric, label_depth, labels_file, where, scale, sub_parts, output_format, as_json):
    """The category of each PART (a file, or a path of the store) by its nearest labelled entries.

    \b
    Example:
      shapeidx classify new/bracket.stl --store parts.shapeidx
      shapeidx classify new/*.wrl --store parts.shapeidx --labels categories.csv --json
      shapeidx classify new/bracket.stl --store parts.shapeidx --where 'project!=legacy'
      shapeidx classify pin.step --store lib.shapeidx --parts
    """
    from .families.classify import DEFAULT_K, classify_parts
    from .families.labels import labels_from_csv, labels_from_paths
    from .search import Filters, open_searcher, parse_where
    from .system import available_cores

    filters = Filters(scale=scale, where=parse_where(where))
    with open_searcher(_store_path(store), parts=sub_parts) as searcher:
        if len(searcher) == 0:
            raise _empty_store_error(store, sub_parts)
        paths = searcher.entry_paths()
        if labels_file:
            labels, unknown = labels_from_csv(labels_file, paths)
            if unknown:
                click.echo(f"shapeidx: warning: {labels_file}: {len(unknown)} path(s) not in the store, ignored"
                           f" (first: {unknown[0]!r})", err=True)
        else:
            labels = labels_from_paths(paths, label_depth)
        results = classify_parts(searcher, list(parts), dict(zip(paths, labels)), k or DEFAULT_K, metric, filters,
                                 available_cores())
    fmt = chosen_format(output_format, as_json)
    if fmt == "json":
        emit_json(results)
        return
    if fmt != "table":
        emit_rows(fmt, ["path", "label", "confidence"], results)
        return
    width = max([5] + [len(printable(nb["label"])) for r in results for nb in r["neighbours"]])
    for r in results:
        label = r["label"] if r["label"] is not None else "(no voter)"
        click.echo(f"{printable(r['path'])}: {printable(label)} (confidence {r['confidence']:.2f})")
        if r["neighbours"]:
            click.echo(f"    {'distance':<11s} {'label':{width}s}  voter")
        for nb in r["neighbours"]:
            click.echo(f"    {nb['distance']:<11.6g} {printable(nb['label']):{width}s}  {printable(nb['path'])}")


@main.command(context_settings=CONTEXT)
@store_option
@click.option("--clusters", type=click.IntRange(1), help="How many clusters [default: one per ten entries].")
@click.option("--threshold", type=click.FloatRange(0),
              help="Cut Ward's tree at this height instead (in units of the distance; beyond 4,000 entries"
                   " inside each family of the neighbour graph).")
@metric_option("cluster")
@where_option
@scale_option
@click.option("--csv", "as_csv", is_flag=True, help="Rows of path,cluster,distance.")
@click.option("--plot", "plot_output", metavar="OUT", type=click.Path(dir_okay=False, path_type=str),
              help="Also draw the clusters to OUT (.png, .svg or .pdf): the dendrogram, or beyond the exact"
                   " matrix's size a 2-D embedding.")
@click.option("--parts", is_flag=True,
              help="Group the store's sub-parts (FILE#n, a store built with build --parts) instead of its files.")
@format_options
def cluster(store, clusters, threshold, metric, where, scale, as_csv, plot_output, parts, output_format, as_json):
    """Group the whole store into families of similar parts.

    Up to 4,000 entries Ward's clustering of the exact distances; above, Leiden's communities of
    each entry's nearest neighbours, split further by exact Ward (docs/families.md).

    \b
    Example:
      shapeidx cluster --store parts.shapeidx --clusters 50
      shapeidx cluster --store parts.shapeidx --threshold 40 --format csv
      shapeidx cluster --store parts.shapeidx --where 'path~Connector*' --plot families.png
      shapeidx cluster --store lib.shapeidx --parts --clusters 20
    """
    from .families.cluster import cluster_store
    from .system import available_cores

    if plot_output:
        from .pictures.plot import check_format

        check_format(plot_output)  # before the work, not after it
    table = _family_table(store, metric, parts)
    keep = _table_keep(store, table, where, parts)
    if len(table) == 0 or (keep is not None and not keep.any()):
        raise _empty_store_error(store, parts) if len(table) == 0 else _no_entry_kept(where)
    if keep is not None:
        table = table.subset(keep)
    result = cluster_store(table, metric, clusters, threshold, scale, threads=available_cores())
    if plot_output:
        from .families.cluster_plot import plot_clusters

        drawn = plot_clusters(result, table, plot_output, metric)
        click.echo(f"wrote {plot_output} ({drawn})", err=True)  # stderr: stdout stays the rows
    rows = [{"path": str(p), "cluster": int(c), "distance": float(d)}
            for p, c, d in sorted(zip(result["paths"], result["clusters"], result["distances"]), key=lambda r: (r[1], r[2], r[0]))]
    fmt = "csv" if as_csv and output_format is None else chosen_format(output_format, as_json)
    if fmt == "json":
        emit_json(rows)
    elif fmt != "table":
        emit_rows(fmt, ["path", "cluster", "distance"], rows)
    else:
        click.echo(f"{len(rows)} entries in {result['count']} clusters ({metric}, {result['road']})")
        for r in rows:
            click.echo(f"{r['cluster']:>6}  {r['distance']:<11.6g} {printable(r['path'])}")


def _no_entry_kept(where):
    from .errors import NoAnswer

    return NoAnswer(f"no entry of the store satisfies --where {' '.join(where)}")


@main.command(context_settings=CONTEXT)
@store_option
@metric_option("duplicates", choices=duplicate_metrics())  # only metrics whose duplicate thresholds were measured
@click.option("--similar", "with_similar", is_flag=True,
              help="Also report tier similar: one body whose details (pins, pitch) may differ; measured imprecise,"
                   " docs/duplicates.md.")
@click.option("--near", "with_near", is_flag=True,
              help="Also report tiers similar and near (near duplicates: measured less precise still).")
@where_option
@scale_option
@click.option("--parts", is_flag=True,
              help="Groups of sub-parts (a store built with build --parts) shared by several files, one of them an"
                   " assembly: the same pin in two connectors; each group names its files. Files that are each"
                   " one part are whole-file duplicates: duplicates without --parts reports them.")
@click.option("--csv", "as_csv", is_flag=True, help="One row per member (same as --format csv).")
@format_options
def duplicates(store, metric, with_similar, with_near, where, scale, parts, as_csv, output_format, as_json):
    """Groups of entries that are one part: identical files (tier identical), the same surface at
    one size or in other units, which each member's row names (same), or one part written by two
    programs, in two file formats or two units (converted); most confident groups first.

    Every member is within the tier's thresholds of its group's first member, the
    representative. Only reports: nothing is deleted or moved.

    \b
    Example:
      shapeidx duplicates --store parts.shapeidx
      shapeidx duplicates --store parts.shapeidx --similar --csv > duplicates.csv
      shapeidx duplicates --store parts.shapeidx --scale sensitive --where 'path~Resistor*'
    """
    from .families.duplicates import DEFAULT_TIERS, find_duplicates, shared_sub_parts
    from .system import available_cores

    table = _family_table(store, metric, parts)
    keep = _table_keep(store, table, where, parts)
    if len(table) == 0 or (keep is not None and not keep.any()):
        raise _empty_store_error(store, parts) if len(table) == 0 else _no_entry_kept(where)
    tiers = DEFAULT_TIERS + (("similar", "near") if with_near else ("similar",) if with_similar else ())
    if parts:
        from .store import open_store
        from .store.reader import member_stores

        parent_of, count_of = {}, {}
        for member in member_stores(_store_path(store), parts=True):  # each shard's sub-parts
            with open_store(member) as reader:
                parent_of.update(zip(reader.paths.tolist(), reader.column("entries/parent").tolist()))
                count_of.update(zip(reader.paths.tolist(), reader.column("entries/count").tolist()))
        groups = shared_sub_parts(table, [parent_of[p] for p in table.paths], metric, scale, threads=available_cores(),
                                  tiers=tiers, keep=keep, counts=[count_of[p] for p in table.paths])
    else:
        groups = find_duplicates(table, metric, scale, threads=available_cores(), tiers=tiers, keep=keep)
    fmt = "csv" if as_csv and output_format is None else chosen_format(output_format, as_json)
    if fmt == "json":
        emit_json(groups)
        return
    if fmt != "table":
        emit_rows(fmt, ["group", "confidence", "a", "b", "tier", "distance", "size_ratio", "unit", "mirrored"],
                  [{"group": g, "confidence": group["confidence"], **p}
                   for g, group in enumerate(groups, start=1) for p in group["pairs"]])
        return
    members = sum(len(g["members"]) for g in groups)
    click.echo(f"{len(groups)} group(s) of duplicates, {members} entries, among {len(table)} entries"
               f" ({metric}; tiers {', '.join(tiers)}; most confident first)")
    def size_of(p):
        ratio = "?" if p["size_ratio"] is None else f"x{p['size_ratio']:.4g}"
        return ratio + (f" (unit factor {p['unit']:.4g})" if p.get("unit") else "")

    pairs = [p for group in groups for p in group["pairs"]]
    tier_width = max([4] + [len(p["tier"]) for p in pairs])
    size_width = max([4] + [len(size_of(p)) for p in pairs])
    for g, group in enumerate(groups, start=1):
        click.echo(f"group {g}: {len(group['members'])} parts, {group['tier']}, confidence {group['confidence']:.2f}:"
                   f" {printable(group['representative'])}"
                   + (f" (in {len(group['files'])} files)" if "files" in group else ""))
        click.echo(f"  {'tier':{tier_width}s}  {'distance':<10s} {'size':{size_width}s}  {'mirrored':8s}  part")
        for p in group["pairs"]:
            click.echo(f"  {p['tier']:{tier_width}s}  {p['distance']:<10.4g} {size_of(p):{size_width}s}"
                       f"  {'yes' if p['mirrored'] else '':8s}  {printable(p['b'])}")


@main.command("check-new", context_settings=CONTEXT)
@click.argument("paths", nargs=-1)
@store_option
@click.option("--git", "git_rev", metavar="REV",
              help="Check the part files that a commit (REV) or a range (A..B) added or changed; ':staged' for the"
                   " files staged for the next commit (a pre-commit hook).")
@click.option("--exclude-self", is_flag=True,
              help="Leave each file's own entry out of the answer: the file checked as new against the store"
                   " without it (leave one out).")
@click.option("--look-alikes", default=5, show_default=True, type=click.IntRange(0),
              help="Nearest look-alikes (not duplicates) reported per new part.")
@metric_option("check-new", choices=duplicate_metrics())  # the tiers need measured thresholds
@click.option("--sheet", "sheet", metavar="OUT.html", help="Also write the answers as an HTML sheet with pictures.")
@click.option("--parts", is_flag=True,
              help="Look for each file among the store's sub-parts (FILE#n, a store built with build --parts): is the"
                   " new part already a part of a library file? Tiers by geometry alone (a sub-part holds its"
                   " file's hash); --exclude-self leaves out the file's own sub-parts.")
@format_options
def check_new(paths, store, git_rev, exclude_self, look_alikes, metric, sheet, parts, output_format, as_json):
    """Is each new or changed part file already in the library? For each, the store's parts that
    are the same part (tiers identical, same, converted, as duplicates says them: size ratio, unit
    factor, mirror flag) and, apart, its nearest look-alikes worth reusing.

    A file the store holds under the same path with the same content is not news (unchanged).
    Exit status: 0 nothing found, 7 a duplicate found, 1 a file or the store could not be used,
    5 a damaged store (docs/checkin.md).

    \b
    Example:
      shapeidx check-new new/Resistor_0603.wrl --store library.shapeidx
      shapeidx check-new --git origin/main..HEAD --store library.shapeidx --format json
      shapeidx check-new new/pin.step --store library.shapeidx --parts
    """
    from .errors import LoadError, ShapeidxError, StoreDamagedError, StoreLockedError
    from .families.checkin import Checker, git_changed

    files = list(paths)
    if git_rev:
        files += git_changed(git_rev)
    if not files:
        if git_rev:
            click.echo(f"shapeidx: check-new: no part file added or changed in {git_rev}", err=True)
            return
        raise click.UsageError("give PATH... or --git REV")
    reports, failed = [], False
    with Checker(_store_path(store), metric=metric, parts=parts) as checker:
        if sheet:
            from .pictures.sheet import check_sheet_folder

            check_sheet_folder(sheet)  # before any part is checked
        for path in files:
            try:
                if not os.path.isfile(path):
                    raise LoadError(path, "no such file" if not os.path.exists(path) else "not a regular file")
                reports.append(checker.check(path, exclude_self=exclude_self, look_alikes=look_alikes))
            except (StoreDamagedError, StoreLockedError):
                raise
            except (ShapeidxError, OSError) as exc:
                failed = True
                line = _error_line(exc)
                if printable(path) not in line:
                    line = line.replace("shapeidx: error: ", f"shapeidx: error: {printable(path)}: ", 1)
                click.echo(line, err=True)
                reports.append({"file": path, "status": "error", "reason": plain_reason(exc),
                                "duplicates": [], "look_alikes": []})
        if sheet:
            from .pictures.sheet import check_new_sheet

            click.echo(f"wrote {check_new_sheet(checker.searcher, reports, sheet, checker.metric)}", err=True)
    fmt = chosen_format(output_format, as_json)
    if fmt == "json":
        emit_json(reports)
    elif fmt != "table":
        rows = [{"file": r["file"], "status": r["status"], "kind": kind, "tier": h["tier"], "distance": h["distance"],
                 "size_ratio": h["size_ratio"], "unit": h["unit"], "mirrored": h["mirrored"], "path": h["path"]}
                for r in reports for kind in ("duplicates", "look_alikes") for h in r[kind]]
        rows += [{"file": r["file"], "status": r["status"], "kind": "", "tier": "", "distance": "", "size_ratio": "",
                  "unit": "", "mirrored": "", "path": ""} for r in reports if not r["duplicates"] and not r["look_alikes"]]
        emit_rows(fmt, ["file", "status", "kind", "tier", "distance", "size_ratio", "unit", "mirrored", "path"], rows)
    else:
        def size_of(h):
            ratio = "?" if h["size_ratio"] is None else f"x{h['size_ratio']:.4g}"
            return ratio + (f" (unit factor {h['unit']:.4g})" if h.get("unit") else "") + (" mirrored" if h["mirrored"] else "")

        for r in reports:
            if r["status"] == "error":
                continue
            if r["status"] == "unchanged":
                click.echo(f"{printable(r['file'])}: unchanged (the store holds it under this path, same content)")
                continue
            head = "ALREADY IN THE LIBRARY" if r["duplicates"] else "new"
            click.echo(f"{printable(r['file'])}: {head}")
            for h in r["duplicates"]:
                click.echo(f"  duplicate  {h['tier']:10s} {h['distance']:<10.4g} {size_of(h)}  {printable(h['path'])}"
                           f"  ({h['words']})")
            for h in r["look_alikes"]:
                tier = "" if h["tier"] == "look-alike" else h["tier"]  # a plain look-alike: no tier to say
                click.echo(f"  look-alike {tier:10s} {h['distance']:<10.4g} {size_of(h)}  {printable(h['path'])}"
                           f"  ({h['words']})")
    if failed:
        sys.exit(exits.ERROR)
    if any(r["duplicates"] for r in reports):
        sys.exit(exits.DUPLICATES)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
