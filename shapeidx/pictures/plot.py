"""The paper's Figure 3/4 layout: a part's ALL, IN, OUT and MIXED D2 histograms (matplotlib, Agg).

Four panels (ALL, IN / OUT, MIXED). Each histogram is drawn as probability per bin against
distance over the mean of its own set: bin k of a histogram holds distances in
``[k, k + 1) * mean / 50`` (``shapeidx.signature.BIN_DIVISOR``), so it is drawn at
``(k + 0.5) / 50``. This is the scale the paper's distances compare bin by bin, and it lets
parts of any size share one axis. Several parts are overlaid, each with its class fractions
in the panel legends; the paper's four distances between the parts head the figure.
"""

from __future__ import annotations

import os
from itertools import combinations
from pathlib import Path

import numpy as np

from ..distance import PAPER_METRICS, compare
from ..distance.metrics import label as metric_label
from ..signing.parameters import BIN_DIVISOR, HISTOGRAMS

#: Colours of the parts, in order (matplotlib's tab10, colour-blind tolerable pairs first).
COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf")
FORMATS = (".png", ".svg", ".pdf")


def histogram_curve(histogram, divisor: int = BIN_DIVISOR) -> tuple[np.ndarray, np.ndarray]:
    """(distance / mean at each bin centre, probability of each bin) of a Histogram."""
    p = histogram.p
    return (np.arange(len(p)) + 0.5) / divisor, p


def pair_distances(named: list) -> list[tuple[str, str, dict]]:
    """``(label a, label b, compare(a, b))`` for every pair of ``(label, Signature)``."""
    return [(a, b, compare(sa, sb)) for (a, sa), (b, sb) in combinations(named, 2)]


def distance_line(a: str, b: str, distances: dict, metrics=PAPER_METRICS) -> str:
    return f"{a} - {b}: " + ", ".join(f"{metric_label(m)} {distances[m]:.3g}" for m in metrics)


def figure_of(named: list, title: str | None = None, divisor: int = BIN_DIVISOR, size=(10.0, 7.5)):
    """A matplotlib Figure of the four histograms of each ``(label, Signature)`` in ``named``.

    Uses matplotlib's object API with the Agg canvas: no display and no global state.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    pairs = pair_distances(named)
    head = [title] if title else []
    head += [distance_line(a, b, d) for a, b, d in pairs[:10]]
    if len(pairs) > 10:
        head.append(f"... and {len(pairs) - 10} more pairs")
    head_inches = 0.19 * len(head) + 0.45  # the header lines, then the panel titles
    height = size[1] + head_inches
    fig = Figure(figsize=(size[0], height), layout=None)
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 2)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.6 / height, top=1 - head_inches / height, hspace=0.3, wspace=0.18)
    for ax, name in zip(axes.ravel(), HISTOGRAMS):
        reach = _common_reach(named, name, divisor)
        top = 0.0
        for k, (label, sig) in enumerate(named):
            x, p = histogram_curve(sig.histograms[name], divisor)
            f = sig.fractions
            if name == "all":
                share = f" (IN {100 * f['in']:.1f}%, OUT {100 * f['out']:.1f}%, MIXED {100 * f['mixed']:.1f}%)"
            else:
                share = f" ({100 * f[name]:.2f}%)"
            colour = COLOURS[k % len(COLOURS)]
            if len(p):
                ax.plot(x, p, color=colour, linewidth=1.3, label=f"{label}{share}", drawstyle="steps-mid")
                top = max(top, float(p.max()))
            else:
                ax.plot([], [], color=colour, label=f"{label}{share}, no pairs")
        ax.set_title(name.upper(), fontsize=11, fontweight="bold")
        ax.set_xlim(0, reach)
        ax.set_ylim(0, top * (1.12 + 0.07 * len(named)) if top else 1)  # room for the legend
        ax.set_xlabel("distance / mean distance of the set", fontsize=8)
        ax.set_ylabel("probability", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.25)
        ax.legend(fontsize=7, loc="upper right", frameon=False)
    if head:
        fig.text(0.5, 1 - 0.12 / height, "\n".join(head), ha="center", va="top", fontsize=8.5, linespacing=1.5)
    return fig


def _common_reach(named: list, name: str, divisor: int) -> float:
    """Distance / mean below which 99.9% of histogram ``name`` of every part lies (a panel's x range)."""
    reach = 2.0
    for _, sig in named:
        p = sig.histograms[name].p
        if len(p):
            reach = max(reach, (int(np.searchsorted(np.cumsum(p), 0.999)) + 1) / divisor)
    return min(reach * 1.03, 6.0)


def check_format(output: str | os.PathLike) -> Path:
    """``output`` as a Path when its suffix is a format we write (ShapeidxError otherwise)."""
    output = Path(output)
    if output.suffix.lower() not in FORMATS:  # a bad option value: a usage error (status 2)
        from ..errors import UsageError

        raise UsageError(f"{output}: unknown picture format {output.suffix!r}; use one of {', '.join(FORMATS)}")
    if not output.parent.is_dir():
        from ..errors import ShapeidxError

        raise ShapeidxError(f"{output}: no folder {output.parent} to write the figure in")
    return output


def plot_signatures(named: list, output: str | os.PathLike, title: str | None = None) -> Path:
    """Write the figure of ``named`` (``[(label, Signature), ...]``) to ``output``.

    The format follows the suffix: .png (150 dpi), .svg or .pdf.
    """
    output = check_format(output)
    fig = figure_of(named, title)
    from matplotlib import rc_context

    try:
        with rc_context({"svg.fonttype": "none", "svg.hashsalt": "shapeidx"}):  # SVG text stays text
            fig.savefig(output, dpi=150, format=output.suffix.lower()[1:], metadata=stable_metadata(output))
    except OSError as exc:
        from ..errors import ShapeidxError

        raise ShapeidxError(f"{output}: cannot write the figure ({exc.strerror or exc})") from None
    return output


def stable_metadata(output: Path) -> dict:
    """Matplotlib's ``metadata`` for ``output`` that leaves out the creation date."""
    # no creation date: the same parts give the same file (docs stay byte-stable)
    suffix = output.suffix.lower()
    if suffix == ".svg":
        return {"Date": None}
    if suffix == ".pdf":
        return {"CreationDate": None}
    return {}


def labels_for(paths: list[str]) -> list[str]:
    """Short labels for parts: file names, or more of the path where names repeat."""
    names = [Path(p).name for p in paths]
    if len(set(names)) == len(names):
        return names
    return [str(p) for p in paths]
