"""Xacro -> URDF: variants, calibration injection, package:// resolution and validation errors."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import pinocchio as pin
import pytest
import yaml

from sim2real.errors import InputError
from sim2real.assets.urdf import build_urdf, mesh_names, resolve_package_uri, validate_urdf

PANDA_ARM = [f"panda_joint{i}" for i in range(1, 8)]
UR5_JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]


@pytest.fixture()
def robots_copy(tmp_path: Path, repo_root: Path) -> Path:
    """A writable copy of robots/ (the Xacro files include ../common)."""
    return Path(shutil.copytree(repo_root / "robots", tmp_path / "robots"))


def joint_names(urdf: Path) -> list[str]:
    model = pin.buildModelFromUrdf(str(urdf))
    return [model.names[i] for i in range(1, model.njoints)]


def test_panda_with_and_without_hand(tmp_path: Path, repo_root: Path) -> None:
    xacro = repo_root / "robots/panda/panda.urdf.xacro"
    build_urdf(xacro, tmp_path / "hand.urdf", {})
    build_urdf(xacro, tmp_path / "nohand.urdf", {"hand": False})
    assert joint_names(tmp_path / "hand.urdf") == [*PANDA_ARM, "panda_finger_joint1", "panda_finger_joint2"]
    assert joint_names(tmp_path / "nohand.urdf") == PANDA_ARM
    root = ET.parse(tmp_path / "hand.urdf").getroot()
    mimic = root.find("joint[@name='panda_finger_joint2']/mimic")
    assert mimic is not None and mimic.get("joint") == "panda_finger_joint1"


def test_ur5_builds_with_its_joint_order(tmp_path: Path, repo_root: Path) -> None:
    build_urdf(repo_root / "robots/ur5/ur5.urdf.xacro", tmp_path / "ur5.urdf", {})
    assert joint_names(tmp_path / "ur5.urdf") == UR5_JOINTS


def test_output_is_deterministic_and_keeps_package_uris(tmp_path: Path, repo_root: Path) -> None:
    xacro = repo_root / "robots/panda/panda.urdf.xacro"
    build_urdf(xacro, tmp_path / "a.urdf", {})
    build_urdf(xacro, tmp_path / "b.urdf", {})
    text = (tmp_path / "a.urdf").read_text()
    assert text == (tmp_path / "b.urdf").read_text()
    assert str(repo_root) not in text and str(tmp_path) not in text
    names = mesh_names(tmp_path / "a.urdf")
    assert set(names["visual"]) == {"link0", "link1", "link2", "link3", "link4", "link5", "link6", "link7", "hand", "finger"}
    assert all(uri.startswith("package://example-robot-data/") for uri in names["collision"].values())


def test_calibration_yaml_overrides_dynamics_inertials_and_adds_payload(tmp_path: Path, repo_root: Path) -> None:
    calibration = tmp_path / "calibration.yaml"
    calibration.write_text(yaml.safe_dump({
        "joints": {"panda_joint2": {"damping": 0.25, "friction": 0.6}},
        "links": {"panda_link7": {"mass": 0.9, "com": [0.01, 0.0, 0.07]}},
        "payload": {"mass": 0.5, "com": [0.0, 0.0, 0.05], "inertia": {"ixx": 1e-3, "iyy": 1e-3, "izz": 1e-3}},
    }))
    build_urdf(repo_root / "robots/panda/panda.urdf.xacro", tmp_path / "cal.urdf", {"calibration": calibration})
    root = ET.parse(tmp_path / "cal.urdf").getroot()
    dynamics = root.find("joint[@name='panda_joint2']/dynamics")
    assert (float(dynamics.get("damping")), float(dynamics.get("friction"))) == (0.25, 0.6)
    assert float(root.find("joint[@name='panda_joint1']/dynamics").get("damping")) == 0.003  # nominal kept
    link7 = root.find("link[@name='panda_link7']/inertial")
    assert float(link7.find("mass").get("value")) == 0.9
    assert [float(v) for v in link7.find("origin").get("xyz").split()] == [0.01, 0.0, 0.07]
    assert float(link7.find("inertia").get("ixx")) == 0.012516  # not overridden
    assert root.find("joint[@name='payload_joint']/parent").get("link") == "panda_link8"
    model = pin.buildModelFromUrdf(str(tmp_path / "cal.urdf"))
    # joint 7 carries link 7, the payload and the hand (fixed links are merged by Pinocchio)
    assert model.inertias[model.getJointId("panda_joint7")].mass == pytest.approx(0.9 + 0.5 + 0.73)


def test_package_uri_resolution(tmp_path: Path, repo_root: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    erd = resolve_package_uri("package://example-robot-data/robots/panda_description/meshes/visual/link0.dae")
    assert erd.is_file()
    assert resolve_package_uri("package://panda/panda.urdf.xacro") == repo_root / "robots/panda/panda.urdf.xacro"
    (tmp_path / "my_pkg").mkdir()
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path))
    assert resolve_package_uri("package://my_pkg/a.stl") == tmp_path / "my_pkg/a.stl"
    with pytest.raises(InputError, match="unknown package 'nope'"):
        resolve_package_uri("package://nope/a.stl", source="x.urdf", where="link 'l'")


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, f"test setup: '{old}' not in {path}"
    path.write_text(text.replace(old, new, 1))


BAD_INPUTS = {
    "missing mesh": (
        "panda/panda.urdf.xacro", '${mesh_root}/visual/hand.dae', '${mesh_root}/visual/hand_missing.dae',
        ["link 'panda_hand' <visual> mesh", "hand_missing.dae", "does not exist"],
    ),
    "broken xacro expression": (
        "panda/panda.urdf.xacro", 'rpy="${-pi/2} 0 0"', 'rpy="${-pi/} 0 0"',
        ["panda.urdf.xacro", "Xacro cannot expand", "-pi/"],
    ),
    "non-physical inertia": (
        "panda/panda.urdf.xacro", 'ixx="0.012516"', 'ixx="0.05"',
        ["link 'panda_link7' <inertial>", "triangle inequality"],
    ),
    "negative inertia": (
        "ur5/ur5.urdf.xacro", 'ixx="0.010267495893"', 'ixx="-0.010267495893"',
        ["link 'shoulder_link' <inertial>", "not positive definite"],
    ),
    "actuated joint without limits": (
        "panda/panda.urdf.xacro",
        '<limit lower="0.0" upper="0.04" effort="100" velocity="0.2"/>\n      <xacro:calibrated_dynamics joint="panda_finger_joint1"',
        '<xacro:calibrated_dynamics joint="panda_finger_joint1"',
        ["joint 'panda_finger_joint1' (prismatic)", "has no <limit>"],
    ),
    # found by tests/test_fuzz_inputs.py (issue 21): a ValueError, or accepted
    "non-numeric mass": (
        "ur5/ur5.urdf.xacro", 'name="base_link" mesh="base" mass="4.0"', 'name="base_link" mesh="base" mass="4 kg"',
        ["link 'base_link' <inertial> <mass> value", "'4 kg' is not a number"],
    ),
    "infinite effort": (
        "panda/panda.urdf.xacro", 'effort="100" velocity="0.2"/>', 'effort="inf" velocity="0.2"/>',
        ["joint 'panda_finger_joint1' (prismatic)", "effort is inf"],
    ),
    "zero velocity limit": (
        "panda/panda.urdf.xacro", 'effort="100" velocity="0.2"/>', 'effort="100" velocity="0"/>',
        ["joint 'panda_finger_joint1' (prismatic)", "velocity is 0.0"],
    ),
    "infinite range": (
        "panda/panda.urdf.xacro", '<limit lower="0.0" upper="0.04"', '<limit lower="0.0" upper="1e400"',
        ["joint 'panda_finger_joint1' (prismatic)", "upper=inf is not a range"],
    ),
    "unknown package": (
        "ur5/ur5.urdf.xacro", "package://example-robot-data/robots/ur_description", "package://ur_nowhere/robots/ur_description",
        ["ur5.urdf.xacro", "<visual> mesh", "unknown package 'ur_nowhere'", "ROS_PACKAGE_PATH"],
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_input_names_file_and_element_and_writes_nothing(case: str, robots_copy: Path, tmp_path: Path) -> None:
    relative, old, new, expected = BAD_INPUTS[case]
    xacro = robots_copy / relative
    _edit(xacro, old, new)
    out = tmp_path / "out" / "robot.urdf"
    with pytest.raises(InputError) as error:
        build_urdf(xacro, out, {})
    message = str(error.value)
    for fragment in expected:
        assert fragment in message, message
    assert "Fix:" in message
    assert not out.exists()
    assert list(out.parent.iterdir()) == [] if out.parent.exists() else True


def test_failed_rebuild_keeps_previous_output(robots_copy: Path, tmp_path: Path) -> None:
    xacro = robots_copy / "ur5/ur5.urdf.xacro"
    out = tmp_path / "ur5.urdf"
    build_urdf(xacro, out, {})
    before = out.read_bytes()
    _edit(xacro, 'effort="28.0"', 'effort="0"')
    with pytest.raises(InputError, match="effort"):
        build_urdf(xacro, out, {})
    assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["robots", "ur5.urdf"]


def test_validate_names_the_urdf_itself_by_default(tmp_path: Path, repo_root: Path) -> None:
    urdf = tmp_path / "r.urdf"
    build_urdf(repo_root / "robots/ur5/ur5.urdf.xacro", urdf, {})
    _edit(urdf, 'type="revolute"', 'type="continuous"')
    validate_urdf(urdf)  # continuous joints need effort only
    _edit(urdf, 'mass value="3.7"', 'mass value="-3.7"')
    with pytest.raises(InputError, match=r"r\.urdf: link 'shoulder_link' <inertial>: mass"):
        validate_urdf(urdf)
