"""base_mount: gravity's direction in the base frame, named blind on a tilted lab arm, recovered to a tenth of a
degree, and carried by the calibrated URDF, MJCF and USD."""

from __future__ import annotations

import re
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from sim2real.assets.dynamics import RigidBodyModel
from sim2real.assets.meshes import BuiltMeshes
from sim2real.assets.mjcf import build_mjcf
from sim2real.assets.urdf import build_urdf, mesh_uris, resolve_package_uri
from sim2real.identification.effects import calibration_from_params, get_effect
from sim2real.identification.effects.base import Signals
from sim2real.identification.effects.base_mount import gravity_direction, mount_angles, visible_angles

REPO = Path(__file__).resolve().parents[1]
JOINTS = [f"panda_joint{i}" for i in range(1, 8)]
TILT_DEG = (1.5, -1.0)  # configs/panda/lab.yaml, scenarios base_mount and real_arm_like_mount


def truth_x_floor(lab, scenario: str, tilt_deg: tuple[float, float]) -> np.ndarray:
    """Each joint's holdout RMSE against the true arm's model (the nominal URDF under the tilted gravity), in units
    of its own floor: the level a model that knows the mount and nothing else can reach."""
    _, holdout = lab.data(scenario)
    dynamics = lab.nominal.dynamics
    gravity = 9.81 * gravity_direction(*np.radians(tilt_deg))
    tilted = dynamics.inverse_dynamics(holdout.q, holdout.qd, holdout.qdd) + dynamics.unit_gravity(holdout.q) @ (
        gravity - np.array([0.0, 0.0, -9.81]))
    residual = holdout.tau - tilted
    return np.sqrt(np.mean(residual**2, axis=0)) / np.asarray(holdout.noise_floor)


def test_unit_gravity_columns_are_pinocchios_gravity_and_the_angles_invert(shared_lab):
    dynamics = shared_lab.nominal.dynamics
    q = np.random.default_rng(3).uniform(dynamics.lower, dynamics.upper, size=(20, len(JOINTS)))
    np.testing.assert_allclose(dynamics.unit_gravity(q) @ np.array([0.0, 0.0, -9.81]), dynamics.gravity(q), atol=1e-9)
    a, b = np.radians(TILT_DEG)
    assert mount_angles(gravity_direction(a, b)) == pytest.approx((a, b), abs=1e-12)


def test_a_tilt_the_data_cannot_see_is_not_identified():
    """A planar arm whose every axis is parallel to y: gravity along y never loads a joint, so the tilt about x
    (which turns gravity towards y) is not fitted and is reported as not identified; the tilt about y is."""
    rng = np.random.default_rng(0)
    planar = np.zeros((200, 3, 3))
    planar[:, :, 0] = rng.normal(size=(200, 3))
    planar[:, :, 2] = rng.normal(size=(200, 3))
    assert visible_angles(planar).tolist() == [False, True]
    signals = Signals(joint_names=["j1", "j2", "j3"], time=np.arange(200.0), q=np.zeros((200, 3)),
                      qd=np.zeros((200, 3)), qdd=np.zeros((200, 3)), tau_nominal=np.zeros((200, 3)),
                      segments=[slice(0, 200)], gravity_fn=lambda: planar)
    effect = get_effect("base_mount")
    state = effect.prepare(signals)
    columns, labels = effect.columns(signals, state, np.array([]))
    assert [label.param for label in labels] == ["tilt_y"] and columns.shape == (200, 3, 1)
    values = effect.values(np.array([0.01]), np.array([]), signals, state)
    assert values["identified"] == {"tilt_x": False, "tilt_y": True}
    assert values["tilt_x"] == 0.0 and values["tilt_y"] == pytest.approx(0.01)
    # a still arm shows nothing at all
    assert visible_angles(np.zeros((50, 3, 3))).tolist() == [False, False]


def test_a_tilted_base_is_named_base_mount_first_and_one_rung_reaches_the_truth(shared_lab):
    """base_mount: the base off level by 1.5 and -1 degrees, nothing else wrong. Blind, the nominal model's
    diagnosis names base_mount first; with it every joint sits at the true model's level and the angles are
    recovered within a tenth of a degree."""
    nominal = shared_lab.ladder("base_mount", [])
    assert nominal["diagnosis"]["status"] == "add_effect", nominal["diagnosis"]["verdict"]
    assert nominal["diagnosis"]["candidates"][0]["effect"] == "base_mount", nominal["diagnosis"]["candidates"][:3]
    # the model-free ceiling reads the same: a function of the pose, a gravity turned sideways, no drift to declare
    ceiling = nominal["diagnosis"]["model_free"]
    above = [j for j, row in ceiling["per_joint"].items() if row["kind"] != "at_floor"]
    assert above and all(ceiling["per_joint"][j]["kind"] == "motion" for j in above), ceiling["per_joint"]
    assert ceiling["points_to"]["effect"] == "base_mount" and "declare" not in ceiling, ceiling.get("points_to")
    assert "A function of the pose alone explains much of what is left" in ceiling["text"]
    assert "a base mounted off level: add the line '- base_mount'" in ceiling["text"]
    rung = shared_lab.ladder("base_mount", ["base_mount"], diagnose=False)["ladder"][-1]
    values = rung["params"]["base_mount"]
    assert values["identified"] == {"tilt_x": True, "tilt_y": True}
    assert values["tilt_x_deg"] == pytest.approx(TILT_DEG[0], abs=0.1)
    assert values["tilt_y_deg"] == pytest.approx(TILT_DEG[1], abs=0.1)
    x_floor = rung["metrics"]["torque_x_floor"]["per_joint"]
    truth = truth_x_floor(shared_lab, "base_mount", TILT_DEG)
    for joint, level in zip(JOINTS, truth, strict=True):
        assert x_floor[joint] <= 1.05 * level + 0.05, (joint, x_floor[joint], level)


def _calibrated_urdf(tmp_path: Path, tilt: tuple[float, float]) -> Path:
    """The Panda's calibrated URDF (its Xacro with a calibration holding only the mount), visuals left out."""
    params = {"effects": {"base_mount": {"tilt_x": tilt[0], "tilt_y": tilt[1]}}}
    calibration = tmp_path / "calibration.yaml"
    calibration.write_text(yaml.safe_dump(calibration_from_params(params)), encoding="utf-8")
    urdf = tmp_path / "panda.urdf"
    build_urdf(REPO / "robots" / "panda" / "panda.urdf.xacro", urdf, {"hand": "true", "calibration": calibration})
    text = re.sub(r"<visual>.*?</visual>", "", urdf.read_text(encoding="utf-8"), flags=re.S)
    urdf.write_text(text, encoding="utf-8")
    return urdf


def test_the_calibrated_urdf_mjcf_and_usd_of_a_tilted_arm_carry_its_gravity(tmp_path):
    """The calibrated URDF (a fixed world -> base joint), the MJCF built from it (the base body turned, the world's
    gravity and floor level) and the USD (the base's orientation) give the tilted arm's gravity torques: Pinocchio
    on the nominal URDF under the tilted gravity vector, at random poses (the USD at its authored pose)."""
    tilt = tuple(float(v) for v in np.radians(TILT_DEG))
    urdf = _calibrated_urdf(tmp_path, tilt)
    nominal_urdf = tmp_path / "nominal" / "panda.urdf"
    nominal_urdf.parent.mkdir()
    build_urdf(REPO / "robots" / "panda" / "panda.urdf.xacro", nominal_urdf, {"hand": "true"})
    nominal = RigidBodyModel(nominal_urdf, JOINTS)
    rng = np.random.default_rng(7)
    q = rng.uniform(nominal.lower, nominal.upper, size=(10, len(JOINTS)))
    expected = nominal.unit_gravity(q) @ (9.81 * gravity_direction(*tilt))
    assert np.abs(expected - nominal.gravity(q)).max() > 0.1, "the tilt moves the gravity torque"
    np.testing.assert_allclose(RigidBodyModel(urdf, JOINTS).gravity(q), expected, atol=1e-9)

    collision = {uri: [resolve_package_uri(uri, source=urdf)] for uri in mesh_uris(urdf).get("collision", [])}
    out = tmp_path / "mjcf"
    build_mjcf(urdf, REPO / "configs" / "panda" / "robot.yaml", BuiltMeshes.of({}, collision), out / "panda.xml",
               out / "scene.xml")
    model = mujoco.MjModel.from_xml_path(str(out / "scene.xml"))
    np.testing.assert_allclose(model.opt.gravity, [0.0, 0.0, -9.81])  # the world, and its floor, stay level
    # a random pose may touch a joint's limit: the limits' constraint forces are no part of gravity's torque
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    data = mujoco.MjData(model)
    qadr = [model.jnt_qposadr[model.joint(j).id] for j in JOINTS]
    dadr = [model.jnt_dofadr[model.joint(j).id] for j in JOINTS]
    for pose, torque in zip(q, expected, strict=True):
        data.qpos[:] = 0.0
        data.qpos[qadr] = pose
        data.qvel[:] = data.qacc[:] = 0.0
        mujoco.mj_inverse(model, data)
        # the MJCF is written with MuJoCo's own precision: within 1e-4 N*m, a tilt's torque is tenths of N*m
        np.testing.assert_allclose(data.qfrc_inverse[dadr], torque, rtol=1e-5, atol=1e-4)

    _check_usd(urdf, collision, tmp_path / "usd", nominal, tilt)


def _check_usd(urdf: Path, collision: dict, out: Path, nominal: RigidBodyModel, tilt: tuple[float, float]) -> None:
    """The USD's base prim is turned by the mount, and its bodies' masses at their world poses give the tilted arm's
    gravity torque at the authored pose (every joint at zero)."""
    pxr = pytest.importorskip("pxr")
    from pxr import Gf, Usd, UsdGeom, UsdPhysics

    from sim2real.assets.usd import build_usd

    out.mkdir()
    build_usd(urdf, REPO / "configs" / "panda" / "robot.yaml", BuiltMeshes.of({}, collision), out / "panda.usda",
              out / "panda_geometry.usda")
    stage = Usd.Stage.Open(str(out / "panda.usda"))
    cache = UsdGeom.XformCache()
    bodies = {p.GetName(): p for p in stage.Traverse() if p.HasAPI(UsdPhysics.RigidBodyAPI)}
    world = {name: np.array(cache.GetLocalToWorldTransform(prim)).T for name, prim in bodies.items()}  # column form
    turn = world["panda_link0"][:3, :3]
    a, b = tilt
    expected_turn = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]]) @ np.array(
        [[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    np.testing.assert_allclose(turn, expected_turn, atol=1e-9)
    # gravity torque at zero: per joint, minus the moment about its axis of every body's weight beyond it
    joints = {p.GetName(): UsdPhysics.RevoluteJoint(p) for p in stage.Traverse() if p.IsA(UsdPhysics.RevoluteJoint)}
    order = {name: k for k, name in enumerate(bodies)}
    torque = []
    for name in JOINTS:
        joint = joints[name]
        child = joint.GetBody1Rel().GetTargets()[0].name
        frame = world[child] @ _local(joint.GetLocalPos1Attr().Get(), joint.GetLocalRot1Attr().Get(), Gf)
        axis = frame[:3, :3] @ np.eye(3)["XYZ".index(joint.GetAxisAttr().Get())]
        total = 0.0
        for body, prim in bodies.items():
            if order[body] < order[child]:
                continue
            mass_api = UsdPhysics.MassAPI(prim)
            com = world[body] @ np.append(np.asarray(mass_api.GetCenterOfMassAttr().Get(), dtype=float), 1.0)
            weight = mass_api.GetMassAttr().Get() * np.array([0.0, 0.0, -9.81])
            total -= float(axis @ np.cross(com[:3] - frame[:3, 3], weight))
        torque.append(total)
    expected = nominal.unit_gravity(np.zeros((1, len(JOINTS))))[0] @ (9.81 * gravity_direction(*tilt))
    np.testing.assert_allclose(torque, expected, atol=1e-6)


def _local(position, rotation, Gf) -> np.ndarray:
    """A joint's local frame (position, quaternion) as a 4x4 matrix in column form."""
    return np.array(Gf.Matrix4d().SetTransform(Gf.Rotation(Gf.Quatd(rotation)), Gf.Vec3d(position))).T


def test_domain_randomization_turns_the_base_around_the_identified_mount_and_covers_it(tmp_path):
    """dr.yaml's base_tilt randomizes the calibrated MJCF's root body around the identified mount (the world's
    gravity stays level), and the coverage check finds the identified angles, with their intervals, inside it."""
    from gap_fixtures import build_dev_panda
    from sim2real import dr
    from sim2real.assets.mount import turn_base_body
    from sim2real.dr.coverage import check_coverage, read_identified
    from sim2real.dr.parameters import base_tilt, root_body

    urdf, _ = build_dev_panda(tmp_path)
    spec = mujoco.MjSpec.from_file(str(urdf))
    spec.compiler.fusestatic = False  # as the MJCF builder keeps every URDF link: the base is a body of its own
    tilt = np.radians(TILT_DEG)
    turn_base_body(spec, *tilt)  # as the calibrated MJCF carries the mount
    base = spec.compile()
    config = {"physics_randomization": {"base_tilt": {"mode": "reset", "distribution": "uniform", "operation": "add",
                                                       "range": [-0.005, 0.005]}},
              "curriculum": {"levels": [{"name": "full", "scale": 1.0}], "default_level": "full"}}
    resolved = dr.resolve_config(config, base, config_path="dr.yaml")
    target = resolved["physics"][0]["targets"][0]
    assert target["name"] == "panda_link0" and target["nominal"] == pytest.approx(tilt, abs=1e-9)
    identified = read_identified({"effects": {"base_mount": {"tilt_x": float(tilt[0]), "tilt_y": float(tilt[1])}},
                                  "intervals": {"base_mount": {"tilt_x": [tilt[0] - 1e-3, tilt[0] + 1e-3],
                                                               "tilt_y": [tilt[1] - 1e-3, tilt[1] + 1e-3]}}})
    records = check_coverage(resolved, identified)
    assert len(records) == 2 and all(r["covered"] for r in records), records
    narrow = {**config, "physics_randomization": {"base_tilt": {**config["physics_randomization"]["base_tilt"],
                                                                "range": [-5e-4, 5e-4]}}}
    assert not any(r["covered"] for r in check_coverage(dr.resolve_config(narrow, base, config_path="dr.yaml"),
                                                        identified))
    randomizer = dr.DomainRandomizer(resolved, base, seed=3)
    drawn = []
    for _ in range(5):
        model = randomizer.reset()
        np.testing.assert_allclose(model.opt.gravity, [0.0, 0.0, -9.81])
        drawn.append(base_tilt(model.body_quat[root_body(model)]) - tilt)
    drawn = np.array(drawn)
    assert np.all(np.abs(drawn) <= 0.005 + 1e-12) and np.ptp(drawn, axis=0).min() > 1e-4, drawn
