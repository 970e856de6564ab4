"""The metric registry: one record per distance, everything else derives from it.

A :class:`Metric` says what a distance is called (``--metric`` name, label, one line of what
it is for), what it reads (the D2 histograms and per-pair features its formula combines,
whether it needs the normal-angle histograms), how it is computed (its formula over
per-pair features, so one function serves a pair and a whole store), whether a coarse
lower bound can rule entries out (the candidate step of a query), its first-order terms
(what the all-pairs candidate step embeds), which learned weights it uses, which tasks it is
the default of (:func:`default_metric`), and whether ``duplicates`` has measured thresholds
for it. The command line's choices, defaults and help, the web page's menu and default, the
labels of every table and sheet, and the metric table of docs/cli.md are made from
:data:`REGISTRY`; tests check that they are and that no other module names a default.

This module imports nothing heavy (the command line reads it to build ``--help``): a
formula names the module and function that computes it, imported on first use.
"""

from __future__ import annotations

import importlib
import json
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

#: The D2 histograms, in the order the store keeps them (= shapeidx.signing.parameters.HISTOGRAMS).
_HISTOGRAMS = ("all", "in", "out", "mixed")
_CLASSES = _HISTOGRAMS[1:]
#: all-angle = D(ALL) + this times the L1 distance of the ALL angle histograms. Chosen on half A
#: of the KiCad 2017 / KiCad 6 twin pairs (scripts/twin_study.py; docs/twins.md gives half B).
ALL_ANGLE_WEIGHT = 5e-4
#: What a metric is chosen for when none is named: each task's default is the metric whose
#: :attr:`Metric.defaults` names it (docs/results.md and docs/unified.md measured the choice).
TASKS = ("query", "compare", "where-used", "duplicates", "check-new", "classify", "cluster")


@dataclass(frozen=True)
class Metric:
    """One distance between signatures.

    Attributes
    ----------
    name : str
        What ``--metric`` takes.
    label : str
        What tables, sheets and the web page call it.
    summary : str
        One line: what it is and when to use it (``--help``, the web menu, docs/cli.md).
    histograms : tuple of str
        The D2 histograms whose ``D`` it reads (ranking skips the others).
    features : tuple of str
        The per-pair features (:data:`shapeidx.distance.FEATURES`, angle features) its
        formula combines.
    angles : bool
        Whether it needs the normal-angle histograms (stores built before them are refused).
    sizes : bool
        Whether it reads the parts' exact sizes (their principal radii): then it is not
        scale-invariant, and a part and its copy in other units are far apart.
    paper : bool
        One of the paper's four distances, exactly as Ip et al. (2002) define them.
    formula : str
        ``"module:function"`` (relative to this package) computing it from a dict of
        features (numbers, or arrays with one value per pair).
    bounded : bool
        Its formula never decreases when a histogram's ``D`` grows, so a lower bound of
        every ``D`` (the coarse histograms of ``rank/``) with the other features exact gives
        a lower bound of the distance, and a query computes exact distances only for the
        entries the bound cannot rule out.
    learned : str or None
        The file of learned weights it reads (shipped as package data), if any.
    defaults : tuple of str
        The tasks (:data:`TASKS`) that use it when no ``--metric`` is given: every command,
        the API, the web page and the scripts ask :func:`default_metric`, never a name.
    learned_from : str or None
        For a metric made on a learned one (unified on combined-angle), that metric: its
        weights are the ones learned (and checked in-sample by ``evaluate``) for it.
    linear : tuple of (str, float)
        For a metric with no learned weights, the weight of each per-pair feature in its
        first-order form (:attr:`terms`).
    """

    name: str
    label: str
    summary: str
    histograms: tuple
    features: tuple
    formula: str
    angles: bool = False
    sizes: bool = False
    paper: bool = False
    bounded: bool = True
    learned: str | None = None
    defaults: tuple = ()
    learned_from: str | None = None
    linear: tuple = ()

    def value(self, features: dict):
        """The distance from per-pair ``features``."""
        module, function = self.formula.split(":")
        return getattr(importlib.import_module(module, __package__), function)(features)

    @property
    def weights_of(self) -> str | None:
        """The learned metric whose weights this one uses (itself, ``learned_from``), or None."""
        return self.name if self.learned else self.learned_from

    @property
    def terms(self) -> dict:
        """``{feature: weight}``: the metric as a weighted sum of per-pair features, to first
        order. Exact for the learned metrics, combined (a weighted sum) and all-angle; unified
        is combined-angle's sum away from twins; Weighted's class gaps get a small weight of
        their own (a fraction gap separates parts, Weighted divides each D by the classes'
        agreement). The all-pairs candidate step (:mod:`shapeidx.store.candidates`) embeds it."""
        if self.weights_of:
            return dict(learned_weights(self.weights_of)["weights"])
        return dict(self.linear)

    @property
    def monotone(self) -> bool:
        """Whether its formula never decreases when a feature grows, so the block bounds of a
        query hold for it (``bounded``, and no negative learned weight)."""
        if not self.weights_of:
            return self.bounded
        return self.bounded and all(w >= 0 for w in self.terms.values())

    @property
    def duplicate_thresholds(self) -> dict | None:
        """``{"same": d, "near": d, ...}`` measured for ``duplicates`` on this metric's scale
        (``thresholds.json`` beside this module, written by scripts/duplicates_study.py), or
        None: not measured, and ``duplicates`` does not offer the metric."""
        return _thresholds()["thresholds"].get(self.name)


def _d(*histograms) -> tuple:
    return tuple(f"d_{h}" for h in histograms)


def _gaps() -> tuple:
    return tuple(f"gap_{c}" for c in _CLASSES)


def _scales() -> tuple:
    return tuple(f"scale_{c}" for c in _CLASSES)


def _sizes(*radii) -> tuple:
    return tuple(f"size_r{i}" for i in radii)


def _angle(kind: str, histograms=_HISTOGRAMS) -> tuple:
    return tuple(f"{kind}_angle_{h}" if kind else f"angle_{h}" for h in histograms)


#: Every metric, by its ``--metric`` name, in the order menus list them.
REGISTRY: dict[str, Metric] = {
    m.name: m
    for m in (
        Metric("all", "ALL (plain D2)", "the paper's ALL: plain D2 of all pairs (Osada et al.), no IN/OUT/MIXED split",
               histograms=("all",), features=_d("all"), formula=".paper:all_distance", paper=True,
               linear=((_d("all")[0], 1.0),)),
        Metric("avg3", "AvgOf3", "the paper's AvgOf3: mean D of the IN, OUT and MIXED histograms",
               histograms=_CLASSES, features=_d(*_CLASSES), formula=".paper:avg3", paper=True,
               linear=tuple((f, 1 / 3) for f in _d(*_CLASSES))),
        Metric("avg4", "AvgOf4", "the paper's AvgOf4: mean D of the ALL, IN, OUT and MIXED histograms",
               histograms=_HISTOGRAMS, features=_d(*_HISTOGRAMS), formula=".paper:avg4", paper=True,
               linear=tuple((f, 1 / 4) for f in _d(*_HISTOGRAMS))),
        Metric("weighted", "Weighted", "the paper's Weighted: each class's D weighted by 1 / (1 - the gap of its class fractions)",
               histograms=_CLASSES, features=_d(*_CLASSES) + _gaps(), formula=".paper:weighted", paper=True,
               defaults=("query", "compare"), linear=tuple((f, 1.0) for f in _d(*_CLASSES)) + tuple((f, 0.06) for f in _gaps())),
        Metric("combined", "combined", "learned: the four D, class-fraction gaps and class-mean ratios (NCA on kicad6)",
               histograms=_HISTOGRAMS, features=_d(*_HISTOGRAMS) + _gaps() + _scales(),
               formula=".combined:combined", learned="combined_metric.json"),
        Metric("combined-angle", "combined-angle",
               "learned: normal-angle histograms (Hellinger) and class features; best for parts of the same kind",
               histograms=(), features=_gaps() + _scales() + _angle("hellinger"), formula=".combined:combined_angle",
               angles=True, learned="combined_angle_metric.json", defaults=("duplicates", "check-new", "classify", "cluster")),
        Metric("combined-size", "combined-size",
               "learned: combined-angle's features and the exact sizes; for parts of a kind in a library of one unit"
               " (not scale-invariant)",
               histograms=(), features=_gaps() + _scales() + _angle("hellinger") + _sizes(2, 3),
               formula=".combined:combined_size", angles=True, sizes=True, learned="combined_size_metric.json"),
        Metric("all-angle", "all-angle",
               "plain D2 plus the ALL normal-angle histogram: for the same part from another exporter",
               histograms=("all",), features=_d("all") + _angle("", ("all",)), formula=".combined:all_angle", angles=True,
               defaults=("where-used",), linear=((_d("all")[0], 1.0), (_angle("", ("all",))[0], ALL_ANGLE_WEIGHT))),
        Metric("unified", "unified",
               "combined-angle, with pairs all-angle finds to be the same part (another exporter) moved first: one metric for kinds and twins",
               histograms=("all",), features=_d("all") + _angle("", ("all",)) + _gaps() + _scales() + _angle("hellinger"),
               formula=".combined:unified", angles=True, learned_from="combined-angle"),
    )
}

#: The ``--metric`` names, in menu order.
METRICS = tuple(REGISTRY)
#: The paper's four distances.
PAPER_METRICS = tuple(name for name, m in REGISTRY.items() if m.paper)
#: Metrics with a lower bound from coarse histograms (see :attr:`Metric.bounded`).
BOUNDED_METRICS = tuple(name for name, m in REGISTRY.items() if m.bounded)
#: Metrics that need the normal-angle histograms.
ANGLE_METRICS = tuple(name for name, m in REGISTRY.items() if m.angles)
#: Metrics that read the exact sizes (not scale-invariant).
SIZE_METRICS = tuple(name for name, m in REGISTRY.items() if m.sizes)


@lru_cache(maxsize=None)
def learned_weights(name: str) -> dict:
    """The learned weights of the learned metric ``name`` (its record's ``learned`` file) and
    how they were obtained (KeyError: not a learned metric)."""
    record = REGISTRY[name]
    if not record.learned:
        raise KeyError(name)
    data = json.loads(resources.files(__package__).joinpath(record.learned).read_text())
    if set(data["weights"]) != set(record.features):
        raise ValueError(f"{record.learned} does not match the features of metric {name}")
    return data


def _thresholds() -> dict:
    return json.loads(resources.files(__package__).joinpath("thresholds.json").read_text())


def metric(name: str) -> Metric:
    """The record of ``name``; ValueError naming the known ones otherwise."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown metric {name!r}; expected one of {', '.join(METRICS)}") from None


def default_metric(task: str) -> str:
    """The metric ``task`` (one of :data:`TASKS`) uses when none is named."""
    chosen = [name for name, m in REGISTRY.items() if task in m.defaults]
    if len(chosen) != 1:
        raise ValueError(f"task {task!r} has {len(chosen)} default metrics; expected one of {', '.join(TASKS)}")
    return chosen[0]


def label(name: str) -> str:
    """What tables call ``name`` (the name itself for an unknown one)."""
    return REGISTRY[name].label if name in REGISTRY else name


def metric_help() -> str:
    """The ``--metric`` help text: every metric with its one line."""
    return "The distance: " + "; ".join(f"{m.name}: {m.summary}" for m in REGISTRY.values()) + "."


def duplicate_metrics() -> tuple:
    """The metrics ``duplicates`` offers: those with measured thresholds."""
    return tuple(name for name, m in REGISTRY.items() if m.duplicate_thresholds is not None)


def markdown_table() -> str:
    """The metric table of the README and docs/cli.md (``python scripts/docs_tables.py`` writes
    it there; tests/test_docs.py checks that they hold this very table)."""
    rows = ["| `--metric` | label | what it is | reads | `duplicates` | the default of |", "|---|---|---|---|---|---|"]
    for m in REGISTRY.values():
        reads = ", ".join([f"D of {'/'.join(h.upper() for h in m.histograms)}"] if m.histograms else [])
        extra = [what for what, used in (("class fractions", any(f.startswith("gap_") for f in m.features)),
                                         ("class means", any(f.startswith("scale_") for f in m.features)),
                                         ("normal-angle histograms", m.angles),
                                         ("exact sizes", m.sizes)) if used]
        reads = "; ".join([reads] + extra if reads else extra)
        defaults = ", ".join(f"`{task}`" for task in m.defaults)
        rows.append(f"| `{m.name}` | {m.label} | {m.summary} | {reads} | {'yes' if m.duplicate_thresholds else 'no'} | {defaults} |")
    return "\n".join(rows) + "\n"
