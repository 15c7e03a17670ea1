"""CI's promises, played locally on the Panda and the UR5 at fast settings.

- Two clean builds in separate directories give byte-identical outputs (logs and benchmarks aside): the
  suite's shared tree, where the README's commands ran (conftest ``readme_run``), and a clean `snakemake all` of
  the Panda alone.
- The workflow's cache steps: build, copy results/ and .snakemake/metadata aside, make a fresh copy
  of the repository, restore, settle mtimes as CI does: `snakemake all` runs nothing. Then an
  edited inertial value reruns only the jobs that depend on it (no mesh, no decomposition job).
"""

from __future__ import annotations

import filecmp
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from buildtree import FAST_BUILD_TARGET, comparable_outputs, copy_repo, edit_yaml, make_fast, rules_run

from buildtree import run_snakemake as _snakemake
from readme import README_LAB_DURATION_S, ReadmeRun

# The settings of the shared tree: the cache and reproducibility do not depend on what the fits find.
LAB_DURATION_S = README_LAB_DURATION_S

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


def _jobs_run(log: str) -> list[str]:
    return sorted(rules_run(log))


@pytest.fixture(scope="module")
def first_build(readme_run: ReadmeRun) -> Path:
    assert ".venv/bin/snakemake all" in readme_run.ran
    return readme_run.tree


def test_two_clean_builds_are_byte_identical(first_build: Path, tmp_path: Path) -> None:
    """The second build is the Panda's alone (every stage of the DAG runs for it, its second campaign and its
    excitation design too; the UR5's jobs are the same rules on other inputs): its outputs must be the bytes the
    first build, of every robot, wrote for the Panda."""
    second = copy_repo(ROOT, tmp_path / "repo")
    make_fast(second, LAB_DURATION_S)
    edit_yaml(second / "configs/config.yaml", lambda config: config.update(robots=["panda"]))
    _snakemake(second, FAST_BUILD_TARGET)
    files_a = comparable_outputs(first_build / "results" / "panda")
    files_b = comparable_outputs(second / "results" / "panda")
    assert set(files_a) == set(files_b)
    stages = {f.parts[0] for f in files_b}
    assert {"mjcf", "calibrated", "collision", "lab", "sysid", "usd", "excitation", "panda-2026-11"} <= stages, stages
    differing = [str(f) for f in files_b
                 if not filecmp.cmp(first_build / "results/panda" / f, second / "results/panda" / f, shallow=False)]
    assert differing == []


def test_restored_cache_runs_nothing_and_an_inertial_edit_reruns_only_its_dependents(first_build: Path, tmp_path: Path) -> None:
    fresh = copy_repo(ROOT, tmp_path / "repo")
    make_fast(fresh, LAB_DURATION_S)
    # The workflow's restore step: results/ and Snakemake's metadata, file times as archived.
    shutil.copytree(first_build / "results", fresh / "results", copy_function=shutil.copy2)
    shutil.copytree(first_build / ".snakemake" / "metadata", fresh / ".snakemake" / "metadata", copy_function=shutil.copy2)
    subprocess.run(["bash", str(fresh / ".ci" / "settle-mtimes")], check=True)

    log = _snakemake(fresh, FAST_BUILD_TARGET)
    assert _jobs_run(log) == [], f"restored build reran jobs: {_jobs_run(log)}"

    # The UR5's: the same promise as the Panda's, at a third of the cost (the Panda's fits and excitation design
    # rerun for a Panda edit; they are the same code).
    xacro = fresh / "robots" / "ur5" / "ur5.urdf.xacro"
    text = xacro.read_text()
    edited, count = re.subn(
        r'(name="upper_arm_link" mesh="upperarm" mass=")([0-9.]+)(")', lambda m: f"{m[1]}{float(m[2]) * 1.05:.6g}{m[3]}",
        text,
    )
    assert count == 1, "no upper_arm_link mass in the UR5 Xacro to edit"
    xacro.write_text(edited)
    jobs = _jobs_run(_snakemake(fresh, FAST_BUILD_TARGET))
    assert "urdf" in " ".join(jobs) and "mjcf" in " ".join(jobs), jobs
    mesh_jobs = [j for j in jobs if "mesh" in j or "coacd" in j or "decompos" in j or "collision_parts" in j]
    assert mesh_jobs == [], f"an inertial edit reran mesh jobs: {mesh_jobs}"
