"""README command 1 from fresh clones, this commit's against another's in one run (issue 32).

A newcomer's first build is the README's first command (``python3 -m venv .venv && .venv/bin/pip install -q uv
&& .venv/bin/uv pip install -p .venv/bin/python --compile-bytecode -e . && .venv/bin/snakemake all``; ce27dde's
installed with pip alone), typed in a fresh clone. This benchmark does exactly that for the commit at HEAD and,
with ``--against REV``, for REV, alternating (REV first unless ``--head-first``, then the other way round), each in
a new clone with a new environment, as each commit's own README gives the command. It prints the wall time of each
part of the command and the ratio of the medians: machines and days differ 2-3x in speed, so only a ratio
measured in one run on one machine says whether the first build got faster.

From each build's ``benchmark:`` files (the rule times) it prints the issue's other figures: CoACD's jobs (sum and
longest), the excitation design against the longest CoACD job, everything but CoACD against CoACD; and from each
robot's designed excitation, its condition number, closest approach, whether it was scaled down to pass the
every-sample check, and its peaks against the limits.

    python benchmarks/bench_cold_build.py [--against ce27dde] [--repeats 1] [--keep DIR]

Each build downloads the dependencies and runs the whole DAG (about 9 minutes on 2 cores at HEAD, 17 at ce27dde);
nothing else should run beside it.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from harness import ROOT


@dataclass
class ColdBuild:
    """One fresh clone's README command 1: the wall time of each part, and the build's rule times."""

    rev: str
    parts: list[tuple[str, float]] = field(default_factory=list)
    rule_times: dict[str, float] = field(default_factory=dict)  # benchmark file (relative to results/) -> s
    excitation: dict[str, dict] = field(default_factory=dict)  # robot/design -> its report

    @property
    def total(self) -> float:
        return sum(seconds for _, seconds in self.parts)


def readme_command(readme: str) -> list[str]:
    """The README's first command (its first ``bash`` block, comments dropped, continuations joined), split at
    ``&&`` into the parts that are timed one by one."""
    blocks = re.findall(r"^```bash\n(.*?)^```", readme, flags=re.MULTILINE | re.DOTALL)
    if not blocks:
        raise SystemExit("README.md has no bash block: nothing to time")
    lines = [re.sub(r"(^|\s)#.*$", "", line).strip() for line in blocks[0].replace("\\\n", " ").splitlines()]
    command = next((line for line in lines if line), None)
    if command is None:
        raise SystemExit("README.md's first bash block holds no command")
    return [part.strip() for part in command.split("&&")]


def user_environment() -> dict[str, str]:
    """The environment a newcomer types in: this benchmark's own virtual environment taken off PATH, so that
    ``python3`` is the machine's and the clone's ``.venv`` is made from it."""
    env = dict(os.environ)
    env.pop("VIRTUAL_ENV", None)
    if sys.prefix != sys.base_prefix:
        own = str(Path(sys.prefix) / "bin")
        env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep) if p != own)
    return env


def fresh_clone(rev: str, dest: Path) -> None:
    subprocess.run(["git", "clone", "-q", str(ROOT), str(dest)], check=True)
    subprocess.run(["git", "-C", str(dest), "checkout", "-q", rev], check=True)


def run_readme_command(rev: str, dest: Path) -> ColdBuild:
    """A fresh clone of ``rev`` in ``dest`` and its README's first command, part by part (each part's output in
    ``dest/bench_cold_build.<n>.log``); a failed part stops the benchmark with its log's tail."""
    fresh_clone(rev, dest)
    build = ColdBuild(rev)
    env = user_environment()
    for number, part in enumerate(readme_command((dest / "README.md").read_text(encoding="utf-8"))):
        log = dest / f"bench_cold_build.{number}.log"
        started = time.perf_counter()
        with log.open("w") as handle:
            done = subprocess.run(["bash", "-c", part], cwd=dest, env=env, stdout=handle, stderr=subprocess.STDOUT)
        build.parts.append((part, time.perf_counter() - started))
        if done.returncode != 0:
            sys.exit(f"{rev}: '{part}' failed (exit {done.returncode}); the end of {log}:\n"
                     + log.read_text(errors="replace")[-3000:])
    build.rule_times = rule_times(dest / "results")
    build.excitation = excitation_reports(dest / "results")
    return build


def rule_times(results: Path) -> dict[str, float]:
    """Each job's wall time from its ``benchmark:`` file, keyed by the file's path under ``results/``."""
    times = {}
    for path in sorted(results.rglob("benchmarks/**/*.tsv")):
        with path.open() as handle:
            row = next(csv.DictReader(handle, delimiter="\t"), None)
        if row is not None and "s" in row:
            times[path.relative_to(results).as_posix()] = float(row["s"])
    return times


def excitation_reports(results: Path) -> dict[str, dict]:
    return {f"{path.parent.parent.name}/{path.stem}": json.loads(path.read_text())
            for path in sorted(results.glob("*/excitation/*.json"))}


def split_times(times: dict[str, float]) -> dict[str, float]:
    """CoACD's jobs (sum, longest), the excitation designs, and everything else (the excitation included, as
    issue 32 counts it)."""
    coacd = [s for name, s in times.items() if "/benchmarks/coacd/" in name]
    excitation = [s for name, s in times.items() if "/benchmarks/excitation/" in name]
    return {"all": sum(times.values()), "coacd": sum(coacd), "coacd jobs": len(coacd),
            "longest coacd": max(coacd, default=0.0), "excitation": sum(excitation),
            "rest": sum(times.values()) - sum(coacd)}


def excitation_quality(report: dict) -> str:
    """Condition number, closest approach, scaling and the worst peak against its limit of one design."""
    condition = report.get("condition_number", {})
    designed = condition.get("designed") if isinstance(condition, dict) else condition
    clearance = report.get("min_clearance_m")
    scaled = report.get("solver", {}).get("scaled_by")
    peak = report.get("peak", {})
    worst = []
    for kind, limit_kind in (("velocity_rad_s", "velocity_limit_rad_s"), ("torque_Nm", "torque_limit_Nm"),
                             ("acceleration_rad_s2", "acceleration_limit_rad_s2")):
        if kind in peak and limit_kind in peak:
            worst.append(max(abs(peak[kind][j]) / peak[limit_kind][j] for j in peak[kind]))
    inside = all(peak["position_lower_rad"][j] <= peak["position_min_rad"][j]
                 and peak["position_max_rad"][j] <= peak["position_upper_rad"][j]
                 for j in peak.get("position_min_rad", {})) if "position_lower_rad" in peak else None
    return (f"condition number {designed}, closest approach "
            f"{'-' if clearance is None else f'{clearance * 1e3:.1f} mm'}, scaled by {scaled}, "
            f"peak / limit {'-' if not worst else f'{max(worst):.3f}'}, positions inside limits {inside}")


def minutes(seconds: float) -> str:
    return f"{int(seconds // 60)} min {seconds % 60:04.1f} s"


def print_build(label: str, builds: list[ColdBuild]) -> None:
    print(f"  {label}: {', '.join(minutes(b.total) for b in builds)}")
    for index, (part, _) in enumerate(builds[0].parts):
        print(f"    {part}: {', '.join(minutes(b.parts[index][1]) for b in builds)}")
    for b in builds:
        split = split_times(b.rule_times)
        longest = max(split["longest coacd"], 1e-9)
        print(f"    rule times {split['all']:.1f} s: CoACD {split['coacd']:.1f} s over {split['coacd jobs']} jobs, "
              f"longest {split['longest coacd']:.1f} s; excitation {split['excitation']:.1f} s = "
              f"{split['excitation'] / longest:.2f}x the longest CoACD job (issue 32: at most 1); everything but CoACD "
              f"{split['rest']:.1f} s = {split['rest'] / max(split['coacd'], 1e-9):.2f}x CoACD (issue 32: at most 0.5)")
        for design, report in b.excitation.items():
            print(f"    excitation {design}: {excitation_quality(report)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--against", metavar="REV", help="also the README command of this commit, alternating")
    parser.add_argument("--repeats", type=int, default=1, help="builds of each commit")
    parser.add_argument("--head-first", action="store_true", help="HEAD's build first (default: REV's first)")
    parser.add_argument("--keep", metavar="DIR", type=Path, help="keep the clones under DIR (default: removed)")
    args = parser.parse_args()
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                          check=True).stdout.strip()
    if subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"], capture_output=True,
                      text=True, check=True).stdout.strip():
        print(f"note: the work tree has uncommitted changes; the clones hold the commit {head} only")
    revs = [head] if args.against is None else [head, args.against] if args.head_first else [args.against, head]
    builds: dict[str, list[ColdBuild]] = {rev: [] for rev in revs}
    with tempfile.TemporaryDirectory(prefix="sim2real-cold-") as tmp:
        root = args.keep or Path(tmp)
        for repeat in range(args.repeats):
            for rev in revs if repeat % 2 == 0 else revs[::-1]:
                dest = root / f"{rev}-{repeat + 1}"
                if dest.exists():
                    shutil.rmtree(dest)
                build = run_readme_command(rev, dest)
                builds[rev].append(build)
                print(f"{rev} build {repeat + 1}: {minutes(build.total)}", flush=True)
                if args.keep is None:
                    shutil.rmtree(dest)
    print(f"README command 1 from a fresh clone ({os.cpu_count()} cores), wall time of each build:")
    for rev in revs:
        print_build(rev, builds[rev])
    if args.against is not None:
        ours, theirs = (statistics.median(b.total for b in builds[rev]) for rev in (head, args.against))
        print(f"  {head} / {args.against}, medians: {minutes(ours)} / {minutes(theirs)} = {ours / theirs:.2f}x "
              "(issue 32: under 0.5x)")


if __name__ == "__main__":
    main()
