"""Asset build speed: cold build, no-op, and rebuild after an inertial edit (prints seconds).

Runs Snakemake in a tmp copy of the project on the asset targets of every configured robot (URDF,
MJCF, scene: what the urdf/meshes/mjcf stages add to `snakemake all`).
Targets (issue 2): no-op < 1.5 s, inertial rebuild < 15 s, cold < 60 s for both robots.

    .venv/bin/python benchmarks/bench_build.py
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
SNAKEMAKE = Path(sys.executable).with_name("snakemake")


def copy_project(dest: Path) -> Path:
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT, check=True, capture_output=True
    ).stdout.decode().split("\0")
    for rel in filter(None, listed):
        if (ROOT / rel).is_file() and not rel.startswith("results/"):
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / rel, dest / rel)
    return dest


def asset_targets(tree: Path) -> list[str]:
    robots = yaml.safe_load((tree / "configs/config.yaml").read_text())["robots"]
    return [t for r in robots for t in (f"results/{r}/{r}.urdf", f"results/{r}/mjcf/{r}.xml", f"results/{r}/mjcf/scene.xml")]


def timed_run(tree: Path, targets: list[str]) -> tuple[float, int]:
    start = time.perf_counter()
    done = subprocess.run([str(SNAKEMAKE), *targets], cwd=tree, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        sys.exit(done.stderr[-3000:])
    jobs = len(re.findall(r"^\s*(?:local)?(?:rule|checkpoint) \w+:", done.stdout + done.stderr, flags=re.MULTILINE))
    return seconds, jobs


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="sim2real-bench-") as tmp:
        tree = copy_project(Path(tmp) / "project")
        targets = asset_targets(tree)
        cold, cold_jobs = timed_run(tree, targets)
        noop, noop_jobs = timed_run(tree, targets)
        xacro = tree / "robots/panda/panda.urdf.xacro"
        text = xacro.read_text()
        edited = text.replace('name="panda_link3" mesh="link3" mass="3.228604"', 'name="panda_link3" mesh="link3" mass="3.3"')
        assert edited != text, "benchmark setup: panda_link3 inertial not found"
        xacro.write_text(edited)
        rebuild, rebuild_jobs = timed_run(tree, targets)
    print(f"{'cold build (both robots)':<34}{cold:7.2f} s  ({cold_jobs} jobs; target < 60 s)")
    print(f"{'no-op':<34}{noop:7.2f} s  ({noop_jobs} jobs; target < 1.5 s)")
    print(f"{'rebuild after inertial edit':<34}{rebuild:7.2f} s  ({rebuild_jobs} jobs; target < 15 s)")


if __name__ == "__main__":
    main()
