"""The KUKA LBR iiwa 14, the third shipped robot: its assets (primitives, an optional gripper) and its lab arm, whose
loop a user follows from the nominal URDF to the true model's level.

The lab arm (configs/iiwa14/lab.yaml ``real_arm_like``) is a real iiwa's: the FRI cycle (2 ms here, 1-5 ms in its
other scenarios), link-side torque sensors with offsets of each run's own, wrist torques a hundred times smaller than
the shoulder's (its inertials), a tool on the flange the URDF leaves bare, Gaz friction in the drives.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pandas as pd
import pytest
import yaml

import sysid_lab
from sim2real.assets.meshes import BuiltMeshes
from sim2real.assets.mjcf import build_mjcf
from sim2real.assets.urdf import build_urdf, mesh_names
from sim2real.assets.usd import build_usd
from sim2real.assets.usd_validation import compliance_errors
from sim2real.errors import InputError
from sim2real.identification.fitting.nominal import body_hulls
from sim2real.lab import run_lab_scenario_run
from sysid_lab import Lab

JOINTS = [f"iiwa_joint_{i}" for i in range(1, 8)]
# The lab arm logged as a ROS 2 joint_states recording of the FRI driver: positions and link-side torques, no command
# (one link judged: a round in about 10 s at the fast settings).
SCENARIO = "real_arm_like_joint_states"
# What the lab hides, in the library's words: CAD inertias off and the tool (merged into the last body), the share
# of Gaz's friction (an offset sigmoid) after the sensor, each run's sensor offsets.
TRUE_MODEL = ["link_inertia", "asymmetric_friction", "sensor_drift"]


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Lab:
    """The iiwa's lab on the sysid tests' 8 s runs (4000 samples at the 2 ms FRI cycle). On 6 s runs each run's
    drift, a quadratic and two exponentials in its time, takes part of the motion's torque on iiwa_joint_3 and raises it."""
    return Lab(tmp_path_factory.mktemp("iiwa14_lab"), "iiwa14")


def per_joint(rung: dict) -> np.ndarray:
    return np.array([rung["metrics"]["torque_rmse"]["per_joint"][j] for j in JOINTS])


def test_every_rung_lowers_some_joint_raises_none_and_the_loop_ends_at_the_true_models_level(lab: Lab) -> None:
    documents = lab.follow(SCENARIO)
    last = documents[-1]
    ladder = last["ladder"]
    assert [d["diagnosis"]["candidates"][0]["effect"] for d in documents[:1]] == ["link_inertia"]
    assert len(ladder) >= 3, [d["diagnosis"]["verdict"] for d in documents]
    for before, after in zip(ladder, ladder[1:]):
        was, now = per_joint(before), per_joint(after)
        assert np.any(now < was), (after["effects"], was, now)
        assert np.all(now <= was), (after["effects"], dict(zip(JOINTS, was)), dict(zip(JOINTS, now)))
    assert "sensor_drift" in ladder[-1]["effects"], "the per-run offsets are estimated on each run"
    assert last["diagnosis"]["status"] == "at_noise_floor", last["diagnosis"]["verdict"]
    assert all(x <= 1.5 for x in ladder[-1]["metrics"]["torque_x_floor"]["per_joint"].values())
    truth = lab.ladder(SCENARIO, TRUE_MODEL, diagnose=False)["ladder"][-1]
    assert sysid_lab.overall(ladder[-1]) <= 1.05 * sysid_lab.overall(truth), (ladder[-1]["effects"], truth["effects"])


def test_on_a_smoothed_log_the_declared_drift_is_kept_off_the_joint_it_would_raise(lab: Lab) -> None:
    """real_arm_like_smoothed_200hz (a 20 Hz low-pass inside the sensor chain, logged at 200 Hz): no candidate is
    decisive, and the ceiling finds each run's offsets. The drift's line written for every joint raises iiwa_joint_6
    beyond the noise (about 2x -> 5x its floor), so the advice is held to the loop's rule as a candidate is: the line
    is kept on the joints it helps, the report says which joint it would raise and by how much, and the loop that
    follows it raises no joint and ends at the true model's level, the low-pass still unexplained."""
    scenario = "real_arm_like_smoothed_200hz"
    documents = lab.follow(scenario)
    advised = [d["diagnosis"]["model_free"] for d in documents
               if (d["diagnosis"].get("model_free") or {}).get("declare")]
    assert advised, [d["diagnosis"]["verdict"] for d in documents]
    declare = advised[0]["declare"]
    assert "iiwa_joint_6" in declare["raised"] and "iiwa_joint_6" not in declare["kept_to"], declare
    assert declare["line"] == "- sensor_drift: {joints: [" + ", ".join(declare["kept_to"]) + "]}"
    assert "Written for every joint, it raises iiwa_joint_6 from" in advised[0]["text"], advised[0]["text"]
    assert f"add the line '{declare['line']}'" in advised[0]["text"]
    ladder = documents[-1]["ladder"]
    assert ladder[-1]["effects"][-1] == "sensor_drift"
    assert documents[-1]["settings"]["fit"]["effect_joints"]["sensor_drift"] == declare["kept_to"]
    # round by round, as the user sees each line added (the body link's; the actuator link names the friction)
    rounds = [d["ladder"][-1] for d in documents]
    for before, after in zip(rounds, rounds[1:]):
        if after["effects"] == before["effects"]:
            continue
        was, now = ([rung["metrics"]["torque_x_floor"]["per_joint"][j] for j in JOINTS] for rung in (before, after))
        assert any(b < a for a, b in zip(was, now)), (after["effects"], was, now)
        # the rule's own tolerance (diagnosis.raises.RAISE_TOLERANCE), x each joint's floor
        assert all(b <= max(a, 1.5) + 0.1 for a, b in zip(was, now)), (after["effects"], was, now)
    assert documents[-1]["diagnosis"]["status"] == "unexplained"
    truth = lab.ladder(scenario, TRUE_MODEL, diagnose=False)["ladder"][-1]
    assert sysid_lab.overall(ladder[-1]) <= 1.05 * sysid_lab.overall(truth), (ladder[-1]["effects"], truth["effects"])


def test_the_lab_arm_logs_like_an_iiwa_over_fri(lab: Lab) -> None:
    listing = yaml.safe_load(lab.measurement_list(SCENARIO).read_text())
    fit = next(run for run in listing["runs"] if run["role"] == "fit")
    table = pd.read_csv(fit["path"])
    meta = yaml.safe_load(Path(fit["path"]).with_suffix(".yaml").read_text())
    assert meta["torque_sensor"] == "link" and meta["sample_rate_hz"] == 500.0
    assert not any(c.startswith("qd.") for c in table.columns), "FRI reports no joint velocity"
    torque = table[[f"tau.{j}" for j in JOINTS]]
    # the wrist turns a 1.2 kg link about its own axis, the shoulder holds the arm
    assert torque[f"tau.{JOINTS[1]}"].abs().mean() > 50 * torque[f"tau.{JOINTS[6]}"].abs().mean()


@pytest.mark.parametrize(("scenario", "rate_hz"), [("real_arm_like_200hz", 200.0), ("real_arm_like_1khz", 1000.0)])
def test_the_lab_arm_runs_at_either_end_of_the_fri_rates(lab: Lab, tmp_path: Path, scenario: str, rate_hz: float) -> None:
    config = yaml.safe_load(lab.lab_config.read_text())
    config["scenarios"][scenario]["duration_s"] = 1.0
    short = tmp_path / "lab.yaml"
    short.write_text(yaml.safe_dump(config))
    run_lab_scenario_run(lab.mjcf, short, "iiwa14", scenario, "fit", tmp_path / "fit.csv")
    meta = yaml.safe_load((tmp_path / "fit.yaml").read_text())
    assert meta["sample_rate_hz"] == rate_hz and meta["torque_sensor"] == "link"
    steps = np.diff(pd.read_csv(tmp_path / "fit.csv")["time"].to_numpy())
    assert np.median(steps) == pytest.approx(1.0 / rate_hz, rel=0.01)


def test_primitives_give_usd_and_mjcf_and_hulls_holding_each_links_centre_of_mass(tmp_path, repo_root) -> None:
    urdf = tmp_path / "iiwa14.urdf"
    build_urdf(repo_root / "robots/iiwa14/iiwa14.urdf.xacro", urdf, {})
    assert mesh_names(urdf) == {"visual": {}, "collision": {}}, "no mesh: nothing to convert or decompose"
    config = repo_root / "configs/iiwa14/robot.yaml"
    build_usd(urdf, config, BuiltMeshes.of([], {}), tmp_path / "usd/iiwa14.usda", tmp_path / "usd/iiwa14_geometry.usda")
    assert compliance_errors(tmp_path / "usd/iiwa14.usda") == []
    build_mjcf(urdf, config, BuiltMeshes.of([], {}), tmp_path / "mjcf/iiwa14.xml", tmp_path / "mjcf/scene.xml")
    model = mujoco.MjModel.from_xml_path(str(tmp_path / "mjcf/scene.xml"))
    assert [model.joint(i).name for i in range(model.njnt)] == JOINTS
    links = [f"iiwa_link_{i}" for i in range(1, 8)]
    hulls = body_hulls(urdf, links)
    assert hulls[-1] is None and all(h is not None for h in hulls[:-1]), "the last body carries the tool: no hull"
    for link, hull in zip(links, hulls[:-1]):
        com = model.body_ipos[model.body(link).id]
        assert np.max(hull[:, :3] @ com + hull[:, 3]) < 0, link


def test_the_gripper_is_an_option_of_the_xacro_and_a_wrong_tool_is_named(tmp_path, repo_root) -> None:
    urdf = tmp_path / "iiwa14.urdf"
    build_urdf(repo_root / "robots/iiwa14/iiwa14.urdf.xacro", urdf, {"tool": "gripper"})
    settings = yaml.safe_load((repo_root / "configs/iiwa14/robot.yaml").read_text())
    settings["actuators"].append({"joints": "gripper_finger_joint1", "type": "position", "kp": 100, "kv": 10})
    config = tmp_path / "robot.yaml"
    config.write_text(yaml.safe_dump(settings))
    build_mjcf(urdf, config, BuiltMeshes.of([], {}), tmp_path / "mjcf/iiwa14.xml", tmp_path / "mjcf/scene.xml")
    model = mujoco.MjModel.from_xml_path(str(tmp_path / "mjcf/scene.xml"))
    assert model.nu == 8 and model.neq == 1, "two fingers, the second mimics the first"
    assert model.body("gripper").mass[0] == pytest.approx(0.9)
    with pytest.raises(InputError, match=r"iiwa14\.urdf\.xacro.*tool:=griper is not a tool of the iiwa14; use tool:=none"):
        build_urdf(repo_root / "robots/iiwa14/iiwa14.urdf.xacro", tmp_path / "bad.urdf", {"tool": "griper"})
    assert not (tmp_path / "bad.urdf").exists()
