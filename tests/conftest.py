"""Shared pytest fixtures (small and generic)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from readme import ReadmeRun
    from slurm_cluster import SlurmBuild
    from sysid_lab import Lab

REPO_ROOT = Path(__file__).resolve().parents[1]
SLURM_BUILD_TEST = "test_slurm.py::test_panda_mjcf_and_gap_report_through_the_slurm_profile"
SLURM_BUILD = pytest.StashKey["SlurmBuild"]()


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The suite runs on two processes (pytest-xdist, `-n 2 --dist loadgroup` in pyproject.toml). A session fixture
    is made once per process, so the tests of the shared built tree go to one process and those of the shared lab to
    one, each module whole (its module fixtures are made once too); the other modules are spread one by one."""
    modules: dict[str, str] = {}
    for item in items:
        module = item.nodeid.split("::")[0]
        if "readme_run" in item.fixturenames:
            modules[module] = "built_tree"
        elif "shared_lab" in item.fixturenames and modules.get(module) != "built_tree":
            modules[module] = "shared_lab"
    for item in items:
        module = item.nodeid.split("::")[0]
        item.add_marker(pytest.mark.xdist_group(modules.get(module, module)))
    shard = config.getoption("shard")
    if shard:
        _keep_shard(config, items, modules, shard)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--shard", default=None, metavar="K/N",
                     help="run the K-th of N parts of the suite, whole xdist groups each (tests/shards.py; CI's matrix)")


def _keep_shard(config: pytest.Config, items: list[pytest.Item], modules: dict[str, str], shard: str) -> None:
    """Keeps the items of part K of N (tests/shards.py), whole groups; the others are deselected."""
    from shards import assign_shards, parse_shard

    part, count = parse_shard(shard)
    group_of = {item.nodeid: modules.get(item.nodeid.split("::")[0], item.nodeid.split("::")[0]) for item in items}
    shards = assign_shards(set(group_of.values()), count)
    kept = [item for item in items if shards[group_of[item.nodeid]] == part]
    deselected = [item for item in items if shards[group_of[item.nodeid]] != part]
    if deselected:
        config.hook.pytest_deselected(items=deselected)
    items[:] = kept


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_node_collection_finished(node: Any, ids: list[str]) -> None:
    """Stops the run when pytest-xdist did not take the groups (it writes them into the test ids, which pytest 9.2
    no longer reads: pytest-dev/pytest-xdist#1386): the shared tree and lab would be made on each process, twice the
    work."""
    if node.config.getoption("dist") == "loadgroup" and ids and not any("@" in nodeid for nodeid in ids):
        pytest.exit(f"pytest-xdist's --dist loadgroup did not group the tests under pytest {pytest.__version__} "
                    "(pytest-dev/pytest-xdist#1386): install the test extra's pytest (pip install -e '.[test]')", 4)


def start_slurm_build_if_run(session: pytest.Session) -> None:
    """The SLURM build of tests/test_slurm.py starts as soon as the process that runs that test knows it will: the
    build mostly waits on SLURM (tests/slurm_cluster.py), so the tests before it run meanwhile. The test uses the
    built tree, so the process that builds that tree (readme_run) is the one that runs it."""
    runs_it = any(item.nodeid.split("@")[0].endswith(SLURM_BUILD_TEST) for item in session.items)  # "@": its group
    if SLURM_BUILD in session.config.stash or not runs_it:
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
def readme_run(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> "ReadmeRun":
    """The README's commands run as written in a fast copy of the project, once for the suite: the built tree
    that tests needing one copy (readme.copy_built) rather than building their own."""
    from readme import run_readme

    start_slurm_build_if_run(request.session)

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
