"""Virtual lab: scenarios simulate, write the measurement format, hide their effects, stay off the DAG."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

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
