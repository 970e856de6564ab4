"""The metric record (shapeidx.distance.metrics) holds what the rest of the package knows about a
metric: each task's default, what it was learned from, whether it is monotone, its first-order
terms (what the all-pairs candidate step embeds). Nothing outside the registry names a metric as
a default."""

import ast
import re
from pathlib import Path

import numpy as np
import pytest

from shapeidx.distance import ANGLE_FEATURES, FEATURES
from shapeidx.distance.combined import UNIFIED_TWIN_DISTANCE
from shapeidx.distance.metrics import METRICS, REGISTRY, TASKS, default_metric

PACKAGE = Path(__file__).resolve().parents[1] / "shapeidx"
#: Metric names a default could be written as ("all" is also the word for every status, kind, ...).
DEFAULT_NAMES = tuple(m for m in METRICS if m != "all")


def test_every_task_has_one_default_that_its_command_shows():
    from click.testing import CliRunner

    from shapeidx.cli import main

    for task in TASKS:
        assert default_metric(task) in METRICS
    with pytest.raises(ValueError, match="no-such-task"):
        default_metric("no-such-task")
    # the command line's --metric default is the registry's, for every command with one
    for command in ("query", "where-used", "classify", "cluster", "duplicates", "check-new"):
        out = CliRunner().invoke(main, [command, "--help"], terminal_width=400).output
        assert f"[default: {default_metric(command)}]" in out, command


def test_the_paper_weighted_answers_a_query_and_the_learned_metric_the_kinds():
    # the choices docs/results.md measured: the paper's metric for a query by example, the
    # learned one for the questions about kinds, all-angle for the files that hold a part
    assert default_metric("query") == "weighted" and default_metric("where-used") == "all-angle"
    assert {default_metric(t) for t in ("duplicates", "check-new", "classify", "cluster")} == {"combined-angle"}


def _random_features(n=200, seed=3):
    rng = np.random.default_rng(seed)
    return {f: rng.uniform(0.0, 0.3, n) for f in FEATURES + ANGLE_FEATURES}


@pytest.mark.parametrize("name", ["all", "avg3", "avg4", "combined", "combined-angle", "all-angle"])
def test_terms_of_a_linear_metric_give_its_formula(name):
    """Its terms, summed with their weights, are its formula (an independent reading: the formula
    is the registry's function, the terms its record's weights)."""
    record = REGISTRY[name]
    f = _random_features()
    by_terms = sum(w * f[feature] for feature, w in record.terms.items())
    assert np.allclose(by_terms, record.value(f), rtol=1e-12, atol=0)
    assert set(record.terms) == set(record.features)


def test_terms_of_the_nonlinear_metrics_are_their_first_order():
    f = _random_features()
    # unified is combined-angle's sum wherever all-angle finds no twin
    f["d_all"] = np.full(len(f["d_all"]), 10 * UNIFIED_TWIN_DISTANCE)
    unified = REGISTRY["unified"]
    assert unified.weights_of == "combined-angle" and unified.terms == REGISTRY["combined-angle"].terms
    assert np.allclose(unified.value(f), sum(w * f[k] for k, w in unified.terms.items()), rtol=1e-12, atol=0)
    # Weighted with equal class fractions is the sum of the class D; a fraction gap makes it grow
    weighted = REGISTRY["weighted"]
    for c in ("in", "out", "mixed"):
        f[f"gap_{c}"] = np.zeros_like(f["d_all"])
    d = {k: w for k, w in weighted.terms.items() if k.startswith("d_")}
    assert np.allclose(weighted.value(f), sum(w * f[k] for k, w in d.items()), rtol=1e-12)
    f["gap_in"] = np.full_like(f["d_all"], 0.2)
    assert np.all(weighted.value(f) > sum(w * f[k] for k, w in d.items()))
    assert all(w > 0 for k, w in weighted.terms.items() if k.startswith("gap_"))


def test_learned_from_and_monotone():
    for name, record in REGISTRY.items():
        assert (record.weights_of is not None) == (record.learned is not None or record.learned_from is not None)
        if record.learned_from:
            assert REGISTRY[record.learned_from].learned, name
        assert record.monotone == (record.bounded and all(w >= 0 for w in record.terms.values())), name


def test_embedding_follows_the_terms():
    from shapeidx.store.candidates import embedding_weights

    for name, record in REGISTRY.items():
        blocks = embedding_weights(name)
        d2 = {k[3:] for k in blocks if k.startswith("d2_")}
        assert d2 == {k[2:] for k, w in record.terms.items() if k.startswith("d_") and w}, name
        angles = {k[6:] for k in blocks if k.startswith("angle_")}
        assert angles == {k.rsplit("_", 1)[1] for k, w in record.terms.items() if "angle_" in k and w}, name
        assert ("fractions" in blocks) == any(k.startswith("gap_") and w for k, w in record.terms.items()), name
        assert ("scales" in blocks) == any(k.startswith("scale_") and w for k, w in record.terms.items()), name


# -- nothing outside the registry writes a metric name as a default ---------------------------

def metric_defaults_in(source: str) -> list:
    """(line, what) of every place ``source`` writes a metric name as a default: a parameter's
    default, a NAME = "metric" constant, ``x or "metric"``, ``a if c else "metric"``,
    ``.get(key, "metric")``, an option's ``default="metric"`` or ``metric_option("metric")``."""
    def named(node):
        return isinstance(node, ast.Constant) and node.value in DEFAULT_NAMES

    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            found += [(d.lineno, f"parameter default {d.value!r}") for d in node.args.defaults + node.args.kw_defaults
                      if d is not None and named(d)]
        elif isinstance(node, ast.Assign) and named(node.value):
            found.append((node.lineno, f"constant {node.value.value!r}"))
        elif isinstance(node, ast.BoolOp) and isinstance(node.op, ast.Or):
            found += [(v.lineno, f"fallback {v.value!r}") for v in node.values if named(v)]
        elif isinstance(node, ast.IfExp):
            found += [(v.lineno, f"fallback {v.value!r}") for v in (node.body, node.orelse) if named(v)]
        elif isinstance(node, ast.Call):
            if isinstance(node.func, ast.Attribute) and node.func.attr in ("get", "setdefault") and len(node.args) == 2 \
                    and named(node.args[1]):
                found.append((node.lineno, f"fallback {node.args[1].value!r}"))
            name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
            if name.endswith("_option"):  # the command line's @metric_option(...)
                found += [(a.lineno, f"option default {a.value!r}") for a in node.args if named(a)]
            found += [(k.value.lineno, f"default={k.value.value!r}") for k in node.keywords
                      if k.arg == "default" and named(k.value)]
    return found


def test_the_finder_finds_a_planted_default():
    planted = ('def f(metric="weighted"): pass\nDEFAULT_METRIC = "all-angle"\nm = q.get("metric", "unified")\n'
               'n = x or "combined"\nopt = option(default="combined-angle")\ng = lambda metric="avg3": 0\n'
               'h = a if uses else "weighted"\n@metric_option("avg4")\ndef c(): pass\n')
    assert [line for line, _ in metric_defaults_in(planted)] == [1, 2, 3, 4, 5, 6, 7, 8]
    assert metric_defaults_in('table.pair_distances(a, b, "combined-angle")\nm = default_metric("query")\n') == []


def test_no_module_outside_the_registry_writes_a_metric_default():
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.parent.name == "distance":
            continue
        offenders += [f"{path.relative_to(PACKAGE)}:{line}: {what}" for line, what in metric_defaults_in(path.read_text())]
    names = "|".join(re.escape(m) for m in DEFAULT_NAMES)
    for path in sorted(PACKAGE.rglob("*.js")):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if re.search(rf"""(\|\||=)\s*["']({names})["']""", line):
                offenders.append(f"{path.relative_to(PACKAGE)}:{number}: {line.strip()[:80]}")
    assert offenders == [], "metric defaults outside shapeidx/distance/metrics.py:\n" + "\n".join(offenders)
