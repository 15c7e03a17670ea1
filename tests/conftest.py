"""Shared pytest fixtures (small and generic)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from readme import ReadmeRun
    from sysid_lab import Lab

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The project checkout (read-only for tests: copy before editing)."""
    return REPO_ROOT


@pytest.fixture(scope="session")
def readme_run(tmp_path_factory: pytest.TempPathFactory) -> "ReadmeRun":
    """The README's commands run as written in a fast copy of the project, once for the suite: the built tree
    that tests needing one copy (readme.copy_built) rather than building their own."""
    from readme import run_readme

    return run_readme(REPO_ROOT, tmp_path_factory.mktemp("readme"))


@pytest.fixture(scope="session")
def built_tree(readme_run: "ReadmeRun") -> Path:
    """The shared built tree (`snakemake all` at fast settings, and the rest of the README): read-only."""
    return readme_run.tree


@pytest.fixture(scope="session")
def shared_lab(tmp_path_factory: pytest.TempPathFactory) -> "Lab":
    """One virtual lab for the suite's fits (tests/sysid_lab.py at its default settings): its runs are made once,
    and a scenario followed by two test modules is followed once."""
    from sysid_lab import Lab

    return Lab(tmp_path_factory.mktemp("lab"))
