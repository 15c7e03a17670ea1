"""Copies of the repository for tests that run Snakemake, with settings that keep them fast."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import yaml

FAST_BUILD_TARGET = "all"

# Snakemake imports every installed executor and storage plugin when it starts (snakemake/snakemake#3847, open): in
# the test environment, whose `cluster` extra serves the scale-out tests, 1.5 s of `snakemake --version` and about
# 0.5 s of a dry run on a 2-core machine. The suite's other runs start Snakemake as the README's install of `-e .`
# leaves it, without those plugins.
_WITHOUT_SCALE_OUT_PLUGINS = """
import pkgutil
listed = pkgutil.iter_modules
scale_out = ("snakemake_executor_plugin_", "snakemake_storage_plugin_")
pkgutil.iter_modules = lambda *args, **kwargs: (m for m in listed(*args, **kwargs) if not m.name.startswith(scale_out))
from snakemake.cli import main
main()
"""
SNAKEMAKE = [sys.executable, "-c", _WITHOUT_SCALE_OUT_PLUGINS]  # `python -m snakemake` without the scale-out plugins


def copy_repo(root: Path, dest: Path) -> Path:
    """Copy what a clean clone holds: the files git tracks plus untracked, unignored ones (never results/)."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=root, check=True, capture_output=True,
    ).stdout.decode().split("\0")
    for rel in filter(None, listed):
        src = root / rel
        if src.is_file() and not rel.startswith("results/"):
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)
    return dest


def run_snakemake(tree: Path, *args: str, timeout: float = 900) -> str:
    """Run Snakemake in ``tree`` with the test's interpreter; fail with the tail of its log."""
    done = subprocess.run(
        [*SNAKEMAKE, "--cores", "2", *args],
        cwd=tree, capture_output=True, text=True, timeout=timeout, env={**os.environ, "PYTHONHASHSEED": "0"},
    )
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]
    return done.stdout + done.stderr


def rules_run(log: str) -> set[str]:
    """Names of the rules (and checkpoints) whose jobs a Snakemake log says it ran."""
    return set(re.findall(r"^\s*(?:local)?(?:rule|checkpoint) (\w+):", log, flags=re.MULTILINE))


def comparable_outputs(results: Path) -> list[Path]:
    """The files under ``results`` that must be the same bytes in two builds, relative to it: not the logs and
    benchmarks (wall times), nor ``fits/`` and ``kept/``, the loop's caches of fits, replays and figures
    (sim2real.cache: pickles holding solve wall times; what is read back from them, ladder.json, gap.json,
    the figures, is compared)."""
    skip = {"logs", "benchmarks", "fits", "kept"}
    return sorted(p.relative_to(results) for p in results.rglob("*")
                  if p.is_file() and not skip.intersection(p.relative_to(results).parts))


def edit_yaml(path: Path, edit: Callable[[dict], None]) -> None:
    data = yaml.safe_load(path.read_text())
    edit(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def make_fast(tree: Path, lab_duration_s: float | None = None) -> None:
    """Settings for tests: the same DAG with cheap decomposition and short lab runs.

    ``lab_duration_s``: also shorten every lab run to this and bootstrap the fits with few replicates,
    for tests of the DAG itself (caching, reproducibility) rather than of what the fits find.
    """
    if lab_duration_s is not None:
        def short_runs(data: dict) -> None:
            data.setdefault("defaults", {})["duration_s"] = lab_duration_s
            for scenario in (data.get("scenarios") or {}).values():
                if scenario and "duration_s" in scenario:
                    scenario["duration_s"] = lab_duration_s

        def few_replicates(data: dict) -> None:
            data.setdefault("fit", {})["bootstrap_replicates"] = 20

        for lab in sorted((tree / "configs").glob("*/lab.yaml")):
            edit_yaml(lab, short_runs)
        for model in sorted((tree / "configs").glob("*/model.yaml")):
            edit_yaml(model, few_replicates)
    def coarse_design(data: dict) -> None:
        # A real optimisation, a few iterations on a coarse grid: seconds, not minutes.
        data.setdefault("defaults", {})["solver"] = {"max_iterations": 8, "objective_samples": 40,
                                                      "limit_samples": 120, "seed": 0}

    for excitation in sorted((tree / "configs").glob("*/excitation.yaml")):
        edit_yaml(excitation, coarse_design)
    for robot_cfg in sorted((tree / "configs").glob("*/robot.yaml")):
        def fast_collision(data: dict) -> None:
            collision = data.get("collision")
            if isinstance(collision, dict) and "fast" in collision:
                collision.update(collision["fast"])
        edit_yaml(robot_cfg, fast_collision)
