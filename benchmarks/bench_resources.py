"""What each rule declares (threads, mem_mb, runtime) beside what its benchmark files measured.

Run after a build (`snakemake all`, or with --profile profiles/slurm): reads every
results/**/benchmarks/**/*.tsv and prints, per rule, the declared resources and the measured peak
wall time and resident memory. Rules whose measurement exceeds the declaration are listed last (the
figures to raise in rules/*.smk).

    python benchmarks/bench_resources.py [results]
"""

from __future__ import annotations

import sys
from pathlib import Path

from harness import ROOT
from resources import declared_resources, exceeded, measured_resources, resource_table, undeclared


def main() -> int:
    results = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "results"
    declared = declared_resources(ROOT / "rules")
    measured = measured_resources(results, declared)
    print(resource_table(declared, measured), end="")
    problems = undeclared(declared) + exceeded(declared, measured)
    for problem in problems:
        print(f"! {problem}")
    return 1 if problems else 0


if __name__ == "__main__":
    raise SystemExit(main())
