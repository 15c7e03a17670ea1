"""How far another CPU's arithmetic moves the demo's pinned numbers (issue 59), measured on this machine.

The pinned test (tests/test_loop_pinned.py) compares the demo's ladder and diagnoses with
tests/data/loop_pinned.json within tolerances per kind of number (tests/pinned.py). Those tolerances must hold
on any CPU with room to spare. Another CPU is reproduced here: the demo's pinned document is computed in a fresh
process under each OpenBLAS kernel family this CPU can run (``OPENBLAS_CORETYPE``, set explicitly per process:
the machine's own setting is overridden; numpy's and scipy's bundled OpenBLAS both honour it, and the kernel
each actually runs is printed), with the fit's candidates on one and on two processes, and with the consistent
fit's SDP solved to looser tolerances than Clarabel's 1e-11 (patched inside the subprocess only). Every setting is
compared with the first (this machine's default kernel, one process): per kind of number the largest move, the
tolerance's share it uses (largest move / tolerance) and the room left (tolerance / largest move).

    python benchmarks/bench_pinned_spread.py [--kernels SkylakeX Haswell ...] [--save sweep.json | --load sweep.json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path
from typing import Any

from harness import ROOT

# The kernel families OpenBLAS 0.3 ships for x86-64, newest first (Zen runs Haswell's kernels, Core2 and
# Prescott the same generic SSE3 ones; a family the CPU cannot run falls back to the CPU's own, printed).
KERNELS = ("SkylakeX", "Haswell", "Zen", "SandyBridge", "Nehalem", "Core2", "Prescott")
SOLVER_TOLERANCES = (1e-10, 1e-9)  # the consistent fit solves to 1e-11 (inertial/conic.py)
# A CPU without AVX-512 (or AVX2) also runs numpy's own loops (exp, sin, sums) in their narrower forms.
NUMPY_WITHOUT = {"Haswell": "X86_V4 AVX512_ICL", "SandyBridge": "X86_V3 X86_V4 AVX512_ICL"}


def _loosen_clarabel(tolerance: float) -> None:
    """The consistent fit's precise solve at ``tolerance`` instead of 1e-11: Clarabel's solver is wrapped in this
    process only, nothing in src/ changes."""
    import clarabel

    from sim2real.identification.inertial import conic

    def solver(p, q, a, b, cones, settings):  # noqa: ANN001, ANN202  (Clarabel's own signature)
        if settings.tol_feas == 1e-11:  # the precise solve; the fallback's 1e-6 stays
            settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = tolerance
        return clarabel.DefaultSolver(p, q, a, b, cones, settings)

    shim = types.ModuleType("clarabel")
    shim.__dict__.update({**clarabel.__dict__, "DefaultSolver": solver})
    conic.clarabel = shim  # conic imports clarabel inside its functions: the shim goes into sys.modules too
    sys.modules["clarabel"] = shim


def one_setting(workers: int, solver_tolerance: float | None, out: Path) -> None:
    """The demo's pinned numbers in this process (its environment chose the kernel), written to ``out``."""
    from threadpoolctl import threadpool_info

    from pinned import loop_document, pinned_numbers
    from sysid_lab import Lab

    if solver_tolerance is not None:
        _loosen_clarabel(solver_tolerance)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as directory:
        numbers = pinned_numbers(loop_document(Lab(Path(directory)), workers=workers))
    kernels = sorted({f"{Path(i['filepath']).parent.name.split('.')[0]}:{i.get('architecture')}"
                      for i in threadpool_info() if i["internal_api"] == "openblas"})
    out.write_text(json.dumps({"numbers": numbers, "kernels": kernels, "seconds": time.perf_counter() - start}))


def run_setting(kernel: str, workers: int, solver_tolerance: float | None, numpy_without: str,
                directory: Path) -> dict[str, Any]:
    out = directory / f"{kernel}-{workers}-{solver_tolerance}-{len(numpy_without)}.json"
    env = {**os.environ, "OPENBLAS_CORETYPE": kernel, "NPY_DISABLE_CPU_FEATURES": numpy_without}
    command = [sys.executable, __file__, "--one", str(out), "--workers", str(workers)]
    if solver_tolerance is not None:
        command += ["--solver-tolerance", repr(solver_tolerance)]
    done = subprocess.run(command, env=env, cwd=ROOT, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"{kernel}, workers {workers}, tolerance {solver_tolerance} failed:\n{done.stderr[-3000:]}")
    return {"kernel": kernel, "workers": workers, "solver_tolerance": solver_tolerance,
            "numpy_without": numpy_without, **json.loads(out.read_text())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kernels", nargs="+", default=list(KERNELS))
    parser.add_argument("--save", type=Path, help="write every setting's numbers here (JSON)")
    parser.add_argument("--load", type=Path, help="compare a saved sweep instead of running one")
    parser.add_argument("--one", type=Path, help=argparse.SUPPRESS)  # a subprocess of the sweep
    parser.add_argument("--workers", type=int, default=1, help=argparse.SUPPRESS)
    parser.add_argument("--solver-tolerance", type=float, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one is not None:
        one_setting(args.workers, args.solver_tolerance, args.one)
        return
    if args.load is not None:
        runs = json.loads(args.load.read_text())
    else:
        settings = [(kernel, workers, None, "") for kernel in args.kernels for workers in (1, 2)]
        settings += [(kernel, 2, None, NUMPY_WITHOUT[kernel]) for kernel in args.kernels if kernel in NUMPY_WITHOUT]
        settings += [(kernel, 1, tolerance, "") for kernel in args.kernels[:2] for tolerance in SOLVER_TOLERANCES]
        runs = []
        with tempfile.TemporaryDirectory() as directory:
            for setting in settings:
                run = run_setting(*setting, Path(directory))
                print(f"{describe(run)}: kernels {', '.join(run['kernels'])} ({run['seconds']:.0f} s)", flush=True)
                runs.append(run)
        if args.save:
            args.save.write_text(json.dumps(runs))
    report(runs)


def describe(run: dict[str, Any]) -> str:
    numpy = f", numpy without {run['numpy_without']}" if run["numpy_without"] else ""
    return (f"{run['kernel']:>11} workers {run['workers']} solver tol {run['solver_tolerance'] or 1e-11:.0e}"
            f"{numpy}")


def report(runs: list[dict[str, Any]]) -> None:
    """Per kind of number, its largest move from the first setting across the others: in units of its tolerance
    (and the room left) where it has one, else relative to itself; and every setting's words and shape."""
    from pinned import differences, moves

    reference = runs[0]["numbers"]
    largest: dict[str, tuple[float, float, str, str]] = {}
    print(f"\nagainst {describe(runs[0]).strip()}: differences the pinned test would report")
    for run in runs[1:]:
        found = differences(reference, run["numbers"])
        print(f"  {describe(run)}: {len(found)}" + "".join(f"\n      {line}" for line in found[:5]))
        for path, kind, pinned, got, allowed in moves(reference, run["numbers"]):
            move = abs(got - pinned)
            share = move / allowed if allowed else move / max(abs(pinned), 1e-12)
            if share >= largest.get(kind, (-1.0,))[0]:
                largest[kind] = (share, move, "/".join(map(str, path)), f"{pinned:.6g} -> {got:.6g}, {run['kernel']}")
    print("\nlargest move per kind of number (tolerance: tests/pinned.py)")
    print(f"  {'kind':<44} {'move/tolerance':>15} {'room':>6}   where")
    for kind, (share, move, path, values) in sorted(largest.items()):
        if kind.startswith(("undetermined", "interval bound")):
            print(f"  {kind:<44} {'(not by value)':>15} {'':>6}   {100 * share:.3g} % of itself: {path} ({values})")
        else:
            room = f"{1 / share:.1f}" if share > 0 else "inf"
            print(f"  {kind:<44} {share:>15.3f} {room:>6}   {path} ({values})")


if __name__ == "__main__":
    main()
