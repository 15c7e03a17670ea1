"""The UsdPhysics asset: structure, units, drives, masses, colliders, compliance and determinism."""

from __future__ import annotations

import fnmatch
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from collision_usd_build import ROBOT
from sim2real.assets.collision import part_files
from sim2real.assets.meshes import BuiltMeshes
from sim2real.assets.urdf_model import read_urdf
from sim2real.assets.usd import build_usd
from sim2real.assets.usd_bodies import axis_frame, principal_inertia
from sim2real.assets.usd_validation import CLASSIC_CHECKS, PACKAGE_ONLY_VALIDATORS, PHYSICS_VALIDATORS, compliance_errors, validator_names
from sim2real.assets.urdf import mesh_names

pxr = pytest.importorskip("pxr")
from pxr import Gf, Usd, UsdGeom, UsdPhysics, UsdShade  # noqa: E402


@pytest.fixture(scope="module")
def built(built_tree: Path) -> Path:
    """The suite's shared built tree (conftest): read-only."""
    return built_tree


@pytest.fixture(scope="module")
def stage(built: Path) -> Usd.Stage:
    return Usd.Stage.Open(str(built / "results" / ROBOT / "usd" / f"{ROBOT}.usda"))


def build_again(tree: Path, out_dir: Path) -> tuple[Path, Path]:
    results = tree / "results" / ROBOT
    names = mesh_names(results / f"{ROBOT}.urdf")
    visual = [results / "meshes" / "visual" / n for n in names["visual"]]
    collision = {uri: part_files(results / "collision" / n) for n, uri in names["collision"].items()}
    out = (out_dir / f"{ROBOT}.usda", out_dir / f"{ROBOT}_geometry.usda")
    build_usd(results / f"{ROBOT}.urdf", tree / "configs" / ROBOT / "robot.yaml", BuiltMeshes.of(visual, collision), *out)
    return out


def test_stage_units_root_and_compliance(built: Path, stage: Usd.Stage) -> None:
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    root = stage.GetDefaultPrim()
    assert root.GetPath() == "/panda" and root.HasAPI(UsdPhysics.ArticulationRootAPI)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no DeprecationWarning (UsdUtils.ComplianceChecker is gone), no other
        assert compliance_errors(built / "results" / ROBOT / "usd" / f"{ROBOT}.usda") == []


def test_validators_replace_every_classic_check_and_add_physics() -> None:
    names = validator_names()
    for check, validators in CLASSIC_CHECKS.items():
        assert set(validators) <= set(names), check
    assert set(PHYSICS_VALIDATORS) <= set(names)
    assert not set(names) & PACKAGE_ONLY_VALIDATORS


def test_validators_catch_what_the_classic_checker_caught(tmp_path: Path) -> None:
    """A stage breaking one classic check (and one physics rule) at a time: each is an error."""
    from pxr import Sdf

    def errors_of(author) -> list[str]:
        path = tmp_path / f"{author.__name__}.usda"
        stage = Usd.Stage.CreateNew(str(path))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        root = UsdGeom.Xform.Define(stage, "/robot")
        stage.SetDefaultPrim(root.GetPrim())
        author(stage)
        stage.GetRootLayer().Save()
        return compliance_errors(path)

    def fine(stage: Usd.Stage) -> None:
        UsdGeom.Cube.Define(stage, "/robot/box")

    def no_default_prim(stage: Usd.Stage) -> None:
        stage.ClearDefaultPrim()

    def no_up_axis(stage: Usd.Stage) -> None:
        stage.ClearMetadata("upAxis")

    def missing_reference(stage: Usd.Stage) -> None:
        stage.DefinePrim("/robot/part").GetReferences().AddReference("./nowhere.usda")

    def nested_gprims(stage: Usd.Stage) -> None:
        UsdGeom.Cube.Define(stage, "/robot/box")
        UsdGeom.Sphere.Define(stage, "/robot/box/ball")

    def binding_without_api(stage: Usd.Stage) -> None:
        material = UsdShade.Material.Define(stage, "/robot/red")
        box = UsdGeom.Cube.Define(stage, "/robot/box").GetPrim()
        box.CreateRelationship("material:binding").SetTargets([material.GetPath()])

    def joint_to_nowhere(stage: Usd.Stage) -> None:
        joint = UsdPhysics.RevoluteJoint.Define(stage, "/robot/joint")
        joint.CreateBody0Rel().SetTargets([Sdf.Path("/robot/missing_link")])

    assert errors_of(fine) == []
    expected = {
        no_default_prim: "usdValidation:StageMetadataChecker",
        no_up_axis: "usdGeomValidators:StageMetadataChecker",
        missing_reference: "usdUtilsValidators:MissingReferenceValidator",
        nested_gprims: "usdGeomValidators:EncapsulationChecker",
        binding_without_api: "usdShadeValidators:MaterialBindingApiAppliedValidator",
        joint_to_nowhere: "usdPhysicsValidators:PhysicsJointChecker",
    }
    for author, validator in expected.items():
        found = errors_of(author)
        assert any(e.startswith(validator) for e in found), (author.__name__, found)


def test_joints_limits_in_degrees_and_drives_per_degree(built: Path, stage: Usd.Stage) -> None:
    urdf = read_urdf(built / "results" / ROBOT / f"{ROBOT}.urdf")
    config = yaml.safe_load((built / "configs" / ROBOT / "robot.yaml").read_text())

    def gains(joint: str) -> tuple[float, float]:
        entry = next(a for a in config["actuators"] if fnmatch.fnmatchcase(joint, a["joints"]))
        return float(entry["kp"]), float(entry["kv"])

    joints = {p.GetName(): p for p in stage.Traverse() if p.IsA(UsdPhysics.Joint)}
    revolute = [n for n, p in joints.items() if p.IsA(UsdPhysics.RevoluteJoint)]
    assert revolute == [f"panda_joint{i}" for i in range(1, 8)]
    assert [n for n, p in joints.items() if p.IsA(UsdPhysics.PrismaticJoint)] == ["panda_finger_joint1", "panda_finger_joint2"]
    for name in revolute:
        joint = UsdPhysics.RevoluteJoint(joints[name])
        assert joint.GetLowerLimitAttr().Get() == pytest.approx(math.degrees(urdf.joints[name].lower), rel=1e-6)
        assert joint.GetUpperLimitAttr().Get() == pytest.approx(math.degrees(urdf.joints[name].upper), rel=1e-6)
    for name in revolute:
        kp, kv = gains(name)
        drive = UsdPhysics.DriveAPI(joints[name], "angular")
        assert drive.GetStiffnessAttr().Get() == pytest.approx(kp * math.pi / 180, rel=1e-6)  # per degree, not per rad
        assert drive.GetDampingAttr().Get() == pytest.approx(kv * math.pi / 180, rel=1e-6)
    finger = UsdPhysics.PrismaticJoint(joints["panda_finger_joint1"])
    assert UsdPhysics.DriveAPI(finger.GetPrim(), "linear").GetStiffnessAttr().Get() == pytest.approx(100.0)  # N/m: no conversion
    assert finger.GetUpperLimitAttr().Get() == pytest.approx(0.04)
    assert not joints["panda_finger_joint2"].HasAPI(UsdPhysics.DriveAPI, "linear")  # mimic: not actuated


def test_joint_frames_coincide_at_zero_configuration(stage: Usd.Stage) -> None:
    cache = UsdGeom.XformCache()
    for prim in stage.Traverse():
        if not prim.IsA(UsdPhysics.Joint):
            continue
        joint = UsdPhysics.Joint(prim)
        frames = []
        for rel, pos, rot in ((joint.GetBody0Rel(), joint.GetLocalPos0Attr(), joint.GetLocalRot0Attr()),
                              (joint.GetBody1Rel(), joint.GetLocalPos1Attr(), joint.GetLocalRot1Attr())):
            targets = rel.GetTargets()
            world = cache.GetLocalToWorldTransform(stage.GetPrimAtPath(targets[0])) if targets else Gf.Matrix4d(1)
            local = Gf.Matrix4d().SetTransform(Gf.Rotation(Gf.Quatd(rot.Get())), Gf.Vec3d(pos.Get()))
            frames.append(np.array(local * world))
        np.testing.assert_allclose(frames[0], frames[1], atol=1e-6, err_msg=prim.GetName())


def test_masses_and_inertia_match_the_urdf(built: Path, stage: Usd.Stage) -> None:
    urdf = read_urdf(built / "results" / ROBOT / f"{ROBOT}.urdf")
    bodies = {p.GetName(): p for p in stage.Traverse() if p.HasAPI(UsdPhysics.RigidBodyAPI)}
    massive = {name for name, link in urdf.links.items() if link.mass > 0}
    assert set(bodies) == massive  # massless frames (link8, TCP) are folded into their parent body
    for name in massive:
        mass_api = UsdPhysics.MassAPI(bodies[name])
        assert mass_api.GetMassAttr().Get() == pytest.approx(urdf.links[name].mass, rel=1e-6)
        np.testing.assert_allclose(mass_api.GetCenterOfMassAttr().Get(), urdf.links[name].com, atol=1e-7)
        moments, _ = principal_inertia(urdf.links[name].inertia)
        np.testing.assert_allclose(mass_api.GetDiagonalInertiaAttr().Get(), moments, rtol=1e-5)


def test_colliders_are_the_coacd_parts_with_convex_hull_approximation(built: Path, stage: Usd.Stage) -> None:
    report = json.loads((built / "results" / ROBOT / "collision" / "report.json").read_text())
    hand = stage.GetPrimAtPath("/panda/panda_hand")
    colliders = [p for p in Usd.PrimRange(hand) if p.HasAPI(UsdPhysics.CollisionAPI)]
    assert len(colliders) == report["meshes"]["hand"]["hulls"] > 1
    for prim in colliders:
        assert UsdPhysics.MeshCollisionAPI(prim).GetApproximationAttr().Get() == UsdPhysics.Tokens.convexHull
        assert UsdGeom.Imageable(prim).GetPurposeAttr().Get() == UsdGeom.Tokens.guide
    finger_boxes = [p for p in Usd.PrimRange(stage.GetPrimAtPath("/panda/panda_leftfinger")) if p.HasAPI(UsdPhysics.CollisionAPI)]
    assert len(finger_boxes) == 4 and all(p.IsA(UsdGeom.Cube) for p in finger_boxes)


def test_visual_meshes_carry_their_colors(built: Path, stage: Usd.Stage) -> None:
    parts = json.loads((built / "results" / ROBOT / "meshes" / "visual" / "link7" / "parts.json").read_text())["parts"]
    meshes = [p for p in Usd.PrimRange(stage.GetPrimAtPath("/panda/panda_link7/visual_00")) if p.IsA(UsdGeom.Mesh)]
    assert len(meshes) == len(parts)
    for mesh, part in zip(meshes, parts, strict=True):
        material, _ = UsdShade.MaterialBindingAPI(mesh).ComputeBoundMaterial()
        shader = UsdShade.Shader(material.ComputeSurfaceSource()[0])
        assert shader.GetIdAttr().Get() == "UsdPreviewSurface"
        np.testing.assert_allclose(shader.GetInput("diffuseColor").Get(), part["rgba"][:3], atol=1e-6)


def test_rebuild_is_byte_identical_and_has_no_absolute_paths(built: Path, tmp_path: Path) -> None:
    first = build_again(built, tmp_path / "one")
    second = build_again(built, tmp_path / "two")
    for a, b in zip(first, second, strict=True):
        assert a.read_bytes() == b.read_bytes(), a.name
    text = first[0].read_text()
    assert f"@./{ROBOT}_geometry.usda@" in text
    assert str(tmp_path) not in text and str(built) not in text


def test_axis_frame_maps_the_token_axis_onto_the_urdf_axis() -> None:
    for axis in ([0, 0, 1], [0, -1, 0], [-1, 0, 0], [0.6, 0.8, 0]):
        token, rotation = axis_frame(np.array(axis, dtype=float))
        unit = np.eye(3)["XYZ".index(token)]
        np.testing.assert_allclose(rotation @ unit, axis, atol=1e-12)
        assert np.linalg.det(rotation) == pytest.approx(1.0)


def test_principal_inertia_reconstructs_the_tensor() -> None:
    inertia = np.array([[0.0079, -0.0039, 0.0102], [-0.0039, 0.0281, 0.0007], [0.0102, 0.0007, 0.026]])
    moments, axes = principal_inertia(inertia)
    np.testing.assert_allclose(axes @ np.diag(moments) @ axes.T, inertia, atol=1e-12)
    assert np.linalg.det(axes) == pytest.approx(1.0)
