"""``--where``: filters on an entry's metadata, joined to its shape.

A condition is ``KEY OP VALUE``:

    =   !=          equal / not equal (numbers compare as numbers: ``rev=3`` matches ``3.0``)
    <  <=  >  >=    numeric comparisons (an entry whose value is not a number does not match)
    ~   !~          glob match, case-insensitive (``path~Connector_USB*``, ``title~*usb*``)

Keys are the store's metadata columns: the sidecar table's (``build --metadata parts.csv``),
what the files say themselves (``title``, ``product_id``), and ``path`` (the entry's path
relative to the indexed folder). Several conditions must all hold. An entry without a value
for a key has the empty value: it matches ``KEY=`` and ``KEY!=steel``, and no comparison.
A key no entry has is refused (a typo would otherwise filter everything out).
"""

from __future__ import annotations

import fnmatch
import re
from dataclasses import dataclass

import numpy as np

from ..errors import UsageError

#: Operators, longest first (so that ``<=`` is not read as ``<``).
OPERATORS = ("!=", "<=", ">=", "!~", "=", "<", ">", "~")
_SPLIT = re.compile(r"(!=|<=|>=|!~|=|<|>|~)")


@dataclass(frozen=True)
class Condition:
    """One ``--where`` condition."""

    key: str
    op: str
    value: str

    def __str__(self) -> str:
        return f"{self.key}{self.op}{self.value}"

    @property
    def number(self) -> float | None:
        return _number(self.value)

    def matches(self, values: np.ndarray) -> np.ndarray:
        """Which of ``values`` (an object array of strings, "" where missing) satisfy it."""
        values = np.asarray(values, dtype=object)
        if self.op in ("~", "!~"):
            pattern = re.compile(fnmatch.translate(self.value.casefold()), re.DOTALL)
            found = np.fromiter((pattern.match(str(v).casefold()) is not None for v in values), dtype=bool, count=len(values))
            return found if self.op == "~" else ~found
        if self.op in ("=", "!="):
            equal = values == self.value
            if self.number is not None:  # numbers compare as numbers: "3" = "3.0"
                equal |= numbers_of(values) == self.number
            return equal if self.op == "=" else ~equal
        numbers = numbers_of(values)
        with np.errstate(invalid="ignore"):
            return {"<": numbers < self.number, "<=": numbers <= self.number,
                    ">": numbers > self.number, ">=": numbers >= self.number}[self.op]


def parse_condition(text: str) -> Condition:
    """``"material=steel"`` -> Condition; UsageError naming the text when it is not one."""
    parts = _SPLIT.split(str(text), maxsplit=1)
    if len(parts) != 3 or not parts[0].strip():
        raise UsageError(f"--where {text!r}: expected KEY OP VALUE with OP one of {' '.join(OPERATORS)}"
                         " (e.g. --where material=steel --where 'revision>=3')")
    key, op, value = parts[0].strip(), parts[1], parts[2].strip()
    if op in ("<", "<=", ">", ">=") and _number(value) is None:
        raise UsageError(f"--where {text!r}: {op} compares numbers, and {value!r} is not one")
    return Condition(key, op, value)


def parse_where(texts) -> tuple:
    """Every ``--where`` text (None or empty: no condition) as Conditions."""
    return tuple(parse_condition(t) for t in (texts or ()))


def _number(text: str) -> float | None:
    try:
        value = float(text)
    except (TypeError, ValueError):
        return None
    return value if np.isfinite(value) else None


def numbers_of(values: np.ndarray) -> np.ndarray:
    """Each value as a float (NaN where it is not a finite number)."""
    values = np.asarray(values, dtype=object)
    try:  # the common case, a column of numbers, in one pass
        out = np.asarray(values.astype(str), dtype=np.float64)
    except ValueError:
        out = np.fromiter((_number(v) if v != "" else None for v in values), dtype=np.float64, count=len(values))
    out[~np.isfinite(out)] = np.nan
    return out


def keep_mask(conditions, column, keys) -> np.ndarray | None:
    """The entries satisfying every condition (None: no condition).

    ``column(key)`` gives a key's values for every entry; ``keys`` are the keys the store
    knows (a condition on another key is refused in one line).
    """
    if not conditions:
        return None
    keys = set(keys)
    mask = None
    for condition in conditions:
        if condition.key not in keys:
            known = ", ".join(sorted(keys))
            raise UsageError(f"--where {condition}: no entry of the store has metadata {condition.key!r}"
                             f" (the store has: {known})")
        found = condition.matches(column(condition.key))
        mask = found if mask is None else mask & found
    return mask
