"""Designed against random excitation on the lab's real_arm_like Panda (issue 19).

Builds, in a temporary copy of the project, the designed excitation ``identification``
(configs/panda/excitation.yaml, full quality unless ``--coarse``) and the lab runs that play it
(scenario ``real_arm_like_designed``) beside the lab's random Fourier excitation of the same duration
(``real_arm_like``), and the same design with the D-optimal objective. Every fit is judged on two holdout runs
of the same arm: the lab's random one (seed 12, drawn like the random fit run) and one drawn unlike any fit
run (another series).
Prints, for each: the condition number of the identification regressor (the design's metric, on the
measured motion), the link-inertia condition number gap.md reports, the width of the bootstrap intervals
of the inertial parameters, and the final rung's holdout RMSE per joint; and the design's time.

    python benchmarks/bench_excitation.py [--coarse]
"""

from __future__ import annotations

import argparse
import csv
import tempfile
from pathlib import Path

import numpy as np
import yaml

from harness import ROOT

from buildtree import copy_repo, edit_yaml, make_fast, run_snakemake  # noqa: E402

from sim2real.excitation.config import load_design  # noqa: E402
from sim2real.excitation.information import Identification, condition_number, identification_effects  # noqa: E402
from sim2real.identification.fitting import load_nominal  # noqa: E402
from sim2real.measurements import load_prepared_runs  # noqa: E402
from sim2real.identification.model_config import load_model_config  # noqa: E402
from sim2real.identification.sysid import SysidFiles, run_sysid  # noqa: E402

CASES = {"random (lab)": "real_arm_like", "designed": "real_arm_like_designed",
         "designed (D)": "real_arm_like_d_optimal"}
HOLDOUTS = ["results/panda/lab/real_arm_like/holdout.parquet", "results/panda/lab/real_arm_like_other/holdout.parquet"]
LAB_VELOCITY_FRACTION = 0.5  # configs/panda/lab.yaml defaults/excitation/velocity_fraction


def interval_widths(intervals: dict) -> dict[str, float]:
    """Median width of the link masses' (kg) and centres of mass' (mm) bootstrap intervals."""
    widths: dict[str, list[float]] = {"mass": [], "com": []}
    for body in (intervals.get("link_inertia") or {}).get("links", {}).values():
        if isinstance(body, dict):
            if "mass" in body:
                widths["mass"].append(float(body["mass"][1] - body["mass"][0]))
            for pair in body.get("com", []):
                widths["com"].append(1000.0 * float(pair[1] - pair[0]))
    return {k: float(np.median(v)) if v else float("nan") for k, v in widths.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--coarse", action="store_true", help="the tests' coarse design (seconds, not minutes)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tree = copy_repo(ROOT, Path(tmp) / "project")
        full_design = (tree / "configs/panda/excitation.yaml").read_text()
        make_fast(tree)  # coarse CoACD parts (the clearance check uses them) and, for now, a coarse design
        if not args.coarse:
            (tree / "configs/panda/excitation.yaml").write_text(full_design)
        # The same design with the D-optimal objective, played by the lab in a scenario of its own; both within
        # the velocity envelope of the lab's random excitation (half the velocity limit), for a fair comparison.
        def designs(data: dict) -> None:
            data["defaults"]["margins"]["velocity_fraction"] = 1.0 - LAB_VELOCITY_FRACTION
            data["designs"]["identification_d_optimal"] = {"objective": "d_optimal"}

        edit_yaml(tree / "configs/panda/excitation.yaml", designs)

        def d_optimal_scenario(data: dict) -> None:
            scenario = dict(data["scenarios"]["real_arm_like_designed"])
            scenario["runs"] = [dict(run, excitation="identification_d_optimal") if run.get("excitation") else run
                                for run in scenario["runs"]]
            data["scenarios"]["real_arm_like_d_optimal"] = scenario

        edit_yaml(tree / "configs/panda/lab.yaml", d_optimal_scenario)
        # A second holdout drawn unlike every fit run: another series (4 harmonics of another base frequency,
        # other amplitudes, another seed) on the same arm. The first is drawn like the random fit run.
        edit_yaml(tree / "configs/panda/lab.yaml", lambda data: data["scenarios"].update(real_arm_like_other={
            **data["scenarios"]["real_arm_like"],
            "excitation": {"harmonics": 4, "base_frequency_rad_s": 0.6, "position_fraction": 0.4,
                           "velocity_fraction": 0.4},
            "runs": [{"name": "holdout", "seed": 21, "role": "holdout"}]}))
        runs = [f"results/panda/lab/{scenario}/fit.parquet" for scenario in CASES.values()] + HOLDOUTS
        run_snakemake(tree, *runs, "results/panda/excitation/identification.json",
                      "results/panda/excitation/identification_d_optimal.json", timeout=3600)
        for name in ("identification", "identification_d_optimal"):
            design_seconds = 0.0  # the design and its start (rule excitation_start)
            for job in (f"{name}.start", name):
                with open(tree / f"results/panda/benchmarks/excitation/{job}.tsv") as handle:
                    design_seconds += float(next(csv.DictReader(handle, delimiter="\t"))["s"])
            design = yaml.safe_load((tree / f"results/panda/excitation/{name}.json").read_text())
            print(f"design {name} ({design['objective']}): {design['solver']['status']} after "
                  f"{design['solver']['iterations']} IPOPT iterations, {design_seconds:.1f} s (rule times, its start's "
                  f"included); condition number {design['condition_number']['initial']:.4g} (where it started) -> "
                  f"{design['condition_number']['designed']:.4g}; closest approach {design['min_clearance_m'] * 1000:.1f} mm"
                  + (f"; scaled by {design['solver']['scaled_by']:.4g} to pass the every-sample check"
                     if design["solver"]["scaled_by"] < 1 else ""))
        model = load_model_config(tree / "configs/panda/model.yaml")
        robot = yaml.safe_load((tree / "configs/panda/robot.yaml").read_text())
        settings = load_design(tree / "configs/panda/excitation.yaml", "identification")
        joints = settings.joints
        nominal = load_nominal(tree / "results/panda/panda.urdf", joints, robot["armature"], robot["flange"])
        dyn = nominal.dynamics
        ident = Identification(nominal, identification_effects(model.effects), settings.per_joint("noise_floor"),
                               dyn.lower, dyn.upper, dyn.velocity_limit, settings.per_joint("acceleration_limit"))
        print(f"model: {', '.join(model.effects)}")
        rows = []
        for (label, scenario), holdout in [(case, h) for h in HOLDOUTS for case in CASES.items()]:
            print(f"  {label}: fit on {scenario}/fit, judged on {holdout}")
            listing = tree / f"{scenario}.measurements.yaml"
            listing.write_text(yaml.safe_dump({"runs": [
                {"name": "fit", "path": f"results/panda/lab/{scenario}/fit.parquet", "role": "fit"},
                {"name": "holdout", "path": holdout, "role": "holdout"}]}))
            prepared = load_prepared_runs(listing, joints, tree)
            fit_run = prepared[0]
            step = max(1, len(fit_run.time) // 2000)
            cond = condition_number(ident.matrix(fit_run.q[::step], fit_run.qd[::step], fit_run.qdd[::step]))
            out = Path(tmp) / scenario / Path(holdout).parent.name
            document = run_sysid("panda", SysidFiles(tree / "results/panda/panda.urdf", tree / "configs/panda/robot.yaml",
                                                     tree / "configs/panda/model.yaml", listing, out / "ladder.json",
                                                     out / "params.yaml", out / "calibration.yaml", root=tree))
            rung = document["ladder"][-1]
            link = rung["params"]["link_inertia"]
            widths = interval_widths(rung.get("intervals") or {})
            holdout_rmse = rung["metrics"]["torque_rmse"]
            rows.append((f"{label} / {Path(holdout).parent.name}", cond, link["condition_number"], widths, holdout_rmse,
                         rung["metrics"]["torque_x_floor"]["per_joint"]))
        print()
        print(f"{'excitation / holdout':42s} {'cond (design)':>13s} {'cond (gap.md)':>13s} {'mass CI [kg]':>12s} "
              f"{'COM CI [mm]':>11s} {'holdout RMSE [N*m]':>18s}  per joint x floor")
        for label, cond, link_cond, widths, holdout, x_floor in rows:
            print(f"{label:42s} {cond:13.4g} {link_cond:13.4g} {widths['mass']:12.4g} {widths['com']:11.4g} "
                  f"{holdout['overall']:18.4g}  " + " ".join(f"{x:.2f}" for x in x_floor.values()))


if __name__ == "__main__":
    main()
