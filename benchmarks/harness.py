"""What the benchmarks share: the repository's root (with the tests' helpers importable: the dev Panda, the
lab fixtures, copies of the project), wall-clock timing, and timed Snakemake runs that stop the benchmark
with Snakemake's own log when a run fails.

Every benchmark starts with ``from harness import ROOT`` (``python benchmarks/bench_*.py`` puts this folder
on the path).
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "tests") not in sys.path:
    sys.path.insert(0, str(ROOT / "tests"))

Result = TypeVar("Result")


def timed(function: Callable[..., Result], *args: object, **kwargs: object) -> tuple[Result, float]:
    """``function(*args, **kwargs)`` and its wall time in seconds."""
    start = time.perf_counter()
    result = function(*args, **kwargs)
    return result, time.perf_counter() - start


def snakemake(tree: Path, *args: str) -> tuple[float, str]:
    """Snakemake in ``tree`` with this interpreter's installation: (wall seconds, its log). A failed run stops the
    benchmark with the log's tail: a figure of a failed build means nothing."""
    (done, seconds) = timed(subprocess.run, [sys.executable, "-m", "snakemake", *args], cwd=tree,
                            capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(done.stdout[-3000:] + done.stderr[-3000:])
    return seconds, done.stdout + done.stderr


def jobs_run(log: str) -> int:
    """How many jobs (rules and checkpoints) a Snakemake log says it ran."""
    return len(re.findall(r"^\s*(?:local)?(?:rule|checkpoint) \w+:", log, flags=re.MULTILINE))
