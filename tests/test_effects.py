"""Effect library: one shape for all, MJCF edits via MjSpec, calibration YAML the Xacro consumes."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
import yaml

from gap_fixtures import build_dev_panda
from sim2real.identification.fitting import Nonlinear
from sim2real.identification.effects import EFFECTS, apply_to_spec, calibration_from_params, get_effect, spec_edit_from_params
from sim2real.errors import InputError

VOCABULARY = {"viscous_friction", "coulomb_friction", "asymmetric_friction", "stribeck_friction", "rotor_inertia",
              "actuation_delay", "payload", "link_inertia", "torque_bias", "torque_gain", "load_friction"}
JOINTS = [f"panda_joint{i}" for i in range(1, 8)]


def test_vocabulary_and_shape():
    assert VOCABULARY <= set(EFFECTS)
    for name, effect in EFFECTS.items():
        assert effect.name == name
        assert effect.summary and effect.signature
        for spec in (*effect.parameters, *effect.nonlinear):
            assert spec.unit and spec.lower < spec.upper
    with pytest.raises(InputError, match="coulomb_friction"):
        get_effect("colomb")


PARAMS = {
    "torque_source": "tau_cmd",
    "effects": {
        "viscous_friction": {"damping": {j: 0.5 for j in JOINTS}},
        "coulomb_friction": {"friction": {j: 0.7 for j in JOINTS}, "smoothing_velocity": {j: 0.01 for j in JOINTS}},
        "rotor_inertia": {"armature": {j: 0.25 for j in JOINTS}},
        "actuation_delay": {"delay": 0.008},
        "torque_gain": {"gain": {j: 1.25 for j in JOINTS}},
        "payload": {"mass": 1.5, "com": [0.0, 0.0, 0.05], "link": "panda_link8",
                    "com_in_last_link": [0.0, 0.0, 0.157], "last_link": "panda_link7"},
    },
}


@pytest.fixture(scope="module")
def dev_mjcf(tmp_path_factory):
    _, mjcf = build_dev_panda(tmp_path_factory.mktemp("effects"))
    spec = mujoco.MjSpec.from_file(str(mjcf))
    for joint in JOINTS:  # torque motors, as the pipeline's MJCF has actuators
        spec.add_actuator(name=f"motor_{joint}", target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    return spec


def test_apply_to_spec_writes_only_what_urdf_cannot_hold_by_default(dev_mjcf):
    spec = dev_mjcf.copy()
    apply_to_spec(spec, PARAMS)
    model = spec.compile()
    dof = model.joint("panda_joint3").dofadr[0]
    assert model.dof_armature[dof] == pytest.approx(0.25)
    assert model.dof_frictionloss[dof] == pytest.approx(0.0)  # the calibrated URDF carries friction
    actuator = model.actuator("motor_panda_joint3")
    assert model.actuator_gear[actuator.id][0] == pytest.approx(1 / 1.25)
    assert spec.actuator("motor_panda_joint3").delay == pytest.approx(0.008)
    # Fitted on some joints, the delay goes to their actuators alone (a gripper's drive was not fitted).
    spec = dev_mjcf.copy()
    apply_to_spec(spec, {**PARAMS, "joints": JOINTS[1:]})
    assert spec.actuator("motor_panda_joint1").delay == 0.0 and spec.actuator("motor_panda_joint3").delay > 0


def test_apply_to_spec_can_calibrate_a_nominal_mjcf_completely(dev_mjcf):
    spec = dev_mjcf.copy()
    total_mass = spec.compile().body_mass.sum()
    apply_to_spec(spec, PARAMS, include_urdf_effects=True)
    model = spec.compile()
    dof = model.joint("panda_joint5").dofadr[0]
    assert model.dof_damping[dof] == pytest.approx(0.5)
    assert model.dof_frictionloss[dof] == pytest.approx(0.7)
    assert model.body_mass.sum() == pytest.approx(total_mass + 1.5)


def test_sensor_gain_does_not_change_the_simulation(dev_mjcf):
    spec = dev_mjcf.copy()
    apply_to_spec(spec, {**PARAMS, "torque_source": "tau"})
    assert spec.compile().actuator_gear[0][0] == pytest.approx(1.0)


def test_calibration_has_the_build_urdf_shape_and_the_xacro_takes_it(tmp_path, repo_root):
    calibration = calibration_from_params(PARAMS)
    assert calibration["joints"]["panda_joint2"] == {"damping": 0.5, "friction": 0.7}
    assert calibration["payload"]["mass"] == 1.5 and calibration["payload"]["com"] == [0.0, 0.0, 0.05]
    assert set(calibration["payload"]["inertia"]) == {"ixx", "ixy", "ixz", "iyy", "iyz", "izz"}
    assert "rotor_inertia" not in calibration and "armature" not in str(calibration)
    xacro = repo_root / "robots" / "panda" / "panda.urdf.xacro"
    if not xacro.exists():
        pytest.skip("the Panda Xacro is not in this checkout")
    from sim2real.assets.urdf import build_urdf

    path = tmp_path / "calibration.yaml"
    path.write_text(yaml.safe_dump(calibration))
    out = tmp_path / "panda.urdf"
    build_urdf(xacro, out, {"hand": "true", "calibration": str(path)})
    root = ET.parse(out).getroot()
    dynamics = root.find("joint[@name='panda_joint2']/dynamics")
    assert float(dynamics.get("damping")) == pytest.approx(0.5)
    assert float(dynamics.get("friction")) == pytest.approx(0.7)
    assert any(float(link.find("inertial/mass").get("value")) == pytest.approx(1.5)
               for link in root.findall("link") if link.find("inertial/mass") is not None)


def test_spec_edit_from_params_reads_params_yaml(tmp_path, dev_mjcf):
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(PARAMS))
    spec = dev_mjcf.copy()
    spec_edit_from_params(path)(spec)
    assert np.isclose(spec.joint("panda_joint1").armature, 0.25)


# --- friction as real arms show it: Gaz's asymmetric sigmoid, the Stribeck hump ----------------------------


@pytest.fixture(scope="module")
def motion():
    """One 20 s Fourier excitation of the Panda at 200 Hz: (time, q, qd, qdd)."""
    from sysid_synthetic import PANDA_JOINTS, PANDA_URDF, fourier_trajectory
    from sim2real.assets.dynamics import RigidBodyModel

    return fourier_trajectory(RigidBodyModel(PANDA_URDF, PANDA_JOINTS), 20.0, 200.0, seed=1)


def friction_data(motion, friction, noise=0.01):
    """TorqueData and Signals whose judged torque is ``friction(qd)`` plus white noise (nominal model: 0)."""
    from sim2real.identification.effects import Signals
    from sim2real.identification.fitting import TorqueData

    t, q, qd, qdd = motion
    tau = friction(qd) + np.random.default_rng(0).normal(scale=noise, size=qd.shape)
    segments = [slice(0, len(t))]
    data = TorqueData(JOINTS, t, q, qd, qdd, tau, segments, ["r1"], "tau", False, np.full(len(JOINTS), noise))
    signals = Signals(JOINTS, t, q, qd, qdd, np.zeros_like(tau), segments, tau=tau, nominal={})
    return data, signals


def per_joint(values):
    return np.array([values[j] for j in JOINTS])


PHI1 = np.array([0.5, 0.9, 0.6, 1.2, 0.8, 0.3, 0.6])
PHI2 = np.array([8.0, 12.0, 20.0, 6.0, 15.0, 30.0, 10.0])
PHI3 = np.array([0.05, -0.04, 0.06, 0.08, -0.05, 0.03, -0.07])  # an offset on every joint, both signs


def gaz(qd):
    return PHI1 / (1 + np.exp(-PHI2 * (qd + PHI3))) - PHI1 / (1 + np.exp(-PHI2 * PHI3))


def test_asymmetric_friction_recovers_the_gaz_sigmoid_that_coulomb_friction_cannot_fit(motion):
    from sim2real.identification.fitting import fit

    data, signals = friction_data(motion, gaz)
    result = fit(["asymmetric_friction"], None, data, signals=signals, uncertainty=False)
    values = result.values["asymmetric_friction"]
    assert per_joint(values["amplitude"]) == pytest.approx(PHI1, rel=0.03)
    assert per_joint(values["slope"]) == pytest.approx(PHI2, rel=0.03)
    assert per_joint(values["velocity_offset"]) == pytest.approx(PHI3, rel=0.03)
    assert result.fit_rmse["overall"] <= 1.05 * 0.01  # the noise floor
    coulomb = fit(["coulomb_friction"], None, data, signals=signals, uncertainty=False)
    assert coulomb.fit_rmse["overall"] >= 5 * result.fit_rmse["overall"]


def test_asymmetric_friction_works_as_a_candidate_on_top_of_coulomb_friction(motion):
    """As the diagnosis tries it: on the current model (Coulomb friction, its smoothing held)."""
    from sim2real.identification.fitting import fit

    data, signals = friction_data(motion, gaz)
    current = fit(["coulomb_friction"], None, data, signals=signals, uncertainty=False)
    held = {"coulomb_friction": current.nonlinear["coulomb_friction"]}
    added = fit(["coulomb_friction", "asymmetric_friction"], None, data, signals=signals, uncertainty=False,
                nonlinear=Nonlinear(held=held))
    bias = fit(["coulomb_friction", "torque_bias"], None, data, signals=signals, uncertainty=False,
               nonlinear=Nonlinear(held=held))
    assert added.fit_rmse["overall"] <= 1.1 * 0.01 < 0.2 * current.fit_rmse["overall"]
    assert added.fit_rmse["overall"] < 0.5 * bias.fit_rmse["overall"]  # an offset is not a constant bias
    values = added.values["asymmetric_friction"]
    assert np.all(per_joint(values["amplitude"]) > 0)
    assert np.sign(per_joint(values["velocity_offset"])) == pytest.approx(np.sign(PHI3))


FC = np.array([0.6, 0.8, 0.5, 1.0, 0.7, 0.3, 0.5])
PEAK = np.array([0.3, 0.4, 0.2, 0.5, 0.3, 0.15, 0.25])  # F_s - F_c
V_ST = np.array([0.03, 0.05, 0.08, 0.04, 0.1, 0.06, 0.05])


def stribeck(qd):
    return FC * np.tanh(qd / 0.01) + PEAK * np.exp(-((qd / V_ST) ** 2)) * np.tanh(qd / 0.005)


def test_stribeck_friction_recovers_a_hump_on_top_of_coulomb_friction(motion):
    from sim2real.identification.fitting import fit

    data, signals = friction_data(motion, stribeck)
    coulomb = fit(["coulomb_friction"], None, data, signals=signals, uncertainty=False)
    result = fit(["coulomb_friction", "stribeck_friction"], None, data, signals=signals, uncertainty=False)
    values = result.values["stribeck_friction"]
    assert per_joint(values["stribeck_peak"]) == pytest.approx(PEAK, rel=0.05)
    assert per_joint(values["stribeck_velocity"]) == pytest.approx(V_ST, rel=0.05)
    assert per_joint(result.values["coulomb_friction"]["friction"]) == pytest.approx(FC, rel=0.03)
    assert result.fit_rmse["overall"] <= 1.05 * 0.01
    assert coulomb.fit_rmse["overall"] >= 3 * result.fit_rmse["overall"]


def test_log_scale_of_nonlinear_parameters_is_declared_per_effect(motion):
    _, signals = friction_data(motion, gaz)
    for effect in EFFECTS.values():
        mask = effect.nonlinear_log_scale(signals)
        assert mask.dtype == bool and mask.shape == effect.nonlinear_init(signals).shape
        assert np.all(effect.nonlinear_bounds(signals)[0][mask] > 0)  # a logarithm needs positive bounds
    n = len(JOINTS)
    assert EFFECTS["coulomb_friction"].nonlinear_log_scale(signals).all()
    assert EFFECTS["stribeck_friction"].nonlinear_log_scale(signals).all()
    # asymmetric_friction: the slopes in log scale, the offsets (either sign) not
    assert list(EFFECTS["asymmetric_friction"].nonlinear_log_scale(signals)) == [True] * n + [False] * n
    assert not EFFECTS["actuation_delay"].nonlinear_log_scale(signals).any()


FRICTION_PARAMS = {
    "effects": {
        # Listed before the Coulomb friction on purpose: the symmetric part adds to it whatever the order.
        "asymmetric_friction": {"amplitude": {j: 0.4 for j in JOINTS}, "slope": {j: 10.0 for j in JOINTS},
                                "velocity_offset": {j: 0.03 for j in JOINTS}},
        "stribeck_friction": {"stribeck_peak": {j: 0.3 for j in JOINTS},
                              "stribeck_velocity": {j: 0.05 for j in JOINTS}},
        "coulomb_friction": {"friction": {j: 0.7 for j in JOINTS}, "smoothing_velocity": {j: 0.01 for j in JOINTS}},
    },
}


def test_friction_effects_write_what_mujoco_and_urdf_can_hold(dev_mjcf):
    dof = lambda model: model.joint("panda_joint4").dofadr[0]  # noqa: E731
    # Default (the calibrated MJCF, from a URDF with the Coulomb friction): phi1 / 2 adds to what is there.
    spec = dev_mjcf.copy()
    spec.joint("panda_joint4").frictionloss = 0.7  # as the calibrated URDF carries it
    apply_to_spec(spec, FRICTION_PARAMS)
    assert spec.compile().dof_frictionloss[dof(spec.compile())] == pytest.approx(0.7 + 0.2)
    # A nominal MJCF calibrated completely: Coulomb's total, then the symmetric part of the sigmoid on top.
    spec = dev_mjcf.copy()
    apply_to_spec(spec, FRICTION_PARAMS, include_urdf_effects=True)
    model = spec.compile()
    assert model.dof_frictionloss[dof(model)] == pytest.approx(0.7 + 0.2)
    # Stribeck friction has no MuJoCo equivalent: it writes nothing at all.
    spec = dev_mjcf.copy()
    before = spec.compile()
    get_effect("stribeck_friction").apply_to_spec(spec, FRICTION_PARAMS["effects"]["stribeck_friction"], {})
    after = spec.compile()
    for field in ("dof_frictionloss", "dof_damping", "dof_armature"):
        assert np.array_equal(getattr(before, field), getattr(after, field))
    # URDF holds neither: the calibration is the Coulomb friction's alone.
    assert not get_effect("asymmetric_friction").in_urdf and not get_effect("stribeck_friction").in_urdf
    only_coulomb = {"effects": {"coulomb_friction": FRICTION_PARAMS["effects"]["coulomb_friction"]}}
    assert calibration_from_params(FRICTION_PARAMS) == calibration_from_params(only_coulomb)


def test_a_sensor_delay_is_read_through_delayed_joint_torque_sensors(dev_mjcf):
    """The calibrated MJCF of a model with sensor_delay: every actuated joint's torque read by a jointactuatorfrc sensor
    MuJoCo delays by the identified lag; the motion is the same as without it."""
    spec = dev_mjcf.copy()
    apply_to_spec(spec, {"torque_source": "tau", "joints": JOINTS[1:], "effects": {"sensor_delay": {"delay": 0.004}}})
    model = spec.compile()
    assert model.nsensor == len(JOINTS) - 1  # the identified joints' (a gripper's, not identified, has none)
    sensor = model.sensor("panda_joint2_torque")
    assert model.sensor_type[sensor.id] == mujoco.mjtSensor.mjSENS_JOINTACTFRC
    data = mujoco.MjData(model)
    steps = int(round(0.004 / model.opt.timestep))
    applied, read = [], []
    for k in range(steps + 6):
        data.ctrl[:] = 0.5 * k
        mujoco.mj_step(model, data)
        applied.append(data.actuator_force.copy())
        read.append(data.sensordata.copy())
    joint = model.actuator("motor_panda_joint2").id
    assert np.allclose(np.array(read)[steps:, sensor.id], np.array(applied)[: len(applied) - steps, joint])
    plain = dev_mjcf.copy().compile()
    assert plain.nsensor == 0 and np.allclose(plain.body_mass, model.body_mass)


def test_an_actuation_lag_is_an_exact_first_order_filter_of_the_actuators(dev_mjcf):
    """The calibrated MJCF of a model with actuation_lag: each actuator filters its control (MuJoCo's filterexact,
    actearly) as the lab's drive does (sim2real.filters.first_order_lag, a command held over each step)."""
    from sim2real.filters import first_order_lag

    spec = dev_mjcf.copy()
    key = spec.add_key()
    key.name, key.ctrl = "home", [0.1 * (k + 1) for k in range(len(spec.actuators))]
    apply_to_spec(spec, {"torque_source": "tau", "joints": JOINTS[1:],
                         "effects": {"actuation_lag": {"time_constant": 0.004}}})
    model = spec.compile()
    joint = model.actuator("motor_panda_joint2").id
    assert model.actuator_dyntype[joint] == mujoco.mjtDyn.mjDYN_FILTEREXACT
    # the identified joints' actuators only, each keyframe's filter settled at its control
    assert model.actuator_dyntype[model.actuator("motor_panda_joint1").id] == mujoco.mjtDyn.mjDYN_NONE
    assert model.key_act[0][model.actuator_actadr[joint]] == pytest.approx(model.key_ctrl[0][joint])
    assert model.actuator_dynprm[joint, 0] == pytest.approx(0.004)
    data = mujoco.MjData(model)
    commands = np.r_[np.zeros(3), np.linspace(0.0, 2.0, 12), np.full(10, 2.0)]
    applied = []
    for command in commands:
        data.ctrl[joint] = command
        mujoco.mj_step(model, data)
        applied.append(data.actuator_force[joint])
    assert np.allclose(applied, first_order_lag(commands, model.opt.timestep, 0.004), atol=1e-12)
    assert np.allclose(dev_mjcf.copy().compile().body_mass, model.body_mass)  # the arm itself unchanged


def test_a_sensor_lag_and_a_sensor_delay_add_up_on_the_torque_sensors(dev_mjcf):
    """MuJoCo's sensors have a delay and no filter: a sensor_lag is read through the same delayed sensors, its time
    constant the delay (the same lag at a motion's frequencies), added to a sensor_delay's."""
    spec = dev_mjcf.copy()
    apply_to_spec(spec, {"torque_source": "tau", "effects": {"sensor_delay": {"delay": 0.002},
                                                             "sensor_lag": {"time_constant": 0.003}}})
    model = spec.compile()
    sensor = model.sensor("panda_joint2_torque").id
    assert model.sensor_delay[sensor] == pytest.approx(0.005)
    assert model.sensor_history[sensor, 0] >= int(round(0.005 / model.opt.timestep)) + 1



@given(columns=st.integers(1, 6), seed=st.integers(0, 2**16), bounded=st.lists(st.booleans(), min_size=6, max_size=6))
@settings(max_examples=60, deadline=None)
def test_coefficients_held_at_their_bounds_and_the_rest_solved_again(columns, seed, bounded):
    """Whatever the design: every coefficient at or above its bound; one the free solve leaves above its bound is
    untouched; the free ones solve the normal equations with the held ones at their bounds."""
    from sim2real.identification.fitting.linear import _held_at_bounds

    rng = np.random.default_rng(seed)
    design = rng.normal(size=(40, columns))
    target = rng.normal(size=40)
    gram, rhs = design.T @ design, design.T @ target
    free_solution = np.linalg.lstsq(gram, rhs, rcond=None)[0]
    lower = np.where(bounded[:columns], rng.normal(scale=0.5, size=columns), -np.inf)
    coef = _held_at_bounds(gram, rhs, free_solution, lower)
    assert np.all(coef >= lower)
    held = coef == lower
    if not np.any(free_solution < lower):
        assert np.array_equal(coef, free_solution)
    free = ~held
    assert np.allclose(gram[free] @ coef, rhs[free], atol=1e-8)
