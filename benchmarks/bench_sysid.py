"""Benchmark: our torque-domain ladder (fit + diagnosis) vs mujoco.sysid fitting the same parameters.

Data: the virtual lab's ``coulomb_friction`` scenario on a dev Panda (hidden MuJoCo frictionloss),
one fit run and one holdout run. Both fit the 7 Coulomb friction torques:

- ours: ``sim2real.sysid.fit_ladder(["coulomb_friction", "torque_bias"])`` -- two effects, every rung,
  bootstrap intervals and the diagnosis of the last rung included;
- mujoco.sysid: ``frictionloss`` of the 7 joints, open-loop replay of the commanded torques in
  short windows (multiple shooting: each window starts from the measured state), least squares on
  the joint positions and velocities.

Both parameter sets are judged the same way: holdout torque RMSE of the nominal model plus the
fitted friction (our torque-domain predictor). Usage: ``.venv/bin/python benchmarks/bench_sysid.py``.

Known limitation: with this setup (0.1 s open-loop windows from the filtered measured state,
scipy backend) mujoco.sysid does not converge to the lab's friction values yet; its timing is
real, its holdout error reflects that setup, not the toolbox's best.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from sysid_lab import Lab  # noqa: E402

from sim2real import sysid  # noqa: E402
from sim2real.lab import arm_spec  # noqa: E402
from sim2real.measurements import load_run, prepare_run  # noqa: E402

JOINTS = [f"panda_joint{i}" for i in range(1, 8)]
WINDOW_S = 0.1
SETTINGS = {"fit_rate_hz": 200.0, "bootstrap_replicates": 200, "refine_max_samples": 2000}


def ours(lab: Lab, scenario: str) -> tuple[float, dict, float]:
    fit_data, holdout = lab.data(scenario)
    start = time.perf_counter()
    document, result = sysid.fit_ladder(["coulomb_friction", "torque_bias"], lab.nominal, fit_data, holdout,
                                        {"fit": SETTINGS}, "panda")
    elapsed = time.perf_counter() - start
    rmse = document["ladder"][1]["metrics"]["torque_rmse"]["overall"]  # the friction rung
    return elapsed, document["ladder"][1]["params"]["coulomb_friction"]["friction"], rmse


def mujoco_sysid(lab: Lab, scenario: str) -> tuple[float, dict]:
    from mujoco import sysid as ms

    listing = lab.measurement_list(scenario)
    fit_csv = listing.parent / "fit.csv"
    prepared = prepare_run(load_run(fit_csv))
    spec = arm_spec(lab.mjcf, JOINTS)
    for joint in JOINTS:
        spec.add_sensor(name=f"pos_{joint}", type=mujoco.mjtSensor.mjSENS_JOINTPOS, objname=joint,
                        objtype=mujoco.mjtObj.mjOBJ_JOINT)
        spec.add_sensor(name=f"vel_{joint}", type=mujoco.mjtSensor.mjSENS_JOINTVEL, objname=joint,
                        objtype=mujoco.mjtObj.mjOBJ_JOINT)
    spec.option.timestep = prepared.dt
    model = spec.compile()

    def friction_modifier(joint: str):
        def apply(spec_: mujoco.MjSpec, param) -> None:
            spec_.joint(joint).frictionloss = float(np.asarray(param.value).reshape(-1)[0])
        return apply

    params = ms.ParameterDict()
    for joint in JOINTS:
        params.add(ms.Parameter(f"frictionloss_{joint}", 0.1, 0.0, 5.0, modifier=friction_modifier(joint)))
    sensors = [f"pos_{j}" for j in JOINTS] + [f"vel_{j}" for j in JOINTS]
    controls = [f"motor_{j}" for j in JOINTS]
    steps = int(round(WINDOW_S / prepared.dt))
    names, states, ctrls, datas = [], [], [], []
    for k, first in enumerate(range(0, len(prepared.time) - steps, steps)):
        window = slice(first, first + steps)
        t = prepared.time[window] - prepared.time[first]
        names.append(f"w{k}")
        states.append(ms.create_initial_state(model, prepared.q[first], prepared.qd[first]))
        ctrls.append(ms.TimeSeries.from_control_names(t, prepared.tau_cmd[window], model, controls))
        datas.append(ms.TimeSeries.from_names(
            t, np.hstack([prepared.q[window], prepared.qd[window]]), model, sensors))
    sequences = ms.ModelSequences("panda", spec, names, states, ctrls, datas)
    residual_fn = ms.build_residual_fn(models_sequences=[sequences])
    start = time.perf_counter()
    fitted, _ = ms.optimize(params, residual_fn, optimizer="scipy", verbose=False)
    elapsed = time.perf_counter() - start
    values = {j: float(np.asarray(fitted[f"frictionloss_{j}"].value).reshape(-1)[0]) for j in JOINTS}
    return elapsed, values


def holdout_rmse_with(lab: Lab, scenario: str, friction: dict, smoothing: float = 0.003) -> float:
    """Holdout torque RMSE of nominal + Coulomb friction with the given values (same predictor for both)."""
    fit_data, holdout = lab.data(scenario)
    result = sysid.fit(["coulomb_friction"], lab.nominal, fit_data, {**SETTINGS, "bootstrap_replicates": 0},
                       uncertainty=False)
    result.theta["coulomb_friction"] = np.array([friction[j] for j in JOINTS]) - lab.nominal.info["friction"]
    result.nonlinear["coulomb_friction"] = np.full(len(JOINTS), smoothing)
    metrics, _ = sysid.holdout_metrics(result, lab.nominal, holdout)
    return float(metrics["torque_rmse"]["overall"])


def main() -> None:
    scenario = "coulomb_friction"
    with tempfile.TemporaryDirectory() as tmp:
        lab = Lab(Path(tmp))
        lab.data(scenario)  # generate and prepare the runs outside the timings
        our_time, our_friction, our_rmse = ours(lab, scenario)
        our_rmse_same_predictor = holdout_rmse_with(lab, scenario, our_friction)
        try:
            mj_time, mj_friction = mujoco_sysid(lab, scenario)
            mj_rmse = holdout_rmse_with(lab, scenario, mj_friction)
        except Exception as exc:  # report, do not hide, a failure of the reference
            mj_time, mj_friction, mj_rmse = float("nan"), {}, float("nan")
            print(f"mujoco.sysid failed: {exc!r}")
    print(f"{'':28s}{'ours (ladder+diagnosis)':>26s}{'mujoco.sysid':>16s}")
    print(f"{'fit time [s]':28s}{our_time:26.2f}{mj_time:16.2f}")
    print(f"{'holdout torque RMSE [N*m]':28s}{our_rmse_same_predictor:26.4f}{mj_rmse:16.4f}")
    print(f"{'speed-up':28s}{mj_time / our_time:26.1f}x")
    for joint in JOINTS:
        print(f"  friction {joint:14s}{our_friction[joint]:26.4f}{mj_friction.get(joint, float('nan')):16.4f}")
    print(f"(our own smoothing-velocity predictor on the friction rung: {our_rmse:.4f} N*m)")


if __name__ == "__main__":
    main()
