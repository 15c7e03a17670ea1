"""Virtual lab: scenarios simulate, write the measurement format, hide their effects, stay off the DAG."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from gap_fixtures import PANDA_JOINTS, build_dev_panda, short_lab_config
from sim2real.errors import InputError
from sim2real.lab import EFFECTS, load_lab_config, run_lab_scenario_run, simulate_run, write_truth
from sim2real.measurements import load_run

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def dev(tmp_path_factory):
    directory = tmp_path_factory.mktemp("lab")
    urdf, mjcf = build_dev_panda(directory)
    return {"urdf": urdf, "mjcf": mjcf, "lab": short_lab_config(directory, duration_s=3.0), "dir": directory}


def test_panda_lab_declares_demo_clean_and_every_effect():
    config = load_lab_config(REPO / "configs/panda/lab.yaml")
    scenarios = config["scenarios"]
    assert {"demo", "clean"} <= set(scenarios)
    for effect in EFFECTS:
        assert effect in scenarios and list(scenarios[effect]["effects"]) == [effect]
    assert any(len(s["effects"]) == 2 for s in scenarios.values())
    assert scenarios["demo"]["effects"]["coulomb_friction"]["model"] == "gaz_sigmoid"
    assert "demo" in load_lab_config(REPO / "configs/ur5/lab.yaml")["scenarios"]
    for s in scenarios.values():
        roles = {r["role"] for r in s["runs"]}
        seeds = {r["seed"] for r in s["runs"]}
        assert roles == {"fit", "holdout"} and len(seeds) == len(s["runs"])


def test_run_is_deterministic_inside_limits_and_in_measurement_format(dev):
    config = load_lab_config(dev["lab"])
    out = dev["dir"] / "demo" / "fit.parquet"
    run_lab_scenario_run(dev["mjcf"], dev["lab"], "panda", "demo", "fit", out)
    run = load_run(out, known_joints=PANDA_JOINTS)
    assert run.joint_names == PANDA_JOINTS and run.meta["source"] == "synthetic"
    assert run.tau is not None and run.tau_cmd is not None and run.q_cmd is not None
    lower = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
    upper = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
    assert np.all(run.q > lower) and np.all(run.q < upper)
    assert np.max(np.abs(np.diff(run.q_cmd, axis=0))) / 1e-3 < 2.175
    bytes_first = out.read_bytes()
    run_lab_scenario_run(dev["mjcf"], dev["lab"], "panda", "demo", "fit", out)
    assert out.read_bytes() == bytes_first
    _, signals, _ = simulate_run(dev["mjcf"], config["joints"], config["scenarios"]["demo"], seed=99)
    assert not np.allclose(signals["q_cmd"], run.q_cmd)  # another seed, another excitation


def test_delay_scenario_writes_commands_only_and_delays_them(dev):
    config = load_lab_config(dev["lab"])
    scenario = config["scenarios"]["actuation_delay"]
    time, signals, truth = simulate_run(dev["mjcf"], config["joints"], scenario, seed=5)
    assert "tau" not in signals and "tau_cmd" in signals
    assert truth["actuation_delay"]["delay_s"] == pytest.approx(scenario["effects"]["actuation_delay"]["delay_s"])


def test_hidden_effects_change_the_measured_torque(dev):
    config = load_lab_config(dev["lab"])
    clean = simulate_run(dev["mjcf"], config["joints"], config["scenarios"]["clean"], seed=5)[1]
    for name in ("coulomb_friction", "payload", "torque_bias", "rotor_inertia"):
        signals = simulate_run(dev["mjcf"], config["joints"], config["scenarios"][name], seed=5)[1]
        extra = np.sqrt(np.mean((signals["tau"] - clean["tau"]) ** 2))
        assert extra > 0.1, name


def test_truth_file_records_hidden_values(dev):
    out = dev["dir"] / "truth.yaml"
    write_truth(dev["lab"], dev["mjcf"], "friction_and_payload", out)
    truth = yaml.safe_load(out.read_text())
    assert set(truth["effects"]) == {"coulomb_friction", "payload"}
    assert truth["effects"]["payload"]["mass"] == 1.5


def test_unknown_effect_and_bad_per_joint_values_are_clear(dev, tmp_path):
    data = yaml.safe_load(dev["lab"].read_text())
    data["scenarios"]["clean"] = {"effects": {"backlashh": {"x": 1}}}
    bad = tmp_path / "lab.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(InputError, match="backlashh"):
        load_lab_config(bad)
    config = load_lab_config(dev["lab"])
    scenario = dict(config["scenarios"]["clean"], effects={"viscous_friction": {"coefficient": [1.0, 2.0]}})
    with pytest.raises(InputError, match="2 values for 7 joints"):
        simulate_run(dev["mjcf"], config["joints"], scenario, seed=1)


def test_no_comparing_rule_takes_truth_yaml(tmp_path):
    """Dry-run the whole DAG (forced) and check every job's inputs: truth.yaml feeds no rule but its own."""
    work = tmp_path / "wf"
    work.mkdir()
    for item in ("Snakefile", "rules", "configs", "schemas", "scripts", "robots", "report", "profiles"):
        src = REPO / item
        if src.is_dir():
            shutil.copytree(src, work / item)
        elif src.exists():
            shutil.copy2(src, work / item)
    snakemake = Path(sys.executable).with_name("snakemake")
    result = subprocess.run(
        [str(snakemake), "-n", "--forceall", "-c1", "--directory", str(work), "--snakefile", str(work / "Snakefile"),
         "results/panda/gap.json", "results/ur5/gap.json", "results/panda/lab/demo/truth.yaml"],
        capture_output=True, text=True, cwd=work, timeout=300,
    )
    assert result.returncode == 0, result.stderr[-3000:] + result.stdout[-3000:]
    jobs = re.split(r"\n(?=(?:local)?(?:rule|checkpoint) )", result.stdout)
    seen_rules = set()
    for job in jobs:
        head = re.match(r"(?:local)?(?:rule|checkpoint) (\w+):", job)
        if not head:
            continue
        seen_rules.add(head.group(1))
        inputs = re.search(r"input: (.*)", job)
        if head.group(1) == "gap_report":
            assert inputs and re.search(r"lab/\w+/holdout\.parquet", inputs.group(1))  # the check sees real inputs
        if head.group(1) != "lab_truth" and inputs:
            assert "truth.yaml" not in inputs.group(1), f"rule {head.group(1)} reads truth.yaml"
    assert {"gap_report", "lab_run", "lab_truth"} <= seen_rules


# ---- sensors.torque_sensor: a link-side joint torque sensor (the Panda's tau_J) beside the motor-side one


def _with_sensor(scenario: dict, where: str, **sensors) -> dict:
    return dict(scenario, sensors=dict(scenario["sensors"], torque_sensor=where, **sensors))


LINK_IDENTITY_CASES = {
    "frictionloss_damping_payload_gains": {
        "rotor_inertia": {"armature": [0.08, 0.06, 0.05, 0.05, 0.03, 0.03, 0.02]},
        "viscous_friction": {"coefficient": [0.6, 0.6, 0.5, 0.5, 0.3, 0.3, 0.2]},
        "coulomb_friction": {"coefficient": [0.8, 0.8, 0.6, 0.6, 0.4, 0.4, 0.3]},
        "payload": {"mass": 1.5, "com": [0.0, 0.0, 0.15]},
        "actuator_gain": {"gain": [0.9, 0.88, 1.08, 0.92, 1.12, 0.95, 0.9]},
        "command_bias": {"bias": [0.4, -0.5, 0.3, -0.4, 0.25, -0.2, 0.15]},
        "torque_gain": {"gain": [1.08, 1.1, 0.92, 1.1, 0.9, 1.1, 0.9]},
        "torque_bias": {"bias": [0.6, -0.8, 0.5, -0.6, 0.4, -0.3, 0.3]},
    },
    "gaz_links_delay": {
        "rotor_inertia": {"armature": [0.08, 0.06, 0.05, 0.05, 0.03, 0.03, 0.02]},
        "coulomb_friction": {"model": "gaz_sigmoid", "phi1": [0.55, 0.87, 0.64, 1.28, 0.84, 0.3, 0.56],
                             "phi2": [5.1, 9.1, 10.1, 5.6, 8.3, 17.1, 10.3],
                             "phi3": [0.04, 0.026, -0.046, 0.036, 0.026, -0.021, 0.0036]},
        "link_inertia": {"mass_scale": [1.1, 1.25, 0.85, 1.2, 1.15, 0.8, 1.1],
                         "com_offset": {"panda_joint4": [-0.01, 0.02, 0.0], "panda_joint6": [0.02, -0.01, 0.0]}},
        "actuation_delay": {"delay_s": 0.004},
    },
}


@pytest.mark.parametrize("case", sorted(LINK_IDENTITY_CASES))
def test_link_side_sensor_is_applied_torque_minus_the_drive_terms(dev, case):
    """Noise-free link-side tau against the real arm's forward dynamics at the logged true state: the applied
    torque minus rotor inertia * qacc, plus the joint's damping, frictionloss and Gaz torques (all negative
    work on the rotor), which the full model's forward dynamics computes independently of the lab's link model."""
    from sim2real.lab import _apply_spec_effects, arm_spec, compile_arm, gaz_friction

    config = load_lab_config(dev["lab"])
    joints = config["joints"]
    effects = LINK_IDENTITY_CASES[case]
    exact = {"torque_noise_std": 0.0, "encoder_resolution_rad": 0.0, "velocity_noise_std": 0.0}
    base = dict(config["scenarios"]["clean"], duration_s=0.5, effects=effects)
    _, motor, _ = simulate_run(dev["mjcf"], joints, _with_sensor(base, "motor", **exact), seed=3)
    _, link, truth = simulate_run(dev["mjcf"], joints, _with_sensor(base, "link", **exact), seed=3)
    for kind in ("q", "qd", "tau_cmd"):  # the sensor's extra MuJoCo calls leave the motion untouched
        assert np.array_equal(motor[kind], link[kind]), kind

    def per_joint(name, key, absent):
        return np.array([truth[name][key][j] for j in joints]) if name in truth else np.full(len(joints), absent)

    delay = int(round(truth.get("actuation_delay", {}).get("delay_s", 0.0) * 1000.0))
    cmd = link["tau_cmd"][np.maximum(np.arange(len(link["tau_cmd"])) - delay, 0)]
    applied = per_joint("actuator_gain", "gain", 1.0) * cmd + per_joint("command_bias", "bias", 0.0)
    gain, bias = per_joint("torque_gain", "gain", 1.0), per_joint("torque_bias", "bias", 0.0)
    np.testing.assert_allclose(motor["tau"], gain * applied + bias, atol=1e-9)  # the motor side sees the applied torque
    tau_link = (link["tau"] - bias) / gain

    spec = arm_spec(dev["mjcf"], joints)
    _apply_spec_effects(spec, joints, effects, None)
    real, qadr, dadr = compile_arm(spec, joints)
    data = mujoco.MjData(real)
    armature = real.dof_armature[dadr]
    assert np.all(armature >= np.array(effects["rotor_inertia"]["armature"]))
    gaz = None
    if "phi1" in effects["coulomb_friction"]:
        gaz = [np.asarray(effects["coulomb_friction"][k], dtype=float) for k in ("phi1", "phi2", "phi3")]
    expected = np.empty_like(tau_link)
    for k in range(len(tau_link)):
        data.qpos[qadr], data.qvel[dadr] = link["q"][k], link["qd"][k]
        data.ctrl[:] = applied[k]
        data.qfrc_applied[dadr] = -gaz_friction(link["qd"][k], *gaz) if gaz else 0.0
        mujoco.mj_forward(real, data)
        # Rotor: armature * qacc = applied - tau_link + (damping + frictionloss + Gaz torques on the joint)
        expected[k] = (applied[k] - armature * data.qacc[dadr] + data.qfrc_passive[dadr]
                       + data.qfrc_constraint[dadr] + data.qfrc_applied[dadr])
    np.testing.assert_allclose(tau_link, expected, rtol=0, atol=1e-8)
    drive = np.sqrt(np.mean((applied - tau_link) ** 2, axis=0))
    assert np.all(drive > 0.05), drive  # the drive terms are there to be removed on every joint


def test_link_side_sensor_moves_rotor_inertia_and_friction_between_command_and_tau(dev):
    """tau_cmd - tau is the hidden armature * qdd plus the Gaz friction for the link-side sensor, sensor noise
    alone for the motor-side one (real_arm_like has no effect between the command and the applied torque)."""
    config = load_lab_config(dev["lab"])
    joints = config["joints"]
    scenario = config["scenarios"]["link_side_sensor"]
    assert scenario["sensors"]["torque_sensor"] == "link"
    noise = scenario["sensors"]["torque_noise_std"]
    armature = np.array(scenario["effects"]["rotor_inertia"]["armature"])
    phi = [np.array(scenario["effects"]["coulomb_friction"][k]) for k in ("phi1", "phi2", "phi3")]

    def residual_fit(signals):
        """Per joint least squares of tau_cmd - tau on [qdd, Gaz(qd), qd, 1] -> coefficients, R^2, residual RMS."""
        from sim2real.lab import gaz_friction

        m, dt = 10, 1.0 / scenario["sample_rate_hz"]
        qd = signals["qd"]
        qdd = (qd[2 * m:] - qd[:-2 * m]) / (2 * m * dt)  # central difference over 20 ms
        r = (signals["tau_cmd"] - signals["tau"])[m:-m][200:]  # past the controller's start
        qdd, qd = qdd[200:], qd[m:-m][200:]
        friction = gaz_friction(qd, *phi)
        out = []
        for j in range(len(joints)):
            A = np.column_stack([qdd[:, j], friction[:, j], qd[:, j], np.ones(len(r))])
            x, *_ = np.linalg.lstsq(A, r[:, j], rcond=None)
            rest = r[:, j] - A @ x
            out.append((x, 1.0 - rest.var() / r[:, j].var(), np.sqrt(np.mean(rest**2)), np.sqrt(np.mean(r[:, j] ** 2))))
        return out

    _, link, _ = simulate_run(dev["mjcf"], joints, scenario, seed=5)
    _, motor, _ = simulate_run(dev["mjcf"], joints, _with_sensor(scenario, "motor"), seed=5)
    for j, (x, r2, rest, total) in enumerate(residual_fit(link)):
        assert r2 > 0.85 and total > 5 * noise, (j, r2, total)
        assert x[0] == pytest.approx(armature[j], rel=0.25), (j, x)  # the hidden rotor inertia
        assert x[1] == pytest.approx(1.0, abs=0.1), (j, x)  # the hidden Gaz friction, whole
        assert rest < 1.2 * noise, (j, rest)  # nothing else: the sensor's noise
    for j, (x, r2, rest, total) in enumerate(residual_fit(motor)):
        assert r2 < 0.02 and total < 1.2 * noise, (j, r2, total)


def test_run_metadata_says_where_the_torque_sensor_sits(dev, tmp_path):
    for scenario, expected in (("link_side_sensor", "link"), ("real_arm_like", "motor"), ("actuation_delay", None)):
        out = tmp_path / scenario / "fit.parquet"
        run_lab_scenario_run(dev["mjcf"], dev["lab"], "panda", scenario, "fit", out)
        meta = yaml.safe_load(out.with_suffix(".yaml").read_text())
        assert meta.get("torque_sensor") == expected, scenario  # absent when the run logs no tau
        assert load_run(out, known_joints=PANDA_JOINTS).joint_names == PANDA_JOINTS
    truth = tmp_path / "truth.yaml"
    write_truth(dev["lab"], dev["mjcf"], "link_side_sensor", truth)
    assert yaml.safe_load(truth.read_text())["sensors"]["torque_sensor"] == "link"
    config = load_lab_config(dev["lab"])
    with pytest.raises(InputError, match="torque_sensor"):
        simulate_run(dev["mjcf"], config["joints"], _with_sensor(config["scenarios"]["clean"], "wrist"), seed=1)
    data = yaml.safe_load(dev["lab"].read_text())
    data["scenarios"]["clean"] = {"sensors": {"torque_sensor": "wrist"}}
    bad = tmp_path / "lab.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(InputError):
        load_lab_config(bad)
