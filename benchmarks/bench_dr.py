"""Speed of the domain-randomization runtime: resolve, sampler construction, per-episode reset,
independent model copies, observation noise, and the cost of stepping with actuator delay.

Usage: .venv/bin/python benchmarks/bench_dr.py [robot ...]
Uses results/{robot}/mjcf/{robot}.xml and configs/{robot}/dr.yaml (build the MJCF first:
`snakemake results/panda/mjcf/panda.xml`). Prints one line per measurement.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

import mujoco
import numpy as np

from harness import ROOT

from sim2real.dr import DomainRandomizer, load_model, resolve_files  # noqa: E402


def per_call(function: Callable[[], object], repeats: int) -> float:
    """Median seconds per call over 5 batches of ``repeats`` calls."""
    timings = []
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(repeats):
            function()
        timings.append((time.perf_counter() - start) / repeats)
    return float(np.median(timings))


def bench(robot: str) -> None:
    mjcf = ROOT / f"results/{robot}/mjcf/{robot}.xml"
    config = ROOT / f"configs/{robot}/dr.yaml"
    if not mjcf.exists():
        print(f"{robot}: {mjcf.relative_to(ROOT)} missing; build it with snakemake first")
        return
    resolved = resolve_files(config, mjcf, robot=robot)
    print(f"{robot}: resolve dr.yaml against MJCF      {per_call(lambda: resolve_files(config, mjcf), 3) * 1e3:9.1f} ms")
    model = load_model(mjcf, resolved)
    print(f"{robot}: load MJCF with delay buffers     {per_call(lambda: load_model(mjcf, resolved), 3) * 1e3:9.1f} ms")
    print(f"{robot}: construct sampler                {per_call(lambda: DomainRandomizer(resolved, model), 5) * 1e3:9.1f} ms")
    randomizer = DomainRandomizer(resolved, model, seed=0)
    print(f"{robot}: reset() in place (per episode)   {per_call(randomizer.reset, 500) * 1e6:9.1f} us")
    print(f"{robot}: sample() independent deep copy   {per_call(randomizer.sample, 5) * 1e3:9.1f} ms")
    data = mujoco.MjData(randomizer.model)
    print(f"{robot}: reset_data() with held ctrl      {per_call(lambda: randomizer.reset_data(data), 500) * 1e6:9.1f} us")
    print(f"{robot}: observe() noise, all terms       {per_call(lambda: randomizer.observe(data), 2000) * 1e6:9.1f} us")

    def steps(m: mujoco.MjModel) -> Callable[[], None]:
        d = mujoco.MjData(m)
        return lambda: mujoco.mj_step(m, d)

    plain = mujoco.MjModel.from_xml_path(str(mjcf))
    print(f"{robot}: mj_step, no delay buffers        {per_call(steps(plain), 2000) * 1e6:9.1f} us")
    print(f"{robot}: mj_step, randomized with delay   {per_call(steps(randomizer.model), 2000) * 1e6:9.1f} us")


if __name__ == "__main__":
    for name in sys.argv[1:] or ["panda", "ur5"]:
        bench(name)
