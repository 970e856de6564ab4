"""Option types of the command line, and the library's defaults it shows, without importing it.

The defaults are copies (importing the library would cost ``--help`` a second);
tests/test_startup.py checks that every copy equals the library's value.
"""

from __future__ import annotations

import math

import click

from ..distance.metrics import METRICS, default_metric, duplicate_metrics, metric_help  # noqa: F401 (the registry imports nothing heavy)
from ..io.formats import FORMAT_NAMES as PART_FORMATS  # noqa: F401 (the list of formats imports nothing)
#: = shapeidx.signing.parameters.DEFAULT_POINTS, DEFAULT_SEED
DEFAULT_POINTS = 1024
DEFAULT_SEED = 20020101
#: = shapeidx.store.layout.DEFAULT_STORE, STORE_ENV
DEFAULT_STORE = "index.shapeidx"
STORE_ENV = "SHAPEIDX_STORE"
#: = shapeidx.index.commit.DEFAULT_COMMIT_INTERVAL, MERGE_AFTER; shapeidx.index.workers.DEFAULT_TIMEOUT
DEFAULT_COMMIT_INTERVAL = 60.0
MERGE_AFTER = 64
DEFAULT_TIMEOUT = 600.0
#: Seeds are numpy SeedSequence entropy kept as an HDF5 integer attribute.
MAX_SEED = 2**63 - 1


class FiniteFloat(click.ParamType):
    """A float in ``[minimum, maximum]``: NaN and infinities are usage errors, not limits."""

    name = "float"

    def __init__(self, minimum: float | None = None, maximum: float | None = None):
        self.minimum, self.maximum = minimum, maximum

    def convert(self, value, param, ctx):
        if isinstance(value, float) and math.isfinite(value):
            number = value
        else:
            try:
                number = float(value)
            except (TypeError, ValueError):
                self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        if self.minimum is not None and number < self.minimum:
            self.fail(f"{value!r} is below the smallest allowed value, {self.minimum:g}", param, ctx)
        if self.maximum is not None and number > self.maximum:
            self.fail(f"{value!r} is above the largest allowed value, {self.maximum:g}", param, ctx)
        return number

    def __repr__(self) -> str:
        return f"FiniteFloat({self.minimum}, {self.maximum})"
