"""Benchmark: virtual-lab demo data time and gap.json time (prints figures; not a test).

Usage: .venv/bin/python benchmarks/bench_gap.py [robot]   (needs results/{robot}/{robot}.urdf and mjcf built)
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import yaml

from sim2real.report.gap import GapInputs, build_gap_report, compute_gap
from sim2real.lab import run_lab_scenario_run, scenario_runs
from sim2real.report.figures import FIGURES


def main(robot: str = "panda") -> None:
    urdf, mjcf = Path(f"results/{robot}/{robot}.urdf"), Path(f"results/{robot}/mjcf/{robot}.xml")
    lab_config = Path(f"configs/{robot}/lab.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        entries = []
        start = time.perf_counter()
        for run in scenario_runs(lab_config, "demo"):
            out = Path(tmp) / f"{run['name']}.parquet"
            run_lab_scenario_run(mjcf, lab_config, robot, "demo", run["name"], out)
            entries.append({"name": run["name"], "path": out.as_posix(), "role": run["role"]})
        lab_s = time.perf_counter() - start
        listing = Path(tmp) / "m.yaml"
        listing.write_text(yaml.safe_dump({"runs": entries, "replay": {"horizon_s": 0.25}}))
        start = time.perf_counter()
        inputs = GapInputs(robot, urdf, mjcf, listing)
        gap, _ = compute_gap(inputs)
        compute_s = time.perf_counter() - start
        figures = {k: Path(tmp) / f"{k}.png" for k in FIGURES}
        start = time.perf_counter()
        build_gap_report(inputs, Path(tmp) / "gap.json", Path(tmp) / "gap.md", figures)
        report_s = time.perf_counter() - start
    samples = sum(r["samples"] for r in gap["runs"])
    print(f"robot                          {robot}")
    print(f"lab demo data ({len(entries)} runs)          {lab_s:6.2f} s   (target < 30 s)")
    print(f"gap numbers (no figures)       {compute_s:6.2f} s   ({samples} samples)")
    print(f"gap.json + gap.md + figures    {report_s:6.2f} s   (target < 10 s)")


if __name__ == "__main__":
    main(*sys.argv[1:])
