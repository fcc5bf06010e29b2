"""Shared test fixtures: where the real data lives (read-only, never copied)."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import settings

# Property tests are seeded (the same examples on every machine and run) and keep no local
# example database, so a result never depends on what an earlier run happened to find.
settings.register_profile("blurtrack", derandomize=True, database=None)
settings.load_profile("blurtrack")

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA}")
    return SHARED_DATA
