"""Shared test fixtures: where the shared real data lives."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: Real data nobody here made (read-only). Override with SHAPEIDX_DATA.
DATA = Path(os.environ.get("SHAPEIDX_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The shared data folder; a test that needs it fails loudly when it is missing."""
    if not DATA.is_dir():
        pytest.fail(f"shared data not found at {DATA} (set SHAPEIDX_DATA)")
    return DATA
