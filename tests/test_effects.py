"""Effect library: one shape for all, MJCF edits via MjSpec, calibration YAML the Xacro consumes."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest
import yaml

from gap_fixtures import build_dev_panda
from sim2real.effects import EFFECTS, apply_to_spec, calibration_from_params, get_effect, spec_edit_from_params
from sim2real.errors import InputError

VOCABULARY = {"viscous_friction", "coulomb_friction", "rotor_inertia", "actuation_delay", "payload",
              "link_inertia", "torque_bias", "torque_gain"}
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
    from sim2real.urdf import build_urdf

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
