"""Every test that follows the loop or asserts a verdict, under several OpenBLAS kernel families: pass or fail per
test and kernel (issue 66).

``bench_pinned_spread.py`` measures how far another CPU moves the demo's pinned numbers; the verdicts the other
tests assert (a status, a named effect, a rung reaching the floor) were never run on another CPU's arithmetic, and
on an AMD EPYC without AVX-512 two of them failed. This runs them as that CPU would: a fresh ``pytest -n 0`` per
kernel family with ``OPENBLAS_CORETYPE`` set for that process only (numpy's and scipy's bundled OpenBLAS both honour
it), and, for a family without AVX-512 (or AVX2), numpy's own loops without those features
(``NPY_DISABLE_CPU_FEATURES``, as bench_pinned_spread.py does). The suite itself never sets either: this is a check
run before a change is handed in, not a setting the tests depend on.

The tests are chosen from their source (:func:`selected`): a test function whose body asserts a diagnosis's status,
names a candidate, reads a verdict or the model-free ceiling's reading of a joint, follows the loop (``follow``,
``follow_the_diagnosis``, the pinned loop document) or calls ``diagnose``; tests that build the whole tree with Snakemake (``built_tree``, ``readme_run``,
``slurm_build``) are left to the suite, their verdicts being the same functions on the same fits.

    python benchmarks/bench_verdict_sweep.py [--kernels SkylakeX Haswell Prescott] [-k EXPRESSION] [--jobs 3]
                                             [--keep DIR] [--list]
"""

from __future__ import annotations

import argparse
import ast
import os
import re
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ElementTree
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from harness import ROOT

KERNELS = ("SkylakeX", "Haswell", "Prescott")
# A CPU without AVX-512 (or AVX2) also runs numpy's own loops (exp, sin, sums) in their narrower forms.
NUMPY_WITHOUT = {"Haswell": "X86_V4 AVX512_ICL", "Zen": "X86_V4 AVX512_ICL", "SandyBridge": "X86_V3 X86_V4 AVX512_ICL",
                 "Nehalem": "X86_V3 X86_V4 AVX512_ICL", "Core2": "X86_V3 X86_V4 AVX512_ICL",
                 "Prescott": "X86_V3 X86_V4 AVX512_ICL"}
# What makes a test one that follows the loop or asserts a verdict (in its own body).
LOOP_OR_VERDICT = re.compile(
    r'\["status"\]\s*(==|in)|\.status\s*(==|in)\s|Status\.|\["verdict"\]|\["candidates"\]|\.follow\(|'
    r'follow_the_diagnosis|loop_document|diagnose\(|add_effect|at_noise_floor|\["kind"\]\s*==')
WHOLE_BUILDS = ("built_tree", "readme_run", "slurm_build")
# Modules whose matches are not verdicts of a fit: the guard on where words are written, the DR config's build.
NOT_VERDICTS = ("test_words.py", "test_dr.py")


def selected(tests: Path = ROOT / "tests") -> list[str]:
    """The test functions (``file::name``) that follow the loop or assert a verdict, in file order."""
    out = []
    for path in sorted(tests.glob("test_*.py")):
        if path.name in NOT_VERDICTS:
            continue
        source = path.read_text(encoding="utf-8")
        for node in ast.parse(source).body:
            if not isinstance(node, ast.FunctionDef) or not node.name.startswith("test_"):
                continue
            arguments = {a.arg for a in node.args.args}
            if arguments & set(WHOLE_BUILDS):
                continue
            if LOOP_OR_VERDICT.search(ast.get_source_segment(source, node) or ""):
                out.append(f"tests/{path.name}::{node.name}")
    return out


def run_kernel(kernel: str, tests: list[str], keyword: str | None, directory: Path) -> tuple[dict[str, str], float]:
    """``tests`` under ``kernel`` in one fresh pytest process: each test id (with its parameters) and its outcome
    (passed, failed, error, skipped), and the wall time."""
    report = directory / f"{kernel}.xml"
    env = {**os.environ, "OPENBLAS_CORETYPE": kernel, "NPY_DISABLE_CPU_FEATURES": NUMPY_WITHOUT.get(kernel, "")}
    command = [sys.executable, "-m", "pytest", "-n", "0", "-p", "no:randomly", "-p", "no:cacheprovider", "-v",
               "--durations=0", f"--junitxml={report}", *tests] + (["-k", keyword] if keyword else [])
    start = time.perf_counter()
    with (directory / f"{kernel}.log").open("w") as log:  # each test's outcome as it comes (pytest -v)
        subprocess.run(command, env=env, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, text=True)
    seconds = time.perf_counter() - start
    if not report.exists():
        sys.exit(f"pytest under {kernel} wrote no report:\n{(directory / f'{kernel}.log').read_text()[-3000:]}")
    outcomes = {}
    for case in ElementTree.parse(report).getroot().iter("testcase"):
        name = f"{case.get('classname', '').replace('.', '/')}.py::{case.get('name')}"
        states = {child.tag for child in case}
        outcomes[name] = ("failed" if "failure" in states else "error" if "error" in states
                          else "skipped" if "skipped" in states else "passed")
    return outcomes, seconds


def kernels_run(kernel: str) -> str:
    """The OpenBLAS kernel a process under ``kernel`` actually runs (a family the CPU lacks falls back)."""
    probe = ("from threadpoolctl import threadpool_info; import numpy, scipy.linalg; "
             "print(sorted({i.get('architecture') for i in threadpool_info() if i['internal_api'] == 'openblas'}))")
    env = {**os.environ, "OPENBLAS_CORETYPE": kernel}
    return subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True).stdout.strip()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kernels", nargs="+", default=list(KERNELS))
    parser.add_argument("-k", dest="keyword", help="only the selected tests pytest's -k expression keeps")
    parser.add_argument("--list", action="store_true", help="print the selected tests and stop")
    parser.add_argument("--jobs", type=int, default=1, help="kernels run side by side (one process each)")
    parser.add_argument("--keep", type=Path, help="keep each kernel's pytest log and report in this folder")
    args = parser.parse_args()
    tests = selected()
    if args.list:
        print("\n".join(tests))
        return
    print(f"{len(tests)} test functions follow the loop or assert a verdict", flush=True)
    table: dict[str, dict[str, str]] = {}
    with tempfile.TemporaryDirectory() as scratch:
        directory = args.keep or Path(scratch)
        directory.mkdir(parents=True, exist_ok=True)
        with ThreadPoolExecutor(max_workers=args.jobs) as pool:  # each kernel is its own pytest process
            runs = list(pool.map(lambda kernel: run_kernel(kernel, tests, args.keyword, directory), args.kernels))
        for kernel, (outcomes, seconds) in zip(args.kernels, runs, strict=True):
            failed = sum(o in ("failed", "error") for o in outcomes.values())
            print(f"{kernel:>9} (runs {kernels_run(kernel)}, numpy without {NUMPY_WITHOUT.get(kernel) or 'nothing'}): "
                  f"{len(outcomes) - failed} of {len(outcomes)} pass, {seconds:.0f} s", flush=True)
            for name, outcome in outcomes.items():
                table.setdefault(name, {})[kernel] = outcome
    width = max((len(name) for name in table), default=10)
    print(f"\n{'test':<{width}}  " + "  ".join(f"{k:>9}" for k in args.kernels))
    for name, row in table.items():
        print(f"{name:<{width}}  " + "  ".join(f"{row.get(k, '-'):>9}" for k in args.kernels))
    bad = [name for name, row in table.items() if any(v in ("failed", "error") for v in row.values())]
    print(f"\n{len(table) - len(bad)} of {len(table)} tests pass under every kernel" +
          ("".join(f"\n  fails: {name} ({', '.join(k for k, v in table[name].items() if v != 'passed')})"
                   for name in bad)))


if __name__ == "__main__":
    main()
