"""Shared pytest fixtures (small and generic)."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The project checkout (read-only for tests: copy before editing)."""
    return REPO_ROOT
