"""Shared pytest fixtures (small and generic)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from readme import ReadmeRun
    from slurm_cluster import SlurmBuild
    from sysid_lab import Lab

REPO_ROOT = Path(__file__).resolve().parents[1]
SLURM_BUILD_TEST = "test_slurm.py::test_panda_mjcf_and_gap_report_through_the_slurm_profile"
SLURM_BUILD = pytest.StashKey["SlurmBuild"]()


def pytest_collection_finish(session: pytest.Session) -> None:
    """The SLURM build of tests/test_slurm.py starts as soon as the suite knows it runs that test: the build mostly
    waits on SLURM (tests/slurm_cluster.py), so the tests before it run meanwhile."""
    if session.config.option.collectonly or not any(item.nodeid.endswith(SLURM_BUILD_TEST) for item in session.items):
        return
    from slurm_cluster import SlurmBuild, slurm_config

    if slurm_config()[1] is None:
        factory: pytest.TempPathFactory = session.config._tmp_path_factory  # type: ignore[attr-defined]
        session.config.stash[SLURM_BUILD] = SlurmBuild.start(factory.mktemp("slurm_build"))


def pytest_sessionfinish(session: pytest.Session) -> None:
    build = session.config.stash.get(SLURM_BUILD, None)
    if build is not None:
        build.stop()


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
def slurm_build(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> "SlurmBuild":
    """The Panda's build through the SLURM profile, started at collection (or now); skips, saying why, where
    SLURM cannot run it."""
    from slurm_cluster import SlurmBuild, slurm_config

    build = request.config.stash.get(SLURM_BUILD, None)
    if build is None:
        _, unusable = slurm_config()
        if unusable:
            pytest.skip(unusable)
        build = request.config.stash[SLURM_BUILD] = SlurmBuild.start(tmp_path_factory.mktemp("slurm_build"))
    return build


@pytest.fixture(scope="session")
def shared_lab(tmp_path_factory: pytest.TempPathFactory) -> "Lab":
    """One virtual lab for the suite's fits (tests/sysid_lab.py at its default settings): its runs are made once,
    and a scenario followed by two test modules is followed once."""
    from sysid_lab import Lab

    return Lab(tmp_path_factory.mktemp("lab"))
