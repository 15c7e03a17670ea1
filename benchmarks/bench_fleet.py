"""Fan-out of the fleet: N simulated arms x M campaigns through the DAG (prints seconds and job counts).

In a tmp copy of the project (Panda only, fast collision settings, ladder [coulomb_friction]), every
arm gets one virtual-lab scenario per campaign (its own friction, drifting campaign by campaign, and
its own excitation and noise seeds) and a campaign file configs/panda/campaigns/arm<i>-<date>.yaml.
After the Panda's assets are built once, it times the campaign fan-out (two lab runs, sysid and a gap
report per campaign, then the fleet view) with 1 core and again, from clean campaign outputs, with 2
cores, and prints the wall time per gap report and the speed-up. Then it writes a fleet of 10 arms x 12
campaigns and counts the jobs a dry run of `snakemake all` holds.

    .venv/bin/python benchmarks/bench_fleet.py [--arms 2] [--campaigns 2] [--duration 8]
"""

from __future__ import annotations

import argparse
import re
import shutil
import tempfile
from pathlib import Path

import yaml

from harness import ROOT, snakemake

from buildtree import copy_repo, edit_yaml  # noqa: E402  (the tests' copy of a clean clone)

BASE_FRICTION = [0.8, 0.8, 0.6, 0.6, 0.4, 0.4, 0.3]


def campaign_name(arm: int, month: int) -> tuple[str, str]:
    date = f"{2026 + (month - 1) // 12}-{(month - 1) % 12 + 1:02d}"
    return f"arm{arm}-{date}", date


def write_fleet(tree: Path, arms: int, campaigns: int, duration: float, lab_base: dict) -> list[str]:
    """Lab scenarios and campaign files for arms x campaigns; returns the gap.json targets."""
    lab = dict(lab_base)
    lab["scenarios"] = dict(lab_base["scenarios"])
    folder = tree / "configs/panda/campaigns"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    targets = []
    for arm in range(1, arms + 1):
        for month in range(1, campaigns + 1):
            name, date = campaign_name(arm, month)
            scenario = f"bench_{name.replace('-', '_')}"
            # arm i's joint-(i mod 7) friction rises 0.02 N m a month; everything else stays
            friction = list(BASE_FRICTION)
            friction[(arm - 1) % 7] += 0.02 * (month - 1)
            seed = 1000 + 100 * arm + 2 * month
            lab["scenarios"][scenario] = {
                "duration_s": duration,
                "effects": {"coulomb_friction": {"coefficient": friction}},
                "runs": [{"name": "fit", "seed": seed, "role": "fit"},
                         {"name": "holdout", "seed": seed + 1, "role": "holdout"}],
            }
            (folder / f"{name}.yaml").write_text(yaml.safe_dump({
                "runs": [{"name": role, "path": f"results/panda/lab/{scenario}/{role}.parquet", "role": role}
                         for role in ("fit", "holdout")],
                "campaign": {"arm": f"arm{arm}", "date": date},
            }, sort_keys=False))
            targets.append(f"results/panda/{name}/gap.json")
    (tree / "configs/panda/lab.yaml").write_text(yaml.safe_dump(lab, sort_keys=False))
    return targets


def clean_campaigns(tree: Path) -> None:
    results = tree / "results/panda"
    for path in sorted(results.glob("arm*-*")) + sorted((results / "lab").glob("bench_*")) + [tree / "results/fleet"]:
        shutil.rmtree(path, ignore_errors=True)
    for path in (tree / "results/fleet.json", tree / "results/fleet.md"):
        path.unlink(missing_ok=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arms", type=int, default=2)
    parser.add_argument("--campaigns", type=int, default=2)
    parser.add_argument("--duration", type=float, default=8.0, help="seconds of each lab run")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_fleet_") as tmp:
        tree = copy_repo(ROOT, Path(tmp) / "repo")
        edit_yaml(tree / "configs/config.yaml", lambda c: c.update(robots=["panda"]))
        edit_yaml(tree / "configs/panda/model.yaml", lambda m: m.update(effects=["coulomb_friction"]))
        edit_yaml(tree / "configs/panda/robot.yaml",
                  lambda r: r["collision"].update(r["collision"].get("fast") or {}))
        (tree / "configs/panda/measurements.yaml").unlink()  # the fleet is the campaign files only
        lab_base = yaml.safe_load((tree / "configs/panda/lab.yaml").read_text())

        seconds, _ = snakemake(tree, "--cores", "2", "results/panda/mjcf/panda.xml")
        print(f"Panda assets (fast collision), built once: {seconds:.1f} s")

        n_reports = args.arms * args.campaigns
        targets = write_fleet(tree, args.arms, args.campaigns, args.duration, lab_base)
        timings = {}
        for cores in (1, 2):
            clean_campaigns(tree)
            seconds, log = snakemake(tree, "--cores", str(cores), *targets, "results/fleet.md")
            jobs = len(re.findall(r"^\s*(?:local)?rule \w+:", log, flags=re.MULTILINE))
            timings[cores] = seconds
            print(f"{args.arms} arms x {args.campaigns} campaigns, {cores} core(s): {seconds:.1f} s for {jobs} jobs, "
                  f"{seconds / n_reports:.1f} s per gap report (lab runs, sysid, report; fleet view included)")
        print(f"scaling 1 -> 2 cores: {timings[1] / timings[2]:.2f}x")
        fleet = yaml.safe_load((tree / "results/fleet.json").read_text())
        print(f"fleet view: {fleet['summary']['changes']} change(s) named; drifted arms {fleet['summary']['drifted_arms']}")

        write_fleet(tree, 10, 12, args.duration, lab_base)
        _, log = snakemake(tree, "--cores", "2", "--dry-run", "all")
        total = re.search(r"^total\s+(\d+)", log, flags=re.MULTILINE)
        counts = dict(re.findall(r"^(lab_run|sysid|gap_report|fleet)\s+(\d+)$", log, flags=re.MULTILINE))
        print(f"dry run of `snakemake all` for 10 arms x 12 campaigns: {total.group(1) if total else '?'} jobs "
              f"({', '.join(f'{k} {v}' for k, v in sorted(counts.items()))})")


if __name__ == "__main__":
    main()
