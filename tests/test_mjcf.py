"""URDF -> MJCF: the menagerie gate and equality with the URDF, for every robot."""

from __future__ import annotations

import fnmatch
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from sim2real.errors import InputError
from sim2real.assets.meshes import BuiltMeshes, convert_collision_mesh, convert_visual_mesh
from sim2real.assets.mjcf import build_mjcf
from sim2real.assets.urdf import build_urdf, mesh_names, resolve_package_uri

ROBOTS = ["panda", "ur5", "iiwa14"]
MJCF_RTOL = 1e-5  # MuJoCo's XML writer keeps 6 significant digits
EXPECTED_ACTUATORS = {
    "panda": [*(f"panda_joint{i}" for i in range(1, 8)), "panda_finger_joint1"],
    "ur5": ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"],
    "iiwa14": [f"iiwa_joint_{i}" for i in range(1, 8)],
}
PRIMITIVES = {mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_SPHERE}


class Built:
    """One robot built into a tmp tree with the layout of results/{robot}/."""

    def __init__(self, root: Path, repo_root: Path, robot: str) -> None:
        self.robot = robot
        self.dir = root / robot
        self.config = repo_root / "configs" / robot / "robot.yaml"
        settings = yaml.safe_load(self.config.read_text())
        self.urdf = self.dir / f"{robot}.urdf"
        build_urdf(repo_root / settings["xacro"], self.urdf, settings.get("xacro_args") or {})
        names = mesh_names(self.urdf)
        self.visual_dirs = []
        for name, uri in names["visual"].items():
            out = self.dir / "meshes" / "visual" / name
            convert_visual_mesh(resolve_package_uri(uri), out, uri)
            self.visual_dirs.append(out)
        self.collision: dict[str, list[Path]] = {}
        for name, uri in names["collision"].items():
            out = self.dir / "meshes" / "collision" / f"{name}.stl"
            convert_collision_mesh(resolve_package_uri(uri), out, uri)
            self.collision[uri] = [out]
        self.xml = self.dir / "mjcf" / f"{robot}.xml"
        self.scene = self.dir / "mjcf" / "scene.xml"
        build_mjcf(self.urdf, self.config, BuiltMeshes.of(self.visual_dirs, self.collision), self.xml, self.scene)
        self.model = mujoco.MjModel.from_xml_path(str(self.scene))
        self.urdf_root = ET.parse(self.urdf).getroot()


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory, repo_root: Path) -> dict[str, Built]:
    root = tmp_path_factory.mktemp("assets")
    return {robot: Built(root, repo_root, robot) for robot in ROBOTS}


@pytest.mark.parametrize("robot", ROBOTS)
def test_menagerie_gate_one_second_from_home_with_noisy_controls(built: dict[str, Built], robot: str) -> None:
    model = built[robot].model
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    rng = np.random.default_rng(0)
    low, high = model.actuator_ctrlrange.T
    home_ctrl = model.key("home").ctrl.copy()
    for _ in range(int(round(1.0 / model.opt.timestep))):
        data.ctrl[:] = np.clip(home_ctrl + rng.normal(0.0, 0.05 * (high - low)), low, high)
        mujoco.mj_step(model, data)
    assert np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))
    warnings = {mujoco.mjtWarning(i).name: data.warning[i].number for i in range(mujoco.mjtWarning.mjNWARNING)}
    assert not any(warnings.values()), warnings
    assert data.time == pytest.approx(1.0)


def _urdf_joints(b: Built) -> list[ET.Element]:
    return [j for j in b.urdf_root.findall("joint") if j.get("type") != "fixed"]


@pytest.mark.parametrize("robot", ROBOTS)
def test_joint_order_limits_and_dynamics_equal_the_urdf(built: dict[str, Built], robot: str) -> None:
    b = built[robot]
    model = b.model
    joints = _urdf_joints(b)
    assert [model.joint(i).name for i in range(model.njnt)] == [j.get("name") for j in joints]
    armature = yaml.safe_load(b.config.read_text())["armature"]
    for joint in joints:
        mj = model.joint(joint.get("name"))
        limit = joint.find("limit")
        np.testing.assert_allclose(mj.range, [float(limit.get("lower")), float(limit.get("upper"))], rtol=MJCF_RTOL)
        assert model.jnt_limited[mj.id]
        np.testing.assert_allclose(model.jnt_actfrcrange[mj.id], [-float(limit.get("effort")), float(limit.get("effort"))])
        dof = model.jnt_dofadr[mj.id]
        dynamics = joint.find("dynamics")
        assert model.dof_damping[dof] == pytest.approx(float(dynamics.get("damping")))
        assert model.dof_frictionloss[dof] == pytest.approx(float(dynamics.get("friction")))
        expected_armature = next((v for k, v in armature.items() if fnmatch.fnmatchcase(joint.get("name"), k)), 0.0)
        assert model.dof_armature[dof] == pytest.approx(expected_armature)


@pytest.mark.parametrize("robot", ROBOTS)
def test_masses_and_full_inertias_equal_the_urdf(built: dict[str, Built], robot: str) -> None:
    b = built[robot]
    model = b.model
    for link in b.urdf_root.findall("link"):
        inertial = link.find("inertial")
        body = model.body(link.get("name"))
        if inertial is None:
            assert model.body_mass[body.id] == 0.0
            continue
        assert model.body_mass[body.id] == pytest.approx(float(inertial.find("mass").get("value")), rel=MJCF_RTOL)
        np.testing.assert_allclose(
            model.body_ipos[body.id], [float(v) for v in inertial.find("origin").get("xyz").split()], atol=1e-6
        )
        g = {k: float(v) for k, v in inertial.find("inertia").attrib.items()}
        urdf_tensor = np.array([[g["ixx"], g["ixy"], g["ixz"]], [g["ixy"], g["iyy"], g["iyz"]], [g["ixz"], g["iyz"], g["izz"]]])
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, model.body_iquat[body.id])
        rotation = rotation.reshape(3, 3)
        mj_tensor = rotation @ np.diag(model.body_inertia[body.id]) @ rotation.T
        np.testing.assert_allclose(mj_tensor, urdf_tensor, atol=1e-5 * np.abs(urdf_tensor).max())


@pytest.mark.parametrize("robot", ROBOTS)
def test_actuators_ctrlrange_and_forcerange(built: dict[str, Built], robot: str) -> None:
    b = built[robot]
    model = b.model
    assert [model.actuator(i).name for i in range(model.nu)] == EXPECTED_ACTUATORS[robot]
    limits = {j.get("name"): j.find("limit") for j in _urdf_joints(b)}
    for a in range(model.nu):
        joint = model.joint(model.actuator_trnid[a, 0]).name
        limit = limits[joint]
        # position servos: ctrlrange = joint limits; forcerange = URDF effort
        np.testing.assert_allclose(
            model.actuator_ctrlrange[a], [float(limit.get("lower")), float(limit.get("upper"))], rtol=MJCF_RTOL
        )
        np.testing.assert_allclose(model.actuator_forcerange[a], [-float(limit.get("effort")), float(limit.get("effort"))])
        assert model.actuator_ctrllimited[a] and model.actuator_forcelimited[a]
        assert model.actuator_gainprm[a, 0] > 0 and model.actuator_biasprm[a, 1] == -model.actuator_gainprm[a, 0]


@pytest.mark.parametrize("robot", ROBOTS)
def test_visual_and_collision_classes_and_colors(built: dict[str, Built], robot: str) -> None:
    model = built[robot].model
    robot_geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] != 0]  # floor is in the world body
    visual = [g for g in robot_geoms if model.geom_group[g] == 2]
    collision = [g for g in robot_geoms if model.geom_group[g] == 3]
    assert visual and collision and len(visual) + len(collision) == len(robot_geoms)
    # the iiwa 14 is drawn with primitives: each takes its URDF material's color
    shapes = PRIMITIVES if robot == "iiwa14" else {mujoco.mjtGeom.mjGEOM_MESH}
    for g in visual:
        assert model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0
        assert int(model.geom_type[g]) in {int(s) for s in shapes} and model.geom_matid[g] >= 0
    colors = {tuple(np.round(model.mat_rgba[model.geom_matid[g]], 3)) for g in visual}
    assert len(colors) >= 2  # real per-material colors, not one default
    for g in collision:
        assert model.geom_contype[g] == 1 and model.geom_conaffinity[g] == 1
    shape = "visual/geometry/*" if robot == "iiwa14" else "visual/geometry/mesh"
    bodies_with_visual_mesh = {
        link.get("name") for link in built[robot].urdf_root.findall("link") if link.find(shape) is not None
    }
    assert bodies_with_visual_mesh == {model.body(model.geom_bodyid[g]).name for g in visual}


@pytest.mark.parametrize("robot", ROBOTS)
def test_keyframe_site_and_relative_paths(built: dict[str, Built], robot: str, repo_root: Path) -> None:
    b = built[robot]
    model = b.model
    settings = yaml.safe_load(b.config.read_text())
    home = model.key("home")
    for name, value in settings["home"].items():
        assert home.qpos[model.jnt_qposadr[model.joint(name).id]] == pytest.approx(value)
    site = model.site("attachment_site")
    assert model.body(model.site_bodyid[site.id]).name == settings["flange"]
    text = b.xml.read_text()
    assert str(b.dir) not in text and str(repo_root) not in text and "package://" not in text
    for mesh in ET.parse(b.xml).getroot().iter("mesh"):
        if mesh.get("file"):
            assert mesh.get("file").startswith("../meshes/")
    scene = ET.parse(b.scene).getroot()
    assert scene.find("include").get("file") == f"{robot}.xml"
    assert scene.find("worldbody/geom").get("type") == "plane" and scene.find("worldbody/light") is not None


def test_panda_mimic_finger_is_an_equality(built: dict[str, Built]) -> None:
    model = built["panda"].model
    assert model.neq == 1 and model.eq_type[0] == mujoco.mjtEq.mjEQ_JOINT
    pair = {model.joint(model.eq_obj1id[0]).name, model.joint(model.eq_obj2id[0]).name}
    assert pair == {"panda_finger_joint1", "panda_finger_joint2"}


def test_rebuild_is_byte_identical(built: dict[str, Built]) -> None:
    b = built["ur5"]
    again = b.dir / "mjcf" / "again.xml"
    build_mjcf(b.urdf, b.config, BuiltMeshes.of(b.visual_dirs, b.collision), again, b.dir / "mjcf" / "again_scene.xml")
    assert again.read_text() == b.xml.read_text()


def test_several_collision_parts_and_spec_edit(built: dict[str, Built], tmp_path: Path) -> None:
    """The collision stage passes several convex parts per mesh through the same argument."""
    b = built["ur5"]
    collision = {uri: list(files) for uri, files in b.collision.items()}
    first = sorted(collision)[0]
    collision[first] = [*collision[first], collision[sorted(collision)[1]][0]]

    def heavier_damping(spec: mujoco.MjSpec) -> None:
        spec.joint("elbow_joint").damping = [7.0, 0.0, 0.0]

    out = b.dir / "variant" / "mjcf"
    build_mjcf(b.urdf, b.config, BuiltMeshes.of(b.visual_dirs, collision), out / "ur5.xml", out / "scene.xml", spec_edit=heavier_damping)
    model = mujoco.MjModel.from_xml_path(str(out / "scene.xml"))
    collision_geoms = sum(1 for g in range(model.ngeom) if model.geom_group[g] == 3)
    assert collision_geoms == sum(1 for g in range(b.model.ngeom) if b.model.geom_group[g] == 3) + 1
    assert model.dof_damping[model.jnt_dofadr[model.joint("elbow_joint").id]] == 7.0
    assert 'file="../../meshes/collision/' in (out / "ur5.xml").read_text()  # relative to the MJCF file


def test_bad_robot_config_is_named_and_leaves_no_output(built: dict[str, Built], tmp_path: Path) -> None:
    b = built["ur5"]
    config = yaml.safe_load(b.config.read_text())
    config["actuators"].append({"joints": "gripper_*", "type": "position", "kp": 10})
    bad = tmp_path / "robot.yaml"
    bad.write_text(yaml.safe_dump(config))
    out = tmp_path / "mjcf"
    with pytest.raises(InputError, match=r"robot\.yaml: actuators\[3\]\.joints 'gripper_\*': matches no actuated joint"):
        build_mjcf(b.urdf, bad, BuiltMeshes.of(b.visual_dirs, b.collision), out / "ur5.xml", out / "scene.xml")
    assert not out.exists() or list(out.iterdir()) == []
