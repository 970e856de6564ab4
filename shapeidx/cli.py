"""The ``shapeidx`` command: click commands only; the work is in the library."""

from __future__ import annotations

import json
import os
import sys

import click

from . import __version__
from .errors import ShapeidxError
from .pipeline import DEFAULT_POINTS, signature_of_solid, solid_of_file
from .sampling import DEFAULT_SEED


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
    facts = solid_of_file(file).describe()
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
    solid = solid_of_file(file)
    sig = signature_of_solid(solid, points, seed)
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

    sig_a = signature_of_solid(solid_of_file(a), points, seed)
    sig_b = signature_of_solid(solid_of_file(b), points, seed)
    distances = distances_between(sig_a, sig_b)
    if as_json:
        _emit_json({"a": a, "b": b, **distances, "fractions": {"a": sig_a.fractions, "b": sig_b.fractions}})
        return
    for name, label in (("all", "ALL (plain D2)"), ("avg3", "AvgOf3"), ("avg4", "AvgOf4"), ("weighted", "Weighted")):
        click.echo(f"{label:15s} {distances[name]:.6g}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
