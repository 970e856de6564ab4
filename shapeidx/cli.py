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


@main.command()
@click.argument("file", type=click.Path(path_type=str))
@json_option
def inspect(file, as_json):
    """What the loader sees in FILE: size, shells, watertightness, warnings."""
    facts = load(file).describe()
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
def compare(a, b, points, seed, as_json):
    """The paper's four distances between parts A and B (0 = same shape)."""
    from .distance import compare as distances_between

    sig_a, sig_b = signature_of(a, points, seed), signature_of(b, points, seed)
    distances = distances_between(sig_a, sig_b)
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
@click.option("--workers", "-j", type=click.IntRange(1), help="Worker processes [default: one per core].")
@click.option("--full", is_flag=True, help="Recompute every file, changed or not.")
@click.option("--rehash", is_flag=True, help="Hash every file, even when its size and time are unchanged.")
@click.option("--retry-failed", is_flag=True, help="Try failed files again even if unchanged.")
@click.option("--timeout", type=click.FloatRange(0), default=DEFAULT_TIMEOUT, show_default=True,
              help="Seconds one file may take before it is recorded as failed (0: no limit).")
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
def build(ctx, directory, store, points, seed, workers, full, rehash, retry_failed, timeout, commit_interval,
          wait, strict, quiet, verbose, dry_run, as_json, merge_after):
    """Index every part file under DIRECTORY into the store (incremental)."""
    options = BuildOptions(points=points, seed=seed, workers=workers or 0, full=full, rehash=rehash,
                           retry_failed=retry_failed, timeout=timeout, wait=wait,
                           commit_interval=commit_interval, merge_after=merge_after, dry_run=dry_run)
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
@click.option("--scale", type=click.Choice(("invariant", "sensitive")), default="invariant", show_default=True,
              help="sensitive: leave out parts whose size differs by more than a factor 2.")
@json_option
def query(file, store, top, metric, entry, scale, as_json):
    """The store's parts nearest to FILE (or to --id PATH), nearest first."""
    if (file is None) == (entry is None):
        raise click.UsageError("give either FILE or --id PATH")
    # a one-off query shares its ray queries among all cores
    hits = query_store(resolve_store_path(store), part=file, entry=entry, top=top, metric=metric, threads=available_cores(),
                       scale=scale)
    if as_json:
        _emit_json(hits)
        return
    for hit in hits:
        click.echo(f"{hit['rank']:>4}  {hit['distance']:<11.6g} {hit['path']}")


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
    click.echo(f"  versions    signature {p['signature_version']}, layout {facts['schema_version']},"
               f" shapeidx {facts['shapeidx_version']}")
    if facts["journal_batches"]:
        click.echo(f"  journal     {facts['journal_batches']} committed batch(es) not merged yet (a build runs or was stopped)")
    for item in facts["failure_reasons"][:5]:
        click.echo(f"  failed      {item['count']:>5}  {item['reason']}")


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
    click.echo(f"{'distance':30s} {'NN':>6s} {'FT':>6s} {'ST':>6s} {'E':>6s} {'DCG':>6s}   {'kNN':>6s} {'NMI':>6s} {'ARI':>6s}")
    for name, scores in result["metrics"].items():
        label = METRIC_LABELS.get(name, name)
        family = "   " + " ".join(f"{scores[s]:6.3f}" for s in ("knn", "nmi", "ari")) if "knn" in scores else ""
        click.echo(f"{label:30s} " + " ".join(f"{scores[s]:6.3f}" for s in ("nn", "ft", "st", "e", "dcg")) + family)
        for cls, figures in scores.get("per_class", {}).items():
            click.echo(f"  {cls[:28]:28s} " + " ".join(f"{figures[s]:6.3f}" for s in ("nn", "ft", "st", "e", "dcg")))


# --------------------------------------------------------------------------- families (classify, cluster, duplicates)

scale_option = click.option(
    "--scale", type=click.Choice(("invariant", "sensitive")), default="invariant", show_default=True,
    help="invariant: the paper's (size does not count); sensitive: parts whose sizes differ by more than"
         " a factor 2 are kept apart.")


def _family_table(store):
    """The store's ok entries for pair work, with one line on stderr for an old store's missing columns."""
    from .families.table import FamilyTable

    with open_store(resolve_store_path(store)) as reader:
        table = FamilyTable.load(reader)
    if table.missing_columns:
        click.echo(f"shapeidx: warning: {resolve_store_path(store)} predates the size and handedness columns"
                   f" ({', '.join(table.missing_columns)}): sizes and mirroring unknown for its older entries;"
                   " rebuild with 'shapeidx build DIR --full' to fill them", err=True)
    return table


def _empty_store_error(store):
    return ShapeidxError(f"store {resolve_store_path(store)} has no indexed entries (run 'shapeidx build DIR' first)")


@main.command()
@click.argument("parts", nargs=-1, required=True, type=click.Path(path_type=str))
@store_option
@click.option("--k", "-k", "k", default=None, type=click.IntRange(1), help="Voters [default: 3, measured on kicad6].")
@click.option("--metric", type=click.Choice(METRICS), default="combined", show_default=True, help="The distance.")
@click.option("--label-depth", default=1, show_default=True, type=click.IntRange(1),
              help="An entry's label is its first N folders.")
@click.option("--labels", "labels_file", type=click.Path(dir_okay=False, path_type=str),
              help="CSV of path,label (paths as in the store) instead of folders.")
@scale_option
@json_option
def classify(parts, store, k, metric, label_depth, labels_file, scale, as_json):
    """The category of each PART (a file, or a path of the store) by its nearest labelled entries."""
    from .families.classify import DEFAULT_K, classify_parts
    from .families.labels import labels_from_csv, labels_from_paths

    with open_store(resolve_store_path(store)) as reader:
        if (reader.column("entries/status") == 0).sum() == 0:
            raise _empty_store_error(store)
        if labels_file:
            labels, unknown = labels_from_csv(labels_file, reader.paths)
            if unknown:
                click.echo(f"shapeidx: warning: {labels_file}: {len(unknown)} path(s) not in the store, ignored"
                           f" (first: {unknown[0]!r})", err=True)
        else:
            labels = labels_from_paths(reader.paths, label_depth)
        results = classify_parts(reader, list(parts), labels, k or DEFAULT_K, metric, scale, available_cores())
    if as_json:
        _emit_json(results)
        return
    for r in results:
        label = r["label"] if r["label"] is not None else "(no voter)"
        click.echo(f"{r['path']}: {label} (confidence {r['confidence']:.2f})")
        for nb in r["neighbours"]:
            click.echo(f"    {nb['distance']:<11.6g} {nb['label']:24s} {nb['path']}")


@main.command()
@store_option
@click.option("--clusters", type=click.IntRange(1), help="How many clusters [default: one per ten entries].")
@click.option("--threshold", type=click.FloatRange(0), help="Cut the tree at this height instead.")
@click.option("--metric", type=click.Choice(METRICS), default="combined", show_default=True, help="The distance.")
@scale_option
@click.option("--csv", "as_csv", is_flag=True, help="Rows of path,cluster,distance.")
@json_option
def cluster(store, clusters, threshold, metric, scale, as_csv, as_json):
    """Group the whole store into families of similar parts."""
    from .families.cluster import cluster_store

    table = _family_table(store)
    if len(table) == 0:
        raise _empty_store_error(store)
    result = cluster_store(table, metric, clusters, threshold, scale, threads=available_cores())
    rows = [{"path": str(p), "cluster": int(c), "distance": float(d)}
            for p, c, d in sorted(zip(result["paths"], result["clusters"], result["distances"]), key=lambda r: (r[1], r[2], r[0]))]
    if as_json:
        _emit_json(rows)
    elif as_csv:
        _emit_csv(["path", "cluster", "distance"], ([r["path"], r["cluster"], f"{r['distance']:.6g}"] for r in rows))
    else:
        click.echo(f"{len(rows)} entries in {result['count']} clusters ({metric}, {result['road']})")
        for r in rows:
            click.echo(f"{r['cluster']:>6}  {r['distance']:<11.6g} {r['path']}")


def _emit_csv(header, rows) -> None:
    import csv

    writer = csv.writer(sys.stdout, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)


@main.command()
@store_option
@click.option("--metric", type=click.Choice(METRICS), default="combined", show_default=True, help="The distance.")
@scale_option
@click.option("--csv", "as_csv", is_flag=True, help="One row per pair.")
@json_option
def duplicates(store, metric, scale, as_csv, as_json):
    """Groups of entries that are the same part: identical file, same geometry, near duplicate.

    Only reports: nothing is deleted or moved.
    """
    from .families.duplicates import find_duplicates

    table = _family_table(store)
    if len(table) == 0:
        raise _empty_store_error(store)
    groups = find_duplicates(table, metric, scale, threads=available_cores())
    if as_json:
        _emit_json(groups)
        return
    if as_csv:
        _emit_csv(["group", "a", "b", "tier", "distance", "size_ratio", "mirrored"],
                  ([g, p["a"], p["b"], p["tier"], f"{p['distance']:.6g}",
                    "" if p["size_ratio"] is None else f"{p['size_ratio']:.6g}", str(p["mirrored"]).lower()]
                   for g, group in enumerate(groups, start=1) for p in group["pairs"]))
        return
    pairs = sum(len(g["pairs"]) for g in groups)
    click.echo(f"{len(groups)} group(s) of duplicates, {pairs} pair(s), among {len(table)} entries")
    for g, group in enumerate(groups, start=1):
        click.echo(f"group {g}: {len(group['members'])} parts")
        for p in group["pairs"]:
            ratio = "size ?" if p["size_ratio"] is None else f"size x{p['size_ratio']:.4g}"
            mirror = ", mirrored" if p["mirrored"] else ""
            click.echo(f"  {p['tier']:9s} {p['distance']:<10.4g} {ratio}{mirror}  {p['a']}  {p['b']}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
