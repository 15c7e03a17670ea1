"""Longer Hypothesis fuzzing of every user input: the properties of tests/test_fuzz_inputs.py.

    python benchmarks/fuzz_inputs.py                 # 2000 examples per input, fixed seed
    python benchmarks/fuzz_inputs.py --examples 200  # a quick pass
    python benchmarks/fuzz_inputs.py -k tables       # one input (pytest -k expression)
    python benchmarks/fuzz_inputs.py --seed 7        # other cases than the suite's fixed seed

Prints each property's time; exits non-zero with Hypothesis's minimal failing case if one fails.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

from harness import ROOT


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=2000, help="Hypothesis examples per property")
    parser.add_argument("-k", default="", help="pytest -k expression selecting properties")
    parser.add_argument("--seed", type=int, default=None, help="a Hypothesis seed instead of the fixed derandomized one")
    args = parser.parse_args()
    env = {**os.environ, "SIM2REAL_FUZZ_EXAMPLES": str(args.examples)}
    if args.seed is not None:
        env["SIM2REAL_FUZZ_RANDOM"] = "1"
    command = [sys.executable, "-m", "pytest", "tests/test_fuzz_inputs.py", "-q", "-p", "no:cacheprovider",
               "--durations=0", "--durations-min=0.5"] + (["-k", args.k] if args.k else [])
    if args.seed is not None:
        command.append(f"--hypothesis-seed={args.seed}")
    start = time.perf_counter()
    done = subprocess.run(command, cwd=ROOT, env=env)
    print(f"fuzzing at {args.examples} examples per property: {time.perf_counter() - start:.1f} s")
    return done.returncode


if __name__ == "__main__":
    raise SystemExit(main())
