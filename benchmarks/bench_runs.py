"""A round's cost follows the samples, not the runs: one round on few long runs against the same samples cut into
ten short ones.

The lab's ``real_arm_like`` arm (the dev Panda), logged at 200 Hz: ``--total`` seconds (default 180) as one fit run
of 80 % and one holdout run of 20 % of it, and the same samples cut into ten runs of a tenth each (the fit run in
eight, the holdout in two): the same motion, the same arm and sensors; only the number of runs differs. One round (the sysid rule's function, ``run_sysid``, then the gap report's,
``build_gap_report``, with its replays and figures) runs on each, under cProfile; the script prints each round's time,
their ratio (ten runs / one run: at most 1.5) and the functions whose cumulative time grows most with the runs.

    python benchmarks/bench_runs.py [--total 180] [--effects link_inertia,asymmetric_friction] [--top 15]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from harness import ROOT

from gap_fixtures import build_dev_panda  # noqa: E402

RATE_HZ = 200.0


def lab_config(directory: Path, total_s: float) -> Path:
    """configs/panda/lab.yaml with the bench's scenarios: real_arm_like logged at 200 Hz, as one fit run of 80 % of
    ``total_s`` and one holdout run of the rest."""
    data = yaml.safe_load((ROOT / "configs/panda/lab.yaml").read_text(encoding="utf-8"))
    base = {key: value for key, value in data["scenarios"]["real_arm_like"].items() if key != "description"}
    sensors = {**base["sensors"], "log_rate_hz": RATE_HZ}
    data["scenarios"] = {
        "long_fit": {**base, "sensors": sensors, "duration_s": 0.8 * total_s, "runs": [{"name": "fit", "seed": 11, "role": "fit"}]},
        "long_holdout": {**base, "sensors": sensors, "duration_s": 0.2 * total_s,
                         "runs": [{"name": "holdout", "seed": 12, "role": "holdout"}]},
    }
    path = directory / "lab.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def long_runs(directory: Path, mjcf: Path, config: Path) -> Path:
    """The fit and the holdout run simulated (once) and listed."""
    from sim2real.lab import run_lab_scenario_run

    runs = []
    for scenario, run in (("long_fit", "fit"), ("long_holdout", "holdout")):
        out = directory / scenario / f"{run}.parquet"
        if not out.exists():
            run_lab_scenario_run(mjcf, config, "panda", scenario, run, out)
        runs.append({"name": run, "path": out.as_posix(), "role": run})
    listing = directory / "one_run.yaml"
    listing.write_text(yaml.safe_dump({"runs": runs}), encoding="utf-8")
    return listing


def cut_runs(directory: Path, listing: Path) -> Path:
    """The same samples as ten runs: the fit run cut into eight equal pieces, the holdout run into two, each piece a
    run of its own (its table and metadata), so that only the number of runs differs, not the motion."""
    import pandas as pd

    runs = []
    for run in yaml.safe_load(listing.read_text(encoding="utf-8"))["runs"]:
        table = pd.read_parquet(run["path"])
        pieces = 8 if run["role"] == "fit" else 2
        for k, rows in enumerate(np.array_split(np.arange(len(table)), pieces)):
            out = directory / "pieces" / f"{run['name']}{k}.parquet"
            out.parent.mkdir(exist_ok=True)
            table.iloc[rows].reset_index(drop=True).to_parquet(out)
            shutil.copy(Path(run["path"]).with_suffix(".yaml"), out.with_suffix(".yaml"))
            runs.append({"name": f"{run['name']}{k}", "path": out.as_posix(), "role": run["role"]})
    cut = directory / "ten_runs.yaml"
    cut.write_text(yaml.safe_dump({"runs": runs}), encoding="utf-8")
    return cut


def one_round(directory: Path, urdf: Path, mjcf: Path, listing: Path, effects: list[str]) -> tuple[float, pstats.Stats]:
    """The runs prepared (not timed: a round reads them back), then one cold round under cProfile: its wall time and
    profile."""
    from sim2real.identification import sysid
    from sim2real.measurements import prepare_for_model, write_prepared_runs
    from sim2real.report import gap as report
    from sim2real.report.figures import FIGURES

    out = directory / listing.stem
    out.mkdir(exist_ok=True)
    prepared = out / "prepared_runs.npz"
    write_prepared_runs(prepared, prepare_for_model(listing, urdf, "/"))
    model = out / "model.yaml"
    model.write_text(yaml.safe_dump({"effects": effects}), encoding="utf-8")
    profiler = cProfile.Profile()
    started = time.perf_counter()
    profiler.enable()
    sysid.run_sysid("panda", sysid.SysidFiles(urdf, ROOT / "configs/panda/robot.yaml", model, prepared,
                                              out / "ladder.json", out / "params.yaml", out / "calibration.yaml",
                                              root="/", residuals=out / "residuals.npz"))
    inputs = report.GapInputs("panda", urdf, mjcf, prepared, root="/", ladder=out / "ladder.json",
                              residuals=out / "residuals.npz")
    report.build_gap_report(inputs, out / "gap.json", out / "gap.md", {k: out / f"{k}.png" for k in FIGURES})
    profiler.disable()
    return time.perf_counter() - started, pstats.Stats(profiler)


def tried_candidates(ladder: Path) -> dict[str, list[str]]:
    """The candidates each side's diagnosis fitted (what a round's trials cost follows)."""
    import json

    document = json.loads(ladder.read_text(encoding="utf-8"))
    sides = {"body": document, "actuator": document.get("actuator") or {}}
    return {side: [c["effect"] for c in section["diagnosis"]["candidates"]]
            for side, section in sides.items() if section.get("diagnosis")}


def cumulative(stats: pstats.Stats) -> dict[str, float]:
    """Cumulative seconds of every function of the package, by ``module:function``."""
    out: dict[str, float] = {}
    for (filename, _, function), (_, _, _, seconds, _) in stats.stats.items():  # type: ignore[attr-defined]
        if "sim2real" in filename:
            key = f"{filename.split('sim2real/')[-1]}:{function}"
            out[key] = out.get(key, 0.0) + seconds
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--total", type=float, default=180.0, help="seconds of log in each case")
    parser.add_argument("--effects", default="link_inertia,asymmetric_friction", help="model.yaml's effects")
    parser.add_argument("--top", type=int, default=15, help="functions listed whose time grows most")
    parser.add_argument("--keep", type=Path, help="work in this folder and keep it (its lab runs are made once)")
    args = parser.parse_args()
    effects = [e for e in args.effects.split(",") if e]
    with tempfile.TemporaryDirectory() as tmp:
        directory = args.keep or Path(tmp)
        directory.mkdir(parents=True, exist_ok=True)
        urdf, mjcf = build_dev_panda(directory)
        config = lab_config(directory, args.total)
        one = long_runs(directory, mjcf, config)
        ten = cut_runs(directory, one)
        one_s, one_stats = one_round(directory, urdf, mjcf, one, effects)
        ten_s, ten_stats = one_round(directory, urdf, mjcf, ten, effects)
        one_tried, ten_tried = (tried_candidates(directory / name / "ladder.json") for name in ("one_run", "ten_runs"))
    print(f"real_arm_like at {RATE_HZ:g} Hz, {args.total:g} s of log, model {effects or ['nominal']}:")
    print(f"  one run (fit {0.8 * args.total:g} s + holdout {0.2 * args.total:g} s): round {one_s:.1f} s")
    print(f"  the same samples as ten runs of {0.1 * args.total:g} s (the fit run cut in 8, the holdout in 2): "
          f"round {ten_s:.1f} s")
    print(f"  ten runs / one run: {ten_s / one_s:.2f}x (target: at most 1.5x)")
    for name, tried in (("one run", one_tried), ("ten runs", ten_tried)):
        print(f"  {name}: candidates tried by side: {tried}")
    a, b = cumulative(one_stats), cumulative(ten_stats)
    grows = sorted(b, key=lambda k: b[k] - a.get(k, 0.0), reverse=True)[: args.top]
    print(f"\n{'function (cumulative s)':70s}{'one run':>10s}{'ten runs':>10s}")
    for key in grows:
        print(f"{key[:70]:70s}{a.get(key, 0.0):10.2f}{b[key]:10.2f}")


if __name__ == "__main__":
    main()
