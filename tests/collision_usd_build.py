"""One fast Snakemake build of the Panda's collision parts, MJCF, USD and equivalence, shared by the
collision/USD/equivalence/Newton tests (built once per test process, in a tmp copy of the project)."""

from __future__ import annotations

from pathlib import Path

from buildtree import copy_repo, make_fast, run_snakemake

ROBOT = "panda"
TARGETS = [
    f"results/{ROBOT}/collision/report.json",
    f"results/{ROBOT}/mjcf/scene.xml",
    f"results/{ROBOT}/usd/{ROBOT}.usda",
    f"results/{ROBOT}/equivalence.json",
]
_BUILDS: dict[Path, Path] = {}


def fast_panda_build(repo_root: Path, workdir: Path) -> Path:
    """Project tree with the fast-settings Panda built (cached per repository for this process)."""
    if repo_root not in _BUILDS:
        tree = copy_repo(repo_root, workdir / "project")
        make_fast(tree)
        run_snakemake(tree, *TARGETS)
        _BUILDS[repo_root] = tree
    return _BUILDS[repo_root]
