"""Collision and USD speed (prints seconds): CoACD per mesh and in total at the default settings,
serially and with 2 jobs in parallel, and the USD build; or (--settings) CoACD settings per mesh.

Runs Snakemake in a tmp copy of the project. Targets (issue 3): the Panda's whole decomposition
within 4 min with 2 parallel jobs; USD build within 5 s.

    .venv/bin/python benchmarks/bench_collision_usd.py [--robot panda] [--skip-serial]

With --settings (issue 32), per mesh and back to back on one core: the settings before issue 32, each
candidate setting and the shipped one, with time ratio, parts, Hausdorff and volume ratio against before's:

    .venv/bin/python benchmarks/bench_collision_usd.py --settings --robot panda ur5 [--mesh shoulder]
        [--candidate name:key=value,key=value ...] [--tree built-project] [--slack-mm 0.5] [--slack-volume 0.01]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml
from harness import ROOT, snakemake, timed

from buildtree import copy_repo  # noqa: E402
from sim2real.assets.collision import MeshSettings, load_source_mesh, mesh_settings, run_coacd, shape_fidelity

if TYPE_CHECKING:
    import trimesh

# CoACD is OpenMP-parallel; the coacd rule (threads: 1) runs it with Snakemake's OMP_NUM_THREADS=1, and so do
# the in-process trials (set before coacd is first imported).
os.environ["OMP_NUM_THREADS"] = "1"


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


# ------------------------------------------------------------------------------ per-mesh settings trials
# The settings every mesh had before issue 32 (collision.coacd of both robots, no overrides): what "within
# today's fidelity" is measured against.
BEFORE = {"source": "visual", "threshold": 0.05, "max_convex_hull": 24, "preprocess_mode": "auto",
          "mcts_iterations": 40, "seed": 0}
# Candidates: changes to BEFORE, each a CoACD knob that trades search or sampling effort for time.
CANDIDATES = {
    "res1000": {"resolution": 1000},
    "iter20": {"mcts_iterations": 20},
    "depth2": {"mcts_max_depth": 2},
}


def parse_candidate(text: str) -> tuple[str, dict[str, Any]]:
    """``name:key=value,key=value`` (values read as YAML scalars) -> (name, changes)."""
    name, _, body = text.partition(":")
    changes = {k: yaml.safe_load(v) for k, v in (item.split("=", 1) for item in body.split(",") if item)}
    return name, changes


def trial(mesh: trimesh.Trimesh, settings: MeshSettings) -> dict[str, Any]:
    """CoACD and the fidelity measures of one setting on one loaded source, as the rule runs them."""
    parts, coacd_s = timed(run_coacd, mesh, settings.coacd)
    fidelity, measure_s = timed(shape_fidelity, mesh, parts)
    return {**fidelity, "coacd_s": coacd_s, "seconds": coacd_s + measure_s}


def within(before: Mapping[str, Any], after: Mapping[str, Any], slack_mm: float, slack_volume: float) -> bool:
    """Fidelity no worse than before's (up to the slack) and no more parts than before's."""
    return (after["hausdorff_mm"] <= before["hausdorff_mm"] + slack_mm
            and abs(after["volume_ratio"] - 1) <= abs(before["volume_ratio"] - 1) + slack_volume
            and after["hulls"] <= before["hulls"])


def compare_settings(tree: Path, robots: list[str], only: list[str], candidates: dict[str, dict[str, Any]],
                     slack_mm: float, slack_volume: float) -> None:
    """Per mesh, back to back on one core: BEFORE, every candidate, and the shipped (config) setting if it differs.

    Prints each one's seconds (CoACD + fidelity measures, the rule's work less its start and the mesh load),
    its time ratio to BEFORE, parts, Hausdorff and volume ratio, and whether it stays within BEFORE's fidelity."""
    from sim2real.assets.urdf import mesh_names

    print(f"slack: Hausdorff +{slack_mm:g} mm, |volume ratio - 1| +{slack_volume:g}; parts at most before's")
    print(f"{'mesh':<16}{'setting':<12}{'s':>7}{'coacd s':>9}{'ratio':>7}{'parts':>6}{'hd mm':>8}{'vol':>8}  within")
    sums: dict[str, list[float]] = {}
    for robot in robots:
        section = yaml.safe_load((tree / "configs" / robot / "robot.yaml").read_text())["collision"]
        names = sorted(mesh_names(tree / "results" / robot / f"{robot}.urdf")["collision"])
        for name in [n for n in names if not only or n in only]:
            mesh = load_source_mesh(tree / "results" / robot / "meshes" / "visual" / name)
            before = MeshSettings.from_params(BEFORE)
            trials = {"before": before}
            trials.update({label: MeshSettings.from_params({**BEFORE, **changes}) for label, changes in candidates.items()})
            shipped = mesh_settings(section, name)
            if shipped != before and shipped not in trials.values():
                trials["shipped"] = shipped
            results = {label: trial(mesh, settings) for label, settings in trials.items()}
            base = results["before"]
            for label, row in results.items():
                ok = "" if label == "before" else ("yes" if within(base, row, slack_mm, slack_volume) else "no")
                print(f"{robot + '/' + name:<16}{label:<12}{row['seconds']:7.1f}{row['coacd_s']:9.1f}"
                      f"{row['seconds'] / base['seconds']:7.2f}{row['hulls']:6d}{row['hausdorff_mm']:8.2f}"
                      f"{row['volume_ratio']:8.4f}  {ok}", flush=True)
                sums.setdefault(label, []).append(row["seconds"])
            if "shipped" not in results:
                sums.setdefault("shipped", []).append(results[next(k for k, s in trials.items() if s == shipped)]["seconds"])
    for label, seconds in sums.items():
        print(f"{'sum over meshes, ' + label:<32}{sum(seconds):8.1f} s  longest {max(seconds):6.1f} s  "
              f"ratio {sum(seconds) / sum(sums['before']):.2f}")
    print(f"shipped / before: sum {sum(sums['shipped']) / sum(sums['before']):.2f}, "
          f"longest {max(sums['shipped']) / max(sums['before']):.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", nargs="+", default=["panda"], help="with --settings, several robots")
    parser.add_argument("--skip-serial", action="store_true", help="only the 2-job run")
    parser.add_argument("--settings", action="store_true", help="compare CoACD settings per mesh (issue 32)")
    parser.add_argument("--mesh", nargs="*", default=[], help="with --settings: only these meshes")
    parser.add_argument("--candidate", action="append", default=[], metavar="NAME:KEY=VALUE,...",
                        help="with --settings: a candidate (changes to the settings before issue 32); replaces the built-in list")
    parser.add_argument("--tree", type=Path, help="with --settings: a project tree whose meshes are built (else a tmp copy)")
    parser.add_argument("--slack-mm", type=float, default=0.5, help="Hausdorff slack over before's (mm)")
    parser.add_argument("--slack-volume", type=float, default=0.01, help="|volume ratio - 1| slack over before's")
    args = parser.parse_args()
    if args.settings:
        candidates = dict(map(parse_candidate, args.candidate)) if args.candidate else CANDIDATES
        if args.tree:
            compare_settings(args.tree, args.robot, args.mesh, candidates, args.slack_mm, args.slack_volume)
            return
        with tempfile.TemporaryDirectory(prefix="sim2real-bench-") as tmp:
            tree = copy_repo(ROOT, Path(tmp) / "project")
            for robot in args.robot:
                snakemake(tree, "--cores", "1", f"results/{robot}/{robot}.urdf")
                snakemake(tree, "--cores", "1", *mesh_targets(tree, robot))
            compare_settings(tree, args.robot, args.mesh, candidates, args.slack_mm, args.slack_volume)
        return
    robot = args.robot[0]
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
