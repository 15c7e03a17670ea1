"""Collision and USD speed (prints seconds): CoACD per mesh and in total at the default settings,
serially and with 2 jobs in parallel, and the USD build.

Runs Snakemake in a tmp copy of the project. Targets (issue 3): the Panda's whole decomposition
within 4 min with 2 parallel jobs; USD build within 5 s.

    .venv/bin/python benchmarks/bench_collision_usd.py [--robot panda] [--skip-serial]
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

from harness import ROOT, snakemake, timed

from buildtree import copy_repo  # noqa: E402


def mesh_seconds(tree: Path, robot: str) -> dict[str, float]:
    timing = tree / "results" / robot / "benchmarks" / "coacd"
    return {p.stem: json.loads(p.read_text())["seconds"] for p in sorted(timing.glob("*.json"))}


def mesh_targets(tree: Path, robot: str) -> list[str]:
    """The converted visual and collision meshes (the decomposition's inputs) of the built URDF."""
    from sim2real.assets.urdf import mesh_names

    names = mesh_names(tree / "results" / robot / f"{robot}.urdf")
    return [f"results/{robot}/meshes/visual/{n}" for n in names["visual"]] + [
        f"results/{robot}/meshes/collision/{n}.stl" for n in names["collision"]
    ]


def decompose_all(tree: Path, robot: str, cores: int) -> float:
    """Wall time of every coacd job of ``robot`` (forced) on ``cores`` cores, nothing else rerun."""
    shutil.rmtree(tree / "results" / robot / "collision", ignore_errors=True)
    return snakemake(tree, "--cores", str(cores), f"results/{robot}/collision/report.json")[0]


def usd_seconds(tree: Path, robot: str) -> tuple[float, float]:
    """(build_usd call in-process, the Snakemake rule's job incl. interpreter start) in seconds."""
    from sim2real.assets.collision import part_files
    from sim2real.assets.urdf import mesh_names
    from sim2real.assets.usd import build_usd

    results = tree / "results" / robot
    names = mesh_names(results / f"{robot}.urdf")
    visual = [results / "meshes" / "visual" / n for n in names["visual"]]
    collision = {uri: part_files(results / "collision" / n) for n, uri in names["collision"].items()}
    with tempfile.TemporaryDirectory() as out:
        _, in_process = timed(build_usd, results / f"{robot}.urdf", tree / "configs" / robot / "robot.yaml", visual,
                              collision, Path(out) / f"{robot}.usda", Path(out) / f"{robot}_geometry.usda")
    snakemake(tree, "--cores", "1", f"results/{robot}/usd/{robot}.usda")
    benchmark = (results / "benchmarks" / "usd.tsv").read_text().splitlines()
    return in_process, float(benchmark[-1].split("\t")[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="panda")
    parser.add_argument("--skip-serial", action="store_true", help="only the 2-job run")
    args = parser.parse_args()
    robot = args.robot
    with tempfile.TemporaryDirectory(prefix="sim2real-bench-") as tmp:
        tree = copy_repo(ROOT, Path(tmp) / "project")
        # inputs of the decomposition (URDF, converted meshes) first, so only CoACD is timed
        snakemake(tree, "--cores", "2", f"results/{robot}/{robot}.urdf")
        snakemake(tree, "--cores", "2", *mesh_targets(tree, robot))
        rows: dict[str, dict[str, float]] = {}
        totals: dict[str, float] = {}
        for cores in ([2] if args.skip_serial else [1, 2]):
            totals[f"{cores} job{'s' if cores > 1 else ''}"] = decompose_all(tree, robot, cores)
            for name, seconds in mesh_seconds(tree, robot).items():
                rows.setdefault(name, {})[f"{cores}"] = seconds
        report = json.loads((tree / "results" / robot / "collision" / "report.json").read_text())
        in_process, rule = usd_seconds(tree, robot)

    columns = sorted({c for r in rows.values() for c in r})
    print(f"CoACD at the default settings of configs/{robot}/robot.yaml (per-mesh seconds include the fidelity measures)")
    print(f"{'mesh':<12}{'hulls':>6}" + "".join(f"{'s (' + c + ' job' + ('s' if c != '1' else '') + ')':>14}" for c in columns))
    for name in sorted(rows):
        hulls = report["meshes"][name]["hulls"]
        print(f"{name:<12}{hulls:>6}" + "".join(f"{rows[name].get(c, float('nan')):>14.1f}" for c in columns))
    for label, seconds in totals.items():
        print(f"{'total wall, ' + label:<34}{seconds:8.1f} s" + ("  (target < 240 s)" if label.startswith("2") else ""))
    print(f"{'USD build (build_usd call)':<34}{in_process:8.2f} s  (target < 5 s)")
    print(f"{'USD rule job (incl. imports)':<34}{rule:8.2f} s")


if __name__ == "__main__":
    main()
