"""Fixtures for the I/O tests: where the shared real logs live (skip when absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DIR = Path(__file__).resolve().parents[2].parent / "shared"


@pytest.fixture
def realphone_dir() -> Path:
    """../shared/data/realphone (never copied into the repo); skips when it is not there."""
    path = SHARED_DIR / "data" / "realphone"
    if not path.is_dir():
        pytest.skip(f"shared real-phone logs not found at {path}")
    return path
