#!/usr/bin/env python3
"""Write the tables that derive from the code into the docs: the metric table of README.md and
docs/cli.md (from the metric registry, shapeidx/distance/metrics.py).

Usage::

    python scripts/docs_tables.py          # rewrite them
    python scripts/docs_tables.py --check  # exit 1 if a document is out of date

tests/test_docs.py checks the same.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from shapeidx.distance.metrics import markdown_table  # noqa: E402

DOCUMENTS = (REPO / "README.md", REPO / "docs" / "cli.md")
BLOCK = re.compile(r"(<!-- metrics-table -->\n)(.*?)(<!-- /metrics-table -->)", re.S)


def updated(text: str) -> str:
    return BLOCK.sub(lambda m: m.group(1) + markdown_table() + m.group(3), text)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true")
    args = parser.parse_args()
    stale = []
    for path in DOCUMENTS:
        text = path.read_text()
        if not BLOCK.search(text):
            continue
        new = updated(text)
        if new != text:
            stale.append(path)
            if not args.check:
                path.write_text(new)
    if args.check and stale:
        print("out of date: " + ", ".join(str(p.relative_to(REPO)) for p in stale))
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
