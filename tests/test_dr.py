"""Domain randomization: config checks, resolution, runtime sampler statistics, coverage, DAG."""

from __future__ import annotations

import copy
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
import yaml
from scipy import stats

from sim2real import dr
from sim2real.errors import InputError

REPO = Path(__file__).resolve().parents[1]
ROBOTS_DIR = Path(sys.prefix) / "lib/python3.11/site-packages/cmeel.prefix/share/example-robot-data/robots"
URDFS = {"panda": "panda_description/urdf/panda.urdf", "ur5": "ur_description/urdf/ur5_robot.urdf"}


def _standin_mjcf(robot: str, target: Path) -> Path:
    """The robot's example-robot-data URDF as MJCF with position servos named after the joints
    (the shape of results/{robot}/mjcf/{robot}.xml), meshes swapped for spheres to stay fast."""
    text = (ROBOTS_DIR / URDFS[robot]).read_text()
    text = re.sub(r"<visual>.*?</visual>", "", text, flags=re.S)
    text = re.sub(r"<mesh [^>]*/>", '<sphere radius="0.04"/>', text)
    text = re.sub(r"<(gazebo|transmission).*?</\1>", "", text, flags=re.S)
    spec = mujoco.MjSpec.from_string(text)
    for joint in spec.joints:
        actuator = spec.add_actuator(name=joint.name, target=joint.name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        actuator.set_to_position(kp=200.0, kv=20.0)
    spec.compile()
    target.write_text(spec.to_xml())
    return target


@pytest.fixture(scope="module")
def mjcf(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("mjcf")
    return {robot: _standin_mjcf(robot, folder / f"{robot}.xml") for robot in URDFS}


@pytest.fixture(scope="module")
def panda_model(mjcf: dict[str, Path]) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(mjcf["panda"]))


def panda_config() -> dict[str, Any]:
    return yaml.safe_load((REPO / "configs/panda/dr.yaml").read_text())


# ---------------------------------------------------------------------------------------------
# Shipped configs


@pytest.mark.parametrize("robot", ["panda", "ur5"])
def test_shipped_config_covers_standard_set_and_resolves(robot: str, mjcf: dict[str, Path]) -> None:
    resolved = dr.resolve_files(REPO / f"configs/{robot}/dr.yaml", mjcf[robot], robot=robot)
    channels = {c["channel"]: c for c in resolved["physics"]}
    assert {"mass", "sliding_friction", "kp", "kd", "delay"} <= set(channels)
    assert {n["term"] for n in resolved["observation_noise"]} >= {"joint_position", "joint_velocity"}
    assert all(c["mode"] in ("startup", "reset") and c["targets"] for c in resolved["physics"])
    model = mujoco.MjModel.from_xml_path(str(mjcf[robot]))
    # Absolute ranges are concrete: mass scale [0.9, 1.1] around each body's MJCF mass.
    for target in channels["mass"]["targets"]:
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, target["name"])
        assert target["range"][0] == pytest.approx([0.9 * model.body_mass[body], 1.1 * model.body_mass[body]])
    assert channels["delay"]["targets"][0]["range"][0] == pytest.approx([0.010, 0.030])
    assert resolved["actuator_history_samples"] == 16  # 30 ms at 2 ms + 1 margin
    json.dumps(resolved, allow_nan=False)  # JSON-ready


# ---------------------------------------------------------------------------------------------
# Bad configs: each names the key path and the fix


def _set(config: dict[str, Any], key_path: str, value: Any) -> None:
    *parents, leaf = key_path.split("/")
    node = config
    for key in parents:
        node = node[key]
    node[leaf] = value


BAD_CONFIGS = [
    ("selector matches nothing", "physics_randomization/body_mass/body_names", ["panda_link*", "gripper_*"],
     "physics_randomization/body_mass/body_names[1]", "matches no body"),
    ("geom selector matches nothing", "physics_randomization/surface_friction/geom_names", ["table*"],
     "physics_randomization/surface_friction/geom_names[0]", "matches no colliding geom"),
    ("physics parameter at step", "physics_randomization/body_mass/mode", "step",
     "physics_randomization/body_mass/mode", "use 'mode: reset'"),
    ("observation noise at reset", "observation_noise/joint_position/mode", "reset",
     "observation_noise/joint_position/mode", "use 'mode: step'"),
    ("reversed range", "physics_randomization/surface_friction/range", [1.5, 0.3],
     "physics_randomization/surface_friction/range", "reversed"),
    ("empty range", "physics_randomization/actuator_gains/kp_range", [1.0, 1.0],
     "physics_randomization/actuator_gains/kp_range", "empty"),
    ("mass scale <= 0", "physics_randomization/body_mass/range", [0.0, 1.2],
     "physics_randomization/body_mass/range", "mass scale of 0 is not physical"),
    ("negative friction", "physics_randomization/surface_friction/range", [-0.2, 1.0],
     "physics_randomization/surface_friction/range", "friction coefficient of -0.2"),
    ("delay below zero", "physics_randomization/action_delay/delay_range", [-0.005, 0.02],
     "physics_randomization/action_delay/delay_range", "action delay of -0.005"),
    ("negative noise std", "observation_noise/joint_velocity/std", -0.1,
     "observation_noise/joint_velocity/std", "schemas/dr.schema.json"),
    ("unknown term", "physics_randomization/link_colour", {"mode": "reset"},
     "physics_randomization", "schemas/dr.schema.json"),
    ("log_uniform through zero", "physics_randomization/joint_damping/distribution", "log_uniform",
     "physics_randomization/joint_damping/range", "log_uniform needs a positive range"),
]


@pytest.mark.parametrize(("case", "key_path", "value", "where", "problem"), BAD_CONFIGS, ids=[c[0] for c in BAD_CONFIGS])
def test_bad_config_names_key_path_and_fix(
    case: str, key_path: str, value: Any, where: str, problem: str, panda_model: mujoco.MjModel
) -> None:
    config = panda_config()
    _set(config, key_path, value)
    with pytest.raises(InputError) as raised:
        dr.resolve_config(config, panda_model, config_path="configs/panda/dr.yaml", mjcf_label="panda.xml")
    message = str(raised.value)
    assert message.startswith("configs/panda/dr.yaml: key '"), message
    assert where in message and problem in message, message
    assert raised.value.fix, message


def test_added_mass_that_turns_negative_names_the_body(panda_model: mujoco.MjModel) -> None:
    config = panda_config()
    config["physics_randomization"]["body_mass"].update(operation="add", range=[-1.0, 1.0])
    with pytest.raises(InputError, match=r"body 'panda_link2'.*reaches -0.35.*not physical"):
        dr.resolve_config(config, panda_model, config_path="dr.yaml")


def test_static_dynamic_friction_template_keys_explain_mujoco(panda_model: mujoco.MjModel) -> None:
    config = panda_config()
    config["physics_randomization"]["surface_friction"]["static_friction_range"] = [0.3, 1.5]
    with pytest.raises(InputError, match="single Coulomb.*Fix: replace the static/dynamic"):
        dr.resolve_config(config, panda_model, config_path="dr.yaml")


def test_kd_on_actuator_without_damping_is_rejected(tmp_path: Path) -> None:
    xml = """<mujoco><worldbody><body><joint name="j"/><geom size=".1"/></body></worldbody>
      <actuator><motor name="j" joint="j"/></actuator></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    config = {"physics_randomization": {"actuator_gains": {"mode": "reset", "distribution": "uniform", "kd_range": [0.7, 1.3]}}}
    with pytest.raises(InputError, match="actuators j have no derivative gain"):
        dr.resolve_config(config, model, config_path="dr.yaml")


# ---------------------------------------------------------------------------------------------
# Runtime sampler

STATS_CONFIG: dict[str, Any] = {
    "physics_randomization": {
        "body_mass": {"mode": "reset", "distribution": "uniform", "operation": "scale", "range": [0.8, 1.2],
                      "body_names": ["panda_link*"]},
        "joint_damping": {"mode": "reset", "distribution": "log_uniform", "operation": "abs", "range": [0.01, 1.0],
                          "joint_names": ["panda_joint[1-7]"]},
        "actuator_gains": {"mode": "reset", "distribution": "gaussian", "operation": "scale", "mean": 1.0, "std": 0.2,
                           "kp_range": [0.7, 1.3], "actuator_names": ["panda_joint[1-7]"]},
        "surface_friction": {"mode": "startup", "distribution": "uniform", "operation": "abs", "range": [0.3, 1.5]},
        "action_delay": {"mode": "reset", "distribution": "uniform", "delay_range": [10, 30], "unit": "milliseconds",
                         "shared": True, "actuator_names": ["panda_joint*"]},
        "gravity": {"mode": "reset", "distribution": "uniform", "operation": "add", "range": [-0.2, 0.2]},
    },
    "observation_noise": {
        "joint_position": {"mode": "step", "distribution": "gaussian", "std": 0.01, "joint_names": ["panda_joint*"]},
        "joint_velocity": {"mode": "step", "distribution": "uniform", "range": [-0.1, 0.1]},
    },
    "curriculum": {"levels": [{"name": "clean", "scale": 0.25}, {"name": "full", "scale": 1.0}], "default_level": "full"},
}


@pytest.fixture(scope="module")
def stats_setup(mjcf: dict[str, Path]) -> tuple[dict[str, Any], mujoco.MjModel]:
    base = mujoco.MjModel.from_xml_path(str(mjcf["panda"]))
    resolved = dr.resolve_config(copy.deepcopy(STATS_CONFIG), base, config_path="stats.yaml")
    return resolved, dr.load_model(mjcf["panda"], resolved)


def _ids(model: mujoco.MjModel, obj: mujoco.mjtObj, resolved: dict[str, Any], channel: str) -> np.ndarray:
    targets = next(c for c in resolved["physics"] if c["channel"] == channel)["targets"]
    return np.array([mujoco.mj_name2id(model, obj, t["name"]) for t in targets])


def test_samples_follow_the_declared_distributions(stats_setup: tuple[dict[str, Any], mujoco.MjModel]) -> None:
    resolved, base = stats_setup
    randomizer = dr.DomainRandomizer(resolved, base, seed=7)
    bodies = _ids(base, mujoco.mjtObj.mjOBJ_BODY, resolved, "mass")
    joints = _ids(base, mujoco.mjtObj.mjOBJ_JOINT, resolved, "damping")
    actuators = _ids(base, mujoco.mjtObj.mjOBJ_ACTUATOR, resolved, "kp")
    delayed = _ids(base, mujoco.mjtObj.mjOBJ_ACTUATOR, resolved, "delay")
    friction_startup = randomizer.model.geom_friction[:, 0].copy()
    draws: dict[str, list[np.ndarray]] = {k: [] for k in ("mass", "inertia", "damping", "kp", "bias", "delay", "gravity")}
    for _ in range(1500):
        model = randomizer.reset()
        draws["mass"].append(model.body_mass[bodies] / base.body_mass[bodies])
        draws["inertia"].append(model.body_inertia[bodies] / base.body_inertia[bodies])
        draws["damping"].append(model.dof_damping[base.jnt_dofadr[joints]].copy())
        draws["kp"].append(model.actuator_gainprm[actuators, 0] / base.actuator_gainprm[actuators, 0])
        draws["bias"].append(model.actuator_biasprm[actuators, 1] / -model.actuator_gainprm[actuators, 0])
        draws["delay"].append(model.actuator_delay[delayed].copy())
        draws["gravity"].append(model.opt.gravity - base.opt.gravity)
    arrays = {k: np.array(v) for k, v in draws.items()}

    mass = arrays["mass"]
    assert mass.min() >= 0.8 and mass.max() <= 1.2
    assert stats.kstest(mass.ravel(), stats.uniform(0.8, 0.4).cdf).pvalue > 1e-3
    assert np.allclose(arrays["inertia"], mass[:, :, None])  # inertia follows the mass
    assert abs(np.corrcoef(mass[:, 0], mass[:, 1])[0, 1]) < 0.1  # one draw per body

    damping = arrays["damping"]
    assert damping.min() >= 0.01 and damping.max() <= 1.0
    assert stats.kstest(np.log(damping.ravel()), stats.uniform(np.log(0.01), np.log(100.0)).cdf).pvalue > 1e-3

    kp = arrays["kp"]
    assert kp.min() >= 0.7 and kp.max() <= 1.3
    truncated = stats.truncnorm((0.7 - 1.0) / 0.2, (1.3 - 1.0) / 0.2, loc=1.0, scale=0.2)
    assert stats.kstest(kp.ravel(), truncated.cdf).pvalue > 1e-3
    assert np.allclose(arrays["bias"], 1.0)  # position servo stays a servo: biasprm[1] = -kp

    delay = arrays["delay"]
    assert np.allclose(delay, delay[:, :1])  # shared: one bus delay for all actuators
    assert delay.min() >= 0.010 and delay.max() <= 0.030
    assert stats.kstest(delay[:, 0], stats.uniform(0.010, 0.020).cdf).pvalue > 1e-3

    gravity = arrays["gravity"]
    assert np.abs(gravity).max() <= 0.2 and stats.kstest(gravity.ravel(), stats.uniform(-0.2, 0.4).cdf).pvalue > 1e-3
    # startup parameters are drawn once and kept for every episode
    assert np.array_equal(randomizer.model.geom_friction[:, 0], friction_startup)
    assert not np.allclose(friction_startup, base.geom_friction[:, 0])


def test_same_seed_same_models_and_noise_stream_is_separate(stats_setup: tuple[dict[str, Any], mujoco.MjModel]) -> None:
    resolved, base = stats_setup
    first, second, other = (dr.DomainRandomizer(resolved, base, seed=s) for s in (3, 3, 4))
    data = mujoco.MjData(base)
    for _ in range(5):
        second.observe(data)  # observations must not shift the model stream
        a, b, c = first.reset(), second.reset(), other.reset()
        assert np.array_equal(a.body_mass, b.body_mass) and np.array_equal(a.actuator_delay, b.actuator_delay)
        assert not np.array_equal(a.body_mass, c.body_mass)
    sampled = first.sample()
    assert sampled is not first.model and np.array_equal(sampled.body_mass, first.model.body_mass)


def test_base_model_is_never_modified(stats_setup: tuple[dict[str, Any], mujoco.MjModel]) -> None:
    resolved, base = stats_setup
    before = (base.body_mass.copy(), base.actuator_gainprm.copy(), base.geom_friction.copy(), base.opt.gravity.copy())
    randomizer = dr.DomainRandomizer(resolved, base, seed=1)
    for _ in range(3):
        randomizer.reset()
    after = (base.body_mass, base.actuator_gainprm, base.geom_friction, base.opt.gravity)
    assert all(np.array_equal(x, y) for x, y in zip(before, after))


def test_observation_noise_statistics(stats_setup: tuple[dict[str, Any], mujoco.MjModel]) -> None:
    resolved, base = stats_setup
    randomizer = dr.DomainRandomizer(resolved, base, seed=11)
    data = mujoco.MjData(base)
    data.qpos[:] = 0.3
    samples = np.array([randomizer.observe(data)["joint_position"] for _ in range(4000)]) - 0.3
    assert samples.shape == (4000, 7)  # panda_joint*: the arm, not the fingers
    assert stats.kstest(samples.ravel(), stats.norm(0.0, 0.01).cdf).pvalue > 1e-3
    velocity = np.array([randomizer.add_noise("joint_velocity", np.zeros(9)) for _ in range(2000)])
    assert velocity.min() >= -0.1 and velocity.max() <= 0.1
    assert stats.kstest(velocity.ravel(), stats.uniform(-0.1, 0.2).cdf).pvalue > 1e-3
    randomizer.set_level("clean")
    clean = np.array([randomizer.add_noise("joint_position", np.zeros(7)) for _ in range(4000)])
    assert clean.std() == pytest.approx(0.0025, rel=0.05)


def test_curriculum_level_shrinks_ranges_toward_nominal(stats_setup: tuple[dict[str, Any], mujoco.MjModel]) -> None:
    resolved, base = stats_setup
    randomizer = dr.DomainRandomizer(resolved, base, seed=5, level="clean")
    bodies = _ids(base, mujoco.mjtObj.mjOBJ_BODY, resolved, "mass")
    delayed = _ids(base, mujoco.mjtObj.mjOBJ_ACTUATOR, resolved, "delay")
    masses, delays = [], []
    for _ in range(400):
        model = randomizer.reset()
        masses.append(model.body_mass[bodies] / base.body_mass[bodies])
        delays.append(model.actuator_delay[delayed[0]])
    # scale 0.25: mass scale in 1 + 0.25 * ([0.8, 1.2] - 1); delay (nominal 0) in 0.25 * [10, 30] ms
    assert np.min(masses) >= 0.95 and np.max(masses) <= 1.05 and np.ptp(masses) > 0.09
    assert min(delays) >= 0.0025 and max(delays) <= 0.0075
    with pytest.raises(InputError, match="use one of: clean, full"):
        randomizer.set_level("hard")


def test_action_delay_uses_mujoco_actuator_delay(stats_setup: tuple[dict[str, Any], mujoco.MjModel]) -> None:
    resolved, base = stats_setup
    randomizer = dr.DomainRandomizer(resolved, base, seed=2)
    model = randomizer.reset()
    actuator = _ids(base, mujoco.mjtObj.mjOBJ_ACTUATOR, resolved, "delay")[0]
    delay = float(model.actuator_delay[actuator])
    held, stepped = mujoco.MjData(model), mujoco.MjData(model)
    for data in (held, stepped):
        randomizer.reset_data(data, ctrl=np.zeros(model.nu))
    stepped.ctrl[actuator] = 0.5  # step the position target of one servo; `held` keeps 0
    steps_until_force = None
    for step in range(40):
        mujoco.mj_step(model, held)
        mujoco.mj_step(model, stepped)
        differs = abs(stepped.actuator_force[actuator] - held.actuator_force[actuator]) > 1e-9
        if differs and steps_until_force is None:
            steps_until_force = step
    # The command reaches the joint only after the sampled delay (zero-order hold on the history).
    assert steps_until_force == int(np.ceil(delay / model.opt.timestep - 1e-9))


def test_action_lag_randomizes_the_calibrated_actuators_filter_and_is_refused_without_one(
        mjcf: dict[str, Path], tmp_path: Path) -> None:
    """An arm calibrated with actuation_lag drives its joints through MuJoCo's first-order filter; action_lag draws
    that filter's time constant per episode, within its range. A model without a filter is refused, naming the key
    and what puts a filter there; the identified time constant is checked against the randomized range."""
    from sim2real.identification.effects import apply_to_spec

    config = {"physics_randomization": {"action_lag": {
        "mode": "reset", "distribution": "uniform", "lag_range": [2, 6], "unit": "milliseconds",
        "actuator_names": ["panda_joint*"]}}}
    spec = mujoco.MjSpec.from_file(str(mjcf["panda"]))
    with pytest.raises(InputError, match="action_lag/actuator_names.*first-order filter.*actuation_lag"):
        dr.resolve_config(copy.deepcopy(config), spec.compile(), config_path="dr.yaml")
    apply_to_spec(spec, {"torque_source": "tau", "effects": {"actuation_lag": {"time_constant": 0.004}}})
    base = spec.compile()
    resolved = dr.resolve_config(copy.deepcopy(config), base, config_path="dr.yaml")
    lagged = _ids(base, mujoco.mjtObj.mjOBJ_ACTUATOR, resolved, "lag")
    assert len(lagged) and all(base.actuator_dyntype[i] == mujoco.mjtDyn.mjDYN_FILTEREXACT for i in lagged)
    randomizer = dr.DomainRandomizer(resolved, base, seed=3)
    drawn = np.array([randomizer.reset().actuator_dynprm[lagged, 0] for _ in range(300)])
    assert drawn.min() >= 0.002 and drawn.max() <= 0.006 and drawn.std() > 0.0005
    assert np.all(base.actuator_dynprm[lagged, 0] == 0.004)  # the base model is never modified
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"robot": "panda", "effects": {"actuation_lag": {"time_constant": 0.004}}}))
    coverage = dr.coverage_summary(resolved, params)
    records = [r for r in coverage["records"] if r["channel"] == "lag"]
    assert records and all(r["covered"] for r in records)


def test_model_without_history_buffer_is_refused(stats_setup: tuple[dict[str, Any], mujoco.MjModel], mjcf: dict[str, Path]) -> None:
    resolved, _ = stats_setup
    plain = mujoco.MjModel.from_xml_path(str(mjcf["panda"]))
    with pytest.raises(InputError, match="silently cap the delay.*Fix: load the model with sim2real.dr.load_model"):
        dr.DomainRandomizer(resolved, plain)


# ---------------------------------------------------------------------------------------------
# Coverage against identified values


def test_coverage_warns_lists_and_errors_when_strict(tmp_path: Path, mjcf: dict[str, Path]) -> None:
    resolved = dr.resolve_files(REPO / "configs/panda/dr.yaml", mjcf["panda"], robot="panda")
    assert dr.coverage_summary(resolved, tmp_path / "absent.yaml")["status"] == "skipped"
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"parameters": {
        "viscous_friction": {"panda_joint1": {"value": 0.4, "ci": [0.35, 0.45]},
                             "panda_joint2": {"value": 0.95, "ci": [0.9, 1.2]}},
        "actuation_delay": {"value": 0.012, "ci": [0.011, 0.013]},
        "torque_gain": {"panda_joint1": {"value": 1.1}},  # not randomized: ignored
    }}))
    summary = dr.coverage_summary(resolved, params)
    assert summary["status"] == "checked"
    assert len(summary["records"]) == 2 + 7  # two joints' damping + the global delay on 7 actuators
    assert summary["warnings"] == [
        "joint_damping/panda_joint2: identified viscous_friction 0.95 (interval [0.9, 1.2]) "
        "outside the randomized range [0, 1]"
    ]
    with pytest.raises(InputError, match="panda_joint2.*Fix: widen the matching ranges"):
        dr.coverage_summary(resolved, params, strict=True)
    # Record-list shape, keyed by joint for an actuator channel.
    records = tmp_path / "records.yaml"
    records.write_text(yaml.safe_dump([{"effect": "actuation_delay", "joint": "panda_joint3", "value": 0.05}]))
    uncovered = dr.coverage_summary(resolved, records)
    assert [r["element"] for r in uncovered["records"]] == ["panda_joint3"] and uncovered["warnings"]


def test_coverage_reads_the_sysid_params_shape(tmp_path: Path, mjcf: dict[str, Path]) -> None:
    resolved = dr.resolve_files(REPO / "configs/panda/dr.yaml", mjcf["panda"], robot="panda")
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({
        "robot": "panda",
        "effects": {"coulomb_friction": {"friction": {"panda_joint1": 0.42, "panda_joint2": 1.3},
                                         "smoothing_velocity": {"panda_joint1": 0.01}},
                    "actuation_delay": {"delay": 0.004},
                    "actuator_gain": {"gain": {"panda_joint2": 0.88, "panda_joint5": 1.4}},
                    "torque_gain": {"gain": {"panda_joint1": 1.02}}},
        "intervals": {"coulomb_friction": {"friction": {"panda_joint1": [0.40, 0.44], "panda_joint2": [1.2, 1.4]}}},
    }))
    summary = dr.coverage_summary(resolved, params)
    by_channel: dict[str, list[dict[str, Any]]] = {}
    for record in summary["records"]:
        by_channel.setdefault(record["channel"], []).append(record)
    assert [(r["element"], r["covered"], r["interval"]) for r in by_channel["frictionloss"]] == [
        ("panda_joint1", True, [0.40, 0.44]), ("panda_joint2", False, [1.2, 1.4])]
    # 4 ms identified delay lies below the randomized 10-30 ms on every actuator
    assert len(by_channel["delay"]) == 7 and not any(r["covered"] for r in by_channel["delay"])
    # The actuator link's motor gains against the randomized kp (gainprm[0] of the motors, nominal 1, +-30 %)
    assert [(r["element"], r["covered"]) for r in by_channel["kp"]] == [("panda_joint2", True), ("panda_joint5", False)]
    assert len(summary["warnings"]) == 9


# ---------------------------------------------------------------------------------------------
# Snakemake: dr.json and the summary are build outputs, reproducible


@pytest.mark.slow
def test_snakemake_builds_dr_json_and_summary_reproducibly(tmp_path: Path, mjcf: dict[str, Path]) -> None:
    for relative in ["rules/common.smk", "rules/dr.smk", "scripts/dr_resolve.py", "scripts/dr_summary.py",
                     "schemas/config.schema.yaml",
                     "report/dr_summary.rst", "schemas/dr.schema.json", "configs/config.yaml", "configs/panda/dr.yaml", "configs/ur5/dr.yaml",
                     # the Panda is identified (measurements + model ladder): its coverage is checked
                     "configs/panda/measurements.yaml", "configs/panda/model.yaml"]:
        (tmp_path / relative).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(REPO / relative, tmp_path / relative)
    # the robots whose stand-in MJCF this test has (the shipped list names others)
    (tmp_path / "configs/config.yaml").write_text(yaml.safe_dump({"robots": list(mjcf)}))
    for robot, path in mjcf.items():
        (tmp_path / f"results/{robot}/mjcf").mkdir(parents=True)
        shutil.copy(path, tmp_path / f"results/{robot}/mjcf/{robot}.xml")
    (tmp_path / "results/panda/sysid").mkdir()
    (tmp_path / "results/panda/sysid/params.yaml").write_text("coulomb_friction:\n  panda_joint4: {value: 0.3, ci: [0.25, 0.35]}\n")
    (tmp_path / "Snakefile").write_text(
        'configfile: "configs/config.yaml"\ninclude: "rules/common.smk"\ninclude: "rules/dr.smk"\n'
        "rule all:\n    default_target: True\n    input: [t for robot in ROBOTS for t in dr_targets(robot)],\n"
    )
    snakemake = [str(Path(sys.executable).parent / "snakemake"), "-c2", "--snakefile", str(tmp_path / "Snakefile"),
                 "--directory", str(tmp_path)]
    run = subprocess.run(snakemake, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-3000:]
    outputs = ["results/panda/dr.json", "results/panda/dr/summary.svg", "results/panda/dr/summary.tsv",
               "results/panda/dr/coverage.json", "results/ur5/dr.json"]
    first = {o: (tmp_path / o).read_bytes() for o in outputs}
    coverage = json.loads(first["results/panda/dr/coverage.json"])
    assert coverage["status"] == "checked" and coverage["records"][0]["covered"] is True
    assert json.loads(first["results/ur5/dr.json"])["mjcf"] == "results/ur5/mjcf/ur5.xml"  # relative
    rerun = subprocess.run(snakemake + ["--forceall"], capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    assert {o: (tmp_path / o).read_bytes() for o in outputs} == first


def test_selector_error_names_the_available_elements_in_plain_english() -> None:
    """Found by tests/test_input_errors.py (issue 21): the message said "available body with masss"."""
    from sim2real.dr.resolve import _plural

    assert _plural("body with mass") == "bodies with mass"
    assert _plural("body") == "bodies"
    assert _plural("hinge/slide joint") == "hinge/slide joints"
    assert _plural("colliding geom") == "colliding geoms"


def test_physics_randomization_not_a_map_is_an_input_error() -> None:
    """Found by tests/test_fuzz_inputs.py (issue 21): an AttributeError before the schema's message."""
    from sim2real.dr.config import validate_config

    with pytest.raises(InputError, match="dr.yaml: key 'physics_randomization'"):
        validate_config({"physics_randomization": True}, "configs/panda/dr.yaml")


def test_range_beyond_floating_point_or_an_endless_delay_is_an_input_error(panda_model: mujoco.MjModel) -> None:
    """Found by tests/test_fuzz_inputs.py (issue 21): a kp scale of 1.8e306 times kp overflowed to inf
    and write_json failed (ValueError); a delay of 1e6 s asked for a history buffer of 5e8 samples."""
    config = panda_config()
    config["physics_randomization"]["actuator_gains"]["kp_range"] = [0.7, 1.8e306]
    with pytest.raises(InputError, match=r"key 'physics_randomization/actuator_gains'.*beyond floating point"):
        dr.resolve_config(config, panda_model, config_path="dr.yaml")
    config = panda_config()
    config["physics_randomization"]["action_delay"]["delay_range"] = [0.01, 1.0e6]
    with pytest.raises(InputError, match=r"key 'physics_randomization/action_delay'.*history samples"):
        dr.resolve_config(config, panda_model, config_path="dr.yaml")
    # Found by Hypothesis: a delay near the float limit over the time step is inf, not a count.
    config["physics_randomization"]["action_delay"]["delay_range"] = [0.01, 3.6e305]
    with pytest.raises(InputError, match=r"key 'physics_randomization/action_delay'.*history samples"):
        dr.resolve_config(config, panda_model, config_path="dr.yaml")
