"""The ``shapeidx`` command: click commands only; the work is in the library."""

from __future__ import annotations

import json
import os
import sys

import click

from . import __version__
from .errors import ShapeidxError
from .system import available_cores, keep_freed_memory
from .index.build import BuildOptions, run_build
from .index.commit import DEFAULT_COMMIT_INTERVAL, MERGE_AFTER
from .distance import METRICS
from .api import load, signature as signature_of
from .signing.parameters import DEFAULT_POINTS, DEFAULT_SEED
from .index.progress import BuildReporter, duration
from .ranking import query_store
from .store import DEFAULT_STORE, STORE_ENV, describe_store, open_store, resolve_store_path
from .index.workers import DEFAULT_TIMEOUT


class _Group(click.Group):
    """Turns every shapeidx error into one line on stderr and exit status 1, never a traceback."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except ShapeidxError as exc:
            click.echo(f"shapeidx: error: {exc}", err=True)
            ctx.exit(1)
        except (click.exceptions.Exit, click.ClickException, click.Abort):
            raise
        except KeyboardInterrupt:
            click.echo("shapeidx: interrupted", err=True)
            ctx.exit(130)
        except Exception as exc:  # a bug: one line, unless debugging is asked for
            if os.environ.get("SHAPEIDX_DEBUG"):
                raise
            click.echo(f"shapeidx: internal error: {type(exc).__name__}: {exc} (set SHAPEIDX_DEBUG=1 for details)", err=True)
            ctx.exit(2)


@click.group(cls=_Group)
@click.version_option(__version__, prog_name="shapeidx")
def main():
    """Search CAD parts by shape: IN/OUT/MIXED D2 shape distributions (Ip et al. 2002)."""
    keep_freed_memory()


def _emit_json(data) -> None:
    click.echo(json.dumps(data, indent=2))


points_option = click.option(
    "--points", default=DEFAULT_POINTS, show_default=True, type=click.IntRange(2, 8192), help="Surface samples."
)
seed_option = click.option("--seed", default=DEFAULT_SEED, show_default=True, type=int, help="Sampling seed.")
json_option = click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")


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


@main.command()
@click.argument("file", type=click.Path(path_type=str))
@_deflection_options(defaults=True)
@json_option
def inspect(file, linear_deflection, angular_deflection, as_json):
    """What the loader sees in FILE: size, shells, watertightness, warnings (and faceting, for STEP/IGES)."""
    from .io import LoadLimits
    from .io.faceting import Faceting

    faceting = Faceting(linear_deflection, angular_deflection)
    facts = load(file, limits=LoadLimits(faceting=faceting)).describe()
    if facts["format"] in ("step", "iges"):  # read again to measure the faceting against the exact surfaces
        from .io.step import faceting_report

        facts["faceting"] = faceting_report(file, faceting)
    if as_json:
        _emit_json(facts)
        return
    lo, hi = facts["bounds"]
    click.echo(f"{file}")
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
    click.echo(f"  watertight  {'yes' if facts['watertight'] else 'no'}")
    if "faceting" in facts:
        f = facts["faceting"]
        units = ", ".join(f["file_units"]) or "not stated"
        click.echo(f"  faceting    linear deflection {f['linear_deflection']:g} of the diagonal ({f['deflection_mm']:.4g} mm),"
                   f" angular {f['angular_deflection']:g} rad -> {f['triangles']:,} triangles")
        click.echo(f"  chordal     measured max {f['max_chordal_error_mm']:.4g} mm ({f['max_chordal_error']:.3g} of the diagonal)"
                   f" at {f['measured_points']:,} points of curved faces")
        click.echo(f"  units       file: {units}; coordinates in mm")
    for warning in facts["warnings"]:
        click.echo(f"  warning     {warning}")


@main.command()
@click.argument("file", type=click.Path(path_type=str))
@points_option
@seed_option
@json_option
def signature(file, points, seed, as_json):
    """The IN/OUT/MIXED D2 signature of FILE."""
    solid = load(file)
    sig = signature_of(solid, points, seed)
    if as_json:
        _emit_json({**sig.to_dict(), "mesh": solid.describe()})
        return
    fractions = sig.fractions
    click.echo(f"{file}: {points} points, {sig.histograms['all'].total:,} pairs, seed {seed}")
    click.echo("  " + "  ".join(f"{name.upper()} {100 * share:5.1f}%" for name, share in fractions.items()))
    for name, h in sig.histograms.items():
        click.echo(f"  {name:6s} mean {h.mean:10.4g}  bin {h.bin_width:10.4g}  {len(h.counts):4d} bins")
    if not solid.watertight:
        click.echo("  note: not watertight; inside/outside judged by generalized winding numbers")


@main.command()
@click.argument("a", type=click.Path(path_type=str))
@click.argument("b", type=click.Path(path_type=str))
@points_option
@seed_option
@json_option
@click.option("--sheet", type=click.Path(dir_okay=False, path_type=str), help="Also write an HTML sheet of the two parts.")
def compare(a, b, points, seed, as_json, sheet):
    """The paper's four distances between parts A and B (0 = same shape)."""
    from .distance import compare as distances_between

    sig_a, sig_b = signature_of(a, points, seed), signature_of(b, points, seed)
    distances = distances_between(sig_a, sig_b)
    if sheet:
        from .pictures.sheet import compare_sheet

        compare_sheet(sheet, a, b, sig_a, sig_b, distances)
        click.echo(f"shapeidx: wrote {sheet}", err=True)
    if as_json:
        _emit_json({"a": a, "b": b, **distances, "fractions": {"a": sig_a.fractions, "b": sig_b.fractions}})
        return
    for name, label in (("all", "ALL (plain D2)"), ("avg3", "AvgOf3"), ("avg4", "AvgOf4"), ("weighted", "Weighted")):
        click.echo(f"{label:15s} {distances[name]:.6g}")


# --------------------------------------------------------------------------- the store

store_option = click.option(
    "--store",
    default=DEFAULT_STORE,
    show_default=True,
    envvar=STORE_ENV,
    show_envvar=True,
    type=click.Path(dir_okay=False, path_type=str),
    help="The signature store (HDF5 file).",
)
#: Exit status of ``build --strict`` when the store holds failed files.
EXIT_FAILED_FILES = 3


def _size(n: int) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000


@main.command()
@click.argument("directory", type=click.Path(file_okay=False, path_type=str))
@store_option
@click.option("--points", type=click.IntRange(2, 8192), help="Surface samples [default: the store's, else 1024].")
@click.option("--seed", type=int, help="Sampling seed [default: the store's, else the fixed default].")
@_deflection_options(defaults=False)
@click.option("--workers", "-j", type=click.IntRange(1), help="Worker processes [default: one per core].")
@click.option("--full", is_flag=True, help="Recompute every file, changed or not.")
@click.option("--rehash", is_flag=True, help="Hash every file, even when its size and time are unchanged.")
@click.option("--retry-failed", is_flag=True, help="Try failed files again even if unchanged.")
@click.option("--timeout", type=click.FloatRange(0), default=DEFAULT_TIMEOUT, show_default=True,
              help="Seconds one file may take before it is recorded as failed (0: no limit).")
@click.option("--worker-memory", type=click.FloatRange(0), metavar="GIB",
              help="Memory limit of each worker process in GiB; a file that needs more fails as out of memory "
                   "(0: no limit) [default: its share of 80% of the memory, at most 8].")
@click.option("--commit-interval", type=click.FloatRange(0.05), default=DEFAULT_COMMIT_INTERVAL, show_default=True,
              help="Seconds between commits: the most work a crash can lose.")
@click.option("--wait", is_flag=True, help="If another build holds the store, wait for it instead of exiting.")
@click.option("--strict", is_flag=True, help=f"Exit with status {EXIT_FAILED_FILES} if the store holds failed files.")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing but warnings and errors.")
@click.option("--verbose", "-v", is_flag=True, help="A line per indexed file and per commit.")
@click.option("--dry-run", is_flag=True, help="Only say what a build would do: walk and plan, change nothing.")
@json_option
@click.option("--merge-after", type=click.IntRange(1), default=MERGE_AFTER, hidden=True)
@click.pass_context
def build(ctx, directory, store, points, seed, linear_deflection, angular_deflection, workers, full, rehash,
          retry_failed, timeout, worker_memory, commit_interval, wait, strict, quiet, verbose, dry_run, as_json,
          merge_after):
    """Index every part file under DIRECTORY into the store (incremental)."""
    options = BuildOptions(points=points, seed=seed, workers=workers or 0, full=full, rehash=rehash,
                           linear_deflection=linear_deflection, angular_deflection=angular_deflection,
                           retry_failed=retry_failed, timeout=timeout, wait=wait,
                           commit_interval=commit_interval, merge_after=merge_after, dry_run=dry_run,
                           worker_memory=None if worker_memory is None else int(worker_memory * (1 << 30)))
    reporter = BuildReporter(quiet=quiet, verbose=verbose)
    store_path = resolve_store_path(store)
    try:
        summary = run_build(directory, store_path, options, reporter)
    finally:
        reporter.close()
    if as_json:
        _emit_json(summary.to_dict(store_path, dry_run))
    elif dry_run:
        click.echo(f"shapeidx build: would index {summary.planned} new or changed, {summary.unchanged} unchanged,"
                   f" remove {summary.removed} (dry run: nothing changed)")
    elif not quiet:
        click.echo(
            f"shapeidx build: {summary.line()} in {duration(summary.seconds)};"
            f" store: {summary.store_ok} ok, {summary.store_failed} failed, {_size(summary.store_bytes)}"
        )
    if strict and summary.store_failed:
        ctx.exit(EXIT_FAILED_FILES)


@main.command()
@click.argument("file", required=False, type=click.Path(dir_okay=False, path_type=str))
@store_option
@click.option("--top", "-k", default=10, show_default=True, type=click.IntRange(1), help="How many hits.")
@click.option("--metric", type=click.Choice(METRICS), default="weighted", show_default=True, help="The distance.")
@click.option("--id", "entry", metavar="PATH", help="Query with an entry of the store (its path in the store).")
@json_option
@click.option("--sheet", type=click.Path(dir_okay=False, path_type=str),
              help="Also write the answer as one self-contained HTML file (thumbnails, histograms, words).")
@click.option("--thumbnails", default=200, show_default=True, type=click.IntRange(0),
              help="With --sheet: thumbnails for the first N hits (each new one is rendered and cached).")
def query(file, store, top, metric, entry, as_json, sheet, thumbnails):
    """The store's parts nearest to FILE (or to --id PATH), nearest first."""
    if (file is None) == (entry is None):
        raise click.UsageError("give either FILE or --id PATH")
    if sheet:
        from .pictures.sheet import query_sheet

        hits = query_sheet(resolve_store_path(store), sheet, file=file, entry=entry, top=top, metric=metric,
                           thumbnails=thumbnails, threads=available_cores())
        click.echo(f"shapeidx: wrote {sheet}", err=True)
    else:
        hits = query_store(resolve_store_path(store), part=file, entry=entry, top=top, metric=metric,
                           threads=available_cores())
    if as_json:
        _emit_json(hits)
        return
    for hit in hits:
        click.echo(f"{hit['rank']:>4}  {hit['distance']:<11.6g} {hit['path']}")


@main.command()
@click.argument("parts", nargs=-1, type=click.Path(dir_okay=False, path_type=str))
@click.option("--output", "-o", required=True, type=click.Path(dir_okay=False, path_type=str),
              help="The figure: .png, .svg or .pdf.")
@click.option("--id", "entries", multiple=True, metavar="PATH", help="An entry of --store (repeatable).")
@store_option
@click.option("--label", "labels", multiple=True, help="Names for the parts, in order: PARTS, then --id entries (repeatable).")
@click.option("--title", help="A first line for the figure's title.")
@click.option("--points", type=click.IntRange(2, 8192), help="Surface samples for PARTS [default: the store's with --id, else 1024].")
@click.option("--seed", type=int, help="Sampling seed for PARTS [default: the store's with --id, else the fixed default].")
def plot(parts, output, entries, store, labels, title, points, seed):
    """The ALL, IN, OUT and MIXED histograms of PARTS (and --id entries), overlaid (the paper's Figure 3/4)."""
    from .pictures.plot import check_format, labels_for, plot_signatures

    check_format(output)
    if not parts and not entries:
        raise click.UsageError("give one or more PARTS or --id PATH")
    if len(labels) > len(parts) + len(entries):
        raise click.UsageError(f"{len(labels)} --label for {len(parts) + len(entries)} parts")
    signatures = []
    if entries:
        from .pictures.similarity import signatures_of
        from .store import STATUS_OK

        with open_store(resolve_store_path(store)) as reader:
            rows = []
            for entry in entries:
                i = reader.index_of(entry)
                if i is None:
                    raise ShapeidxError(f"no entry {entry!r} in {reader.path} (give the path relative to the indexed folder)")
                if reader.column("entries/status")[i] != STATUS_OK:
                    raise ShapeidxError(f"entry {entry!r} failed to index: {reader.column('entries/reason')[i]}")
                rows.append(i)
            stored = signatures_of(reader, rows)
            points, seed = points or reader.params.points, reader.params.seed if seed is None else seed
    for part in parts:
        signatures.append(signature_of(part, points or DEFAULT_POINTS, DEFAULT_SEED if seed is None else seed))
    if entries:
        signatures += stored
    names = list(labels) + labels_for(list(parts) + list(entries))[len(labels):]
    plot_signatures(list(zip(names, signatures)), output, title)
    click.echo(f"wrote {output}")


@main.command()
@store_option
@json_option
def stats(store, as_json):
    """Entries by status, parameters and size of the store."""
    with open_store(resolve_store_path(store)) as reader:
        facts = describe_store(reader)
    if as_json:
        _emit_json(facts)
        return
    p = facts["parameters"]
    click.echo(f"{facts['store']}: {_size(facts['bytes'])}, updated {facts['updated']}")
    click.echo(f"  root        {facts['root']}")
    click.echo(f"  entries     {facts['entries']:,}: {facts['ok']:,} ok, {facts['failed']:,} failed")
    click.echo(f"  parameters  {p['points']} points, bin divisor {p['bin_divisor']}, seed {p['seed']} ({p['seed_policy']})")
    click.echo(f"  faceting    STEP/IGES: linear deflection {p['linear_deflection']:g} of the diagonal,"
               f" angular {p['angular_deflection']:g} rad")
    click.echo(f"  versions    signature {p['signature_version']}, layout {facts['schema_version']},"
               f" shapeidx {facts['shapeidx_version']}")
    if facts["journal_batches"]:
        click.echo(f"  journal     {facts['journal_batches']} committed batch(es) not merged yet (a build runs or was stopped)")
    for item in facts["failure_reasons"][:5]:
        click.echo(f"  failed      {item['count']:>5}  {item['reason']}")


@main.command()
@store_option
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to listen on (the default: this machine only).")
@click.option("--port", default=8765, show_default=True, type=click.IntRange(1, 65535), help="Port to listen on.")
@click.option("--max-upload", default=64, show_default=True, type=click.IntRange(1), help="Largest part file accepted, MB.")
def serve(store, host, port, max_upload):
    """A local web page and JSON API over the store: query by example, compare, browse."""
    try:
        import uvicorn

        from .web.app import StoreService, create_app
    except ImportError as exc:
        raise ShapeidxError(f"shapeidx serve needs the web extra ({exc.name} is missing): pip install 'shapeidx[web]'") from None
    service = StoreService(resolve_store_path(store))
    app = create_app(service, max_upload * 1024 * 1024)
    click.echo(f"shapeidx serve: {len(service.table):,} parts of {service.store} on http://{host}:{port}/ (Ctrl-C stops)")
    try:
        uvicorn.run(app, host=host, port=port, log_level="warning", access_log=False)
    finally:
        service.close()


main.add_command(click.Command("info", callback=stats.callback, params=stats.params, help="Same as stats."))


METRIC_LABELS = {"all": "ALL (plain D2)", "avg3": "AvgOf3", "avg4": "AvgOf4", "weighted": "Weighted", "combined": "combined"}


@main.command()
@click.argument("directory", type=click.Path(file_okay=False, path_type=str))
@store_option
@click.option("--metric", "metrics", multiple=True, type=click.Choice(METRICS), help="Distances to score [default: all].")
@click.option("--per-class", is_flag=True, help="Also each class's figures.")
@click.option("--cross-validate", is_flag=True, help="Also learn the combined metric on this collection (class-wise cross-validated).")
@click.option("--points", type=click.IntRange(2, 8192), help="Surface samples for a new store [default: 1024].")
@click.option("--workers", "-j", type=click.IntRange(1), help="Worker processes for the build [default: one per core].")
@click.option("--quiet", "-q", is_flag=True, help="No build progress.")
@json_option
def evaluate(directory, store, metrics, per_class, cross_validate, points, workers, quiet, as_json):
    """Retrieval quality on DIRECTORY, whose sub-folders are the classes: NN, FT, ST, E, DCG."""
    from .evaluation.evaluate import evaluate as evaluate_store

    store_path = resolve_store_path(store)
    reporter = BuildReporter(quiet=quiet)
    try:
        run_build(directory, store_path, BuildOptions(points=points, workers=workers or 0), reporter)
    finally:
        reporter.close()
    with open_store(store_path) as reader:
        result = evaluate_store(reader, metrics or METRICS, per_class=per_class, cross_validated=cross_validate)
    if as_json:
        _emit_json({"collection": directory, "store": str(store_path), **result})
        return
    click.echo(
        f"{directory}: {result['models']} models in {result['classes']} classes, {result['points']} points"
        + (f" ({result['unlabelled']} files outside class folders left out)" if result["unlabelled"] else "")
    )
    click.echo(f"{'distance':30s} {'NN':>6s} {'FT':>6s} {'ST':>6s} {'E':>6s} {'DCG':>6s}")
    for name, scores in result["metrics"].items():
        label = METRIC_LABELS.get(name, name)
        click.echo(f"{label:30s} " + " ".join(f"{scores[s]:6.3f}" for s in ("nn", "ft", "st", "e", "dcg")))
        for cls, figures in scores.get("per_class", {}).items():
            click.echo(f"  {cls[:28]:28s} " + " ".join(f"{figures[s]:6.3f}" for s in ("nn", "ft", "st", "e", "dcg")))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
