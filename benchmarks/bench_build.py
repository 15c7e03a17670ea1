"""Build speed: cold asset build, no-op `snakemake all`, rebuilds after an inertial edit (prints seconds).

Runs Snakemake in a tmp copy of the project. The asset targets are URDF, MJCF and scene of every
configured robot (what the urdf/meshes/mjcf stages add). The MJCF's collision geoms come from CoACD,
whose cost at default settings is measured by bench_collision_usd.py; here the collision section's
`fast` settings are used (pass --default-collision to time the full decomposition too).
Targets (issue 2): no-op < 1.5 s, inertial rebuild < 15 s, cold < 60 s for both robots.

    .venv/bin/python benchmarks/bench_build.py
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import yaml

from harness import ROOT, jobs_run, snakemake

from buildtree import copy_repo  # noqa: E402  (the tests' copy of a clean clone)


def asset_targets(tree: Path) -> list[str]:
    robots = yaml.safe_load((tree / "configs/config.yaml").read_text())["robots"]
    return [t for r in robots for t in (f"results/{r}/{r}.urdf", f"results/{r}/mjcf/{r}.xml", f"results/{r}/mjcf/scene.xml")]


def timed_run(tree: Path, targets: list[str]) -> tuple[float, int]:
    seconds, log = snakemake(tree, *targets)
    return seconds, jobs_run(log)


def use_fast_collision(tree: Path) -> None:
    for robot_yaml in sorted((tree / "configs").glob("*/robot.yaml")):
        data = yaml.safe_load(robot_yaml.read_text())
        collision = data.get("collision") or {}
        collision.update(collision.get("fast") or {})
        robot_yaml.write_text(yaml.safe_dump(data, sort_keys=False))


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="sim2real-bench-") as tmp:
        tree = copy_repo(ROOT, Path(tmp) / "project")
        if "--default-collision" not in sys.argv:
            use_fast_collision(tree)
        targets = asset_targets(tree)
        cold, cold_jobs = timed_run(tree, targets)
        rest, rest_jobs = timed_run(tree, ["all"])
        noops = sorted(timed_run(tree, ["all"])[0] for _ in range(3))
        noop, noop_jobs = noops[1], timed_run(tree, ["all"])[1]
        xacro = tree / "robots/panda/panda.urdf.xacro"
        text = xacro.read_text()
        edited = text.replace('name="panda_link3" mesh="link3" mass="3.228604"', 'name="panda_link3" mesh="link3" mass="3.3"')
        assert edited != text, "benchmark setup: panda_link3 inertial not found"
        xacro.write_text(edited)
        rebuild, rebuild_jobs = timed_run(tree, targets)
        rebuild_all, rebuild_all_jobs = timed_run(tree, ["all"])
    print(f"{'cold asset build (both robots)':<40}{cold:7.2f} s  ({cold_jobs} jobs; target < 60 s)")
    print(f"{'rest of snakemake all (lab, fits, ...)':<40}{rest:7.2f} s  ({rest_jobs} jobs)")
    print(f"{'no-op snakemake all (median of 3)':<40}{noop:7.2f} s  ({noop_jobs} jobs; target < 1.5 s)")
    print(f"{'asset rebuild after inertial edit':<40}{rebuild:7.2f} s  ({rebuild_jobs} jobs; target < 15 s)")
    print(f"{'then the rest of snakemake all':<40}{rebuild_all:7.2f} s  ({rebuild_all_jobs} jobs)")


if __name__ == "__main__":
    main()
