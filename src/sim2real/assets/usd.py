"""URDF + built meshes -> a UsdPhysics articulation (pxr: UsdGeom, UsdShade, UsdPhysics).

Two layers, written side by side under ``results/{robot}/usd/``:

- ``{robot}.usda``: the robot. One rigid body Xform per URDF link with mass (flat under the default
  prim, placed at its zero-configuration world pose), mass/CoM/principal inertia (MassAPI),
  revolute/prismatic/fixed joints with limits (degrees for revolute), a drive per actuated joint
  whose gains equal the MJCF actuator's after unit conversion (USD angular gains are per degree),
  materials (UsdPreviewSurface) and the bindings of the visual parts.
- ``{robot}_geometry.usda``: every mesh once (visual parts per material, CoACD convex parts as
  colliders with ``convexHull`` approximation), referenced from the robot layer by a relative path.

Links without mass joined by a fixed joint (a flange frame, a TCP) are folded into their parent
body, as simulators require positive mass on every rigid body; their geometry moves with it.
Output is deterministic: fixed authoring order, no timestamps, no absolute paths.

The link and joint records come from the URDF reader (:mod:`sim2real.assets.urdf_model`), the bodies, joint frames
and drives from :mod:`sim2real.assets.usd_bodies`, the meshes, primitives and materials from
:mod:`sim2real.assets.usd_geometry`; what was authored
is read back by USD's validators (:mod:`sim2real.assets.usd_validation`) before it is moved into place.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.assets.meshes import BuiltMeshes
from sim2real.assets.robot_config import first_match, read_robot_config
from sim2real.assets.urdf import mesh_name
from sim2real.assets.urdf_model import RAD_PER_DEG, Geometry, Joint, UrdfModel, read_urdf, transform
from sim2real.assets.usd_bodies import Body, DriveGains, axis_frame, drive_gains, fold_bodies, matrix_to_quat, principal_inertia
from sim2real.assets.usd_geometry import GEOMETRY_ROOT, GeometryLayer, _material, _primitive, _set_pose, prim_name
from sim2real.assets.usd_validation import compliance_errors
from sim2real.errors import InputError

def _stage_metadata(stage: Any, default_prim: str) -> None:
    from pxr import UsdGeom, UsdPhysics

    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
    stage.SetDefaultPrim(stage.GetPrimAtPath(default_prim))


def build_usd(
    urdf_path: str | Path,
    robot_config_path: str | Path,
    meshes: BuiltMeshes,
    out_usda: str | Path,
    out_geometry: str | Path,
    robot_settings: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Write the robot layer ``out_usda`` and the geometry layer ``out_geometry`` (same directory).

    ``meshes``: the visual parts and the collision files (CoACD's convex parts, or one mesh file);
    ``robot_settings``: robot.yaml's content, when already read (:func:`read_robot_config`).
    Returns a summary (bodies, joints, drives). Both layers pass USD's registered validators
    (:func:`compliance_errors`) before they replace the outputs.
    """
    urdf_path, out_usda, out_geometry = Path(urdf_path), Path(out_usda), Path(out_geometry)
    if out_usda.parent.resolve() != out_geometry.parent.resolve():
        raise InputError(out_geometry, None, "must sit beside the robot layer", f"write it into {out_usda.parent}")
    config = read_robot_config(robot_config_path, robot_settings)
    model = read_urdf(urdf_path)
    bodies, body_of = fold_bodies(model)
    gains = drive_gains(model, config, robot_config_path)
    home = dict(config.get("home") or {})
    armature_patterns = dict(config.get("armature") or {})

    robot = _Robot(model, bodies, body_of, gains, home, armature_patterns, meshes, urdf_path)
    with _staging_dir(out_usda, out_geometry) as (tmp_usda, tmp_geometry):
        summary = _author(robot, tmp_usda, tmp_geometry)
    return summary


@dataclass(frozen=True)
class _Robot:
    """What the layers are authored from: the URDF's records, their bodies, the drives and the built meshes."""

    model: UrdfModel
    bodies: Mapping[str, Body]
    body_of: Mapping[str, str | None]  # URDF link -> the body it is folded into (None: the world)
    gains: Mapping[str, DriveGains]
    home: Mapping[str, float]
    armature_patterns: Mapping[str, Any]
    meshes: BuiltMeshes
    urdf_path: Path  # named in errors


@dataclass(frozen=True)
class _Stages:
    """The two layers being authored, and where the robot layer keeps its materials."""

    stage: Any  # the robot layer
    geometry: GeometryLayer
    geometry_ref: str  # the geometry layer, relative to the robot layer
    robot_path: str
    looks: str
    materials: dict[tuple[float, ...], Any] = field(default_factory=dict)

    def body_path(self, body: str) -> str:
        return f"{self.robot_path}/{prim_name(body)}"


def _author(robot: _Robot, out_usda: Path, out_geometry: Path) -> dict[str, Any]:
    stages = _open_stages(robot.model, out_usda, out_geometry)
    for body in robot.bodies.values():
        _author_body(robot, stages, body)
    summary_joints = _author_joints(robot, stages)
    stages.geometry.stage.GetRootLayer().Save()
    stages.stage.GetRootLayer().Save()
    return {"bodies": list(robot.bodies), "joints": summary_joints}


def _open_stages(model: UrdfModel, out_usda: Path, out_geometry: Path) -> _Stages:
    """The geometry layer (saved empty: the robot layer references it) and the robot layer's root and looks."""
    from pxr import Usd, UsdGeom, UsdPhysics

    robot_path = f"/{prim_name(model.name)}"
    geometry_stage = Usd.Stage.CreateNew(str(out_geometry))
    UsdGeom.Scope.Define(geometry_stage, GEOMETRY_ROOT)
    _stage_metadata(geometry_stage, GEOMETRY_ROOT)
    geometry = GeometryLayer(geometry_stage)
    geometry_ref = f"./{out_geometry.name}"

    geometry_stage.GetRootLayer().Save()  # the robot layer references it: it must be on disk
    stage = Usd.Stage.CreateNew(str(out_usda))
    root = UsdGeom.Xform.Define(stage, robot_path)
    _stage_metadata(stage, robot_path)
    UsdPhysics.ArticulationRootAPI.Apply(root.GetPrim())
    looks = f"{robot_path}/Looks"
    UsdGeom.Scope.Define(stage, looks)
    return _Stages(stage, geometry, geometry_ref, robot_path, looks)


def _author_body(robot: _Robot, stages: _Stages, body: Body) -> None:
    """One rigid body: its pose, its mass properties, and the geometry of every link folded into it."""
    from pxr import UsdGeom, UsdPhysics

    link = robot.model.links[body.link]
    body_path = stages.body_path(body.link)
    xform = UsdGeom.Xform.Define(stages.stage, body_path)
    _set_pose(xform, body.world)
    prim = xform.GetPrim()
    UsdPhysics.RigidBodyAPI.Apply(prim)
    if link.mass > 0:
        _author_mass(prim, link.mass, link.com, link.inertia)
    counters = {"visual": 0, "collision": 0}
    for member, member_pose in body.members.items():
        for item in robot.model.links[member].geometries:
            index = counters[item.kind]
            counters[item.kind] += 1
            item_path = f"{body_path}/{item.kind}_{index:02d}"
            pose = member_pose @ item.pose
            where = f"link '{member}' <{item.kind}>"
            if item.shape == "mesh":
                _author_mesh(robot, stages, item, item_path, pose, where)
            else:
                shape_prim = _primitive(stages.stage, item_path, item)
                _set_pose(shape_prim, pose, item.size if item.shape == "box" else None)
                if item.kind == "collision":
                    shape_prim.CreatePurposeAttr(UsdGeom.Tokens.guide)
                    UsdPhysics.CollisionAPI.Apply(shape_prim.GetPrim())


def _author_mass(prim: Any, mass: float, com: Sequence[float], inertia: np.ndarray) -> None:
    """MassAPI: mass, centre of mass and the principal inertia (moments and axes)."""
    from pxr import Gf, UsdPhysics

    mass_api = UsdPhysics.MassAPI.Apply(prim)
    mass_api.CreateMassAttr(float(mass))
    mass_api.CreateCenterOfMassAttr(Gf.Vec3f(*(float(v) for v in com)))
    moments, axes = principal_inertia(inertia)
    mass_api.CreateDiagonalInertiaAttr(Gf.Vec3f(*(float(v) for v in moments)))
    w, x, y, z = matrix_to_quat(axes)
    mass_api.CreatePrincipalAxesAttr(Gf.Quatf(w, x, y, z))


def _author_mesh(robot: _Robot, stages: _Stages, item: Geometry, item_path: str, pose: np.ndarray, where: str) -> None:
    """A holder referencing the mesh in the geometry layer; a visual mesh's parts get their materials."""
    from pxr import Sdf, UsdGeom, UsdShade

    name = mesh_name(item.uri)
    holder = UsdGeom.Xform.Define(stages.stage, item_path)
    _set_pose(holder, pose, item.scale)
    geometry = stages.geometry
    if item.kind == "visual":
        if name not in robot.meshes.visual:
            raise InputError(robot.urdf_path, where, f"no built visual mesh for '{item.uri}'", "build the visual meshes first")
        source = geometry.visual(name, robot.meshes.visual[name])
    else:
        files = robot.meshes.collision.get(item.uri)
        if not files:
            raise InputError(robot.urdf_path, where, f"no collision parts for '{item.uri}'", "build the collision parts first")
        source = geometry.collision(name, [Path(f) for f in files])
    holder.GetPrim().GetReferences().AddReference(stages.geometry_ref, Sdf.Path(source))
    if item.kind == "visual":
        for part_key, rgba in geometry.rgba.items():
            if part_key.startswith(f"visual/{name}/"):
                part_prim = stages.stage.OverridePrim(f"{item_path}/{part_key.rsplit('/', 1)[1]}")
                binding = UsdShade.MaterialBindingAPI.Apply(part_prim)
                binding.Bind(_material(stages.stage, stages.looks, rgba, stages.materials))


def _author_joints(robot: _Robot, stages: _Stages) -> list[dict[str, Any]]:
    """The joints scope: the weld of a fixed base to the world, then every joint not folded away (URDF order)."""
    from pxr import Sdf, UsdGeom, UsdPhysics

    model = robot.model
    joints_path = f"{stages.robot_path}/joints"
    UsdGeom.Scope.Define(stages.stage, joints_path)
    summary_joints = []
    if robot.body_of[model.root] is not None:  # fixed base: weld the root body to the world
        anchor = UsdPhysics.FixedJoint.Define(stages.stage, f"{joints_path}/world_fixed")
        anchor.CreateBody1Rel().SetTargets([Sdf.Path(stages.body_path(model.root))])
    for joint in model.joints.values():
        parent_body, child_body = robot.body_of[joint.parent], robot.body_of[joint.child]
        if joint.type == "fixed" and parent_body == child_body:
            continue  # folded into its parent body
        summary_joints.append(_author_joint(robot, stages, f"{joints_path}/{prim_name(joint.name)}", joint))
    return summary_joints


def _author_joint(robot: _Robot, stages: _Stages, joint_path: str, joint: Joint) -> dict[str, Any]:
    """One joint: its type, the bodies and frames it joins, and (unless fixed) its axis, limits, armature and drive."""
    from pxr import Gf, Sdf, UsdPhysics

    parent_body, child_body = robot.body_of[joint.parent], robot.body_of[joint.child]
    revolute = joint.type in ("revolute", "continuous")
    if revolute:
        usd_joint = UsdPhysics.RevoluteJoint.Define(stages.stage, joint_path)
    elif joint.type == "prismatic":
        usd_joint = UsdPhysics.PrismaticJoint.Define(stages.stage, joint_path)
    elif joint.type == "fixed":
        usd_joint = UsdPhysics.FixedJoint.Define(stages.stage, joint_path)
    else:
        raise InputError(robot.urdf_path, f"joint '{joint.name}'", f"type '{joint.type}' has no USD counterpart here",
                         "use revolute, continuous, prismatic or fixed")
    token, axis_rotation = axis_frame(joint.axis)
    parent_pose = (robot.bodies[parent_body].members[joint.parent] if parent_body is not None else np.eye(4)) @ joint.origin
    frame0 = parent_pose @ transform(axis_rotation)
    frame1 = robot.bodies[child_body].members[joint.child] @ transform(axis_rotation)  # type: ignore[index]
    if parent_body is not None:
        usd_joint.CreateBody0Rel().SetTargets([Sdf.Path(stages.body_path(parent_body))])
    usd_joint.CreateBody1Rel().SetTargets([Sdf.Path(stages.body_path(child_body))])  # type: ignore[arg-type]
    for frame, pos_attr, rot_attr in ((frame0, usd_joint.CreateLocalPos0Attr, usd_joint.CreateLocalRot0Attr),
                                      (frame1, usd_joint.CreateLocalPos1Attr, usd_joint.CreateLocalRot1Attr)):
        pos_attr(Gf.Vec3f(*(float(v) for v in frame[:3, 3])))
        w, x, y, z = matrix_to_quat(frame[:3, :3])
        rot_attr(Gf.Quatf(w, x, y, z))
    entry: dict[str, Any] = {"name": joint.name, "type": joint.type}
    if joint.type != "fixed":
        usd_joint.CreateAxisAttr(token)
        _author_motion(robot, usd_joint, joint, revolute, entry)
    return entry


def _author_motion(robot: _Robot, usd_joint: Any, joint: Joint, revolute: bool, entry: dict[str, Any]) -> None:
    """A moving joint's limits (degrees for revolute), armature and drive; the drive's gains go into ``entry``."""
    from pxr import Sdf, UsdPhysics

    to_usd = (1.0 / RAD_PER_DEG) if revolute else 1.0
    if joint.type != "continuous" and joint.lower is not None and joint.upper is not None:
        usd_joint.CreateLowerLimitAttr(float(joint.lower * to_usd))
        usd_joint.CreateUpperLimitAttr(float(joint.upper * to_usd))
    armature = first_match(joint.name, robot.armature_patterns)
    if armature is not None:
        prim = usd_joint.GetPrim()
        for attr in ("newton:armature", "physxJoint:armature"):  # solver-specific, no core schema
            prim.CreateAttribute(attr, Sdf.ValueTypeNames.Float, custom=True).Set(float(armature))
    gain = robot.gains.get(joint.name)
    if gain is not None:
        drive = UsdPhysics.DriveAPI.Apply(usd_joint.GetPrim(), "angular" if revolute else "linear")
        drive.CreateTypeAttr(UsdPhysics.Tokens.force)
        drive.CreateStiffnessAttr(float(gain.usd_stiffness(revolute)))
        drive.CreateDampingAttr(float(gain.usd_damping(revolute)))
        if gain.max_force is not None:
            drive.CreateMaxForceAttr(float(gain.max_force))
        if gain.kind == "position":
            drive.CreateTargetPositionAttr(float(robot.home.get(joint.name, 0.0) * to_usd))
        entry["drive"] = {"stiffness": gain.usd_stiffness(revolute), "damping": gain.usd_damping(revolute)}


@contextlib.contextmanager
def _staging_dir(out_usda: Path, out_geometry: Path) -> Iterator[tuple[Path, Path]]:
    """Temporary files beside the outputs: the layers are authored and checked there, then moved in."""
    out_usda.parent.mkdir(parents=True, exist_ok=True)
    tmp_dir = Path(tempfile.mkdtemp(prefix=".usd.", dir=out_usda.parent))
    try:
        tmp_usda, tmp_geometry = tmp_dir / out_usda.name, tmp_dir / out_geometry.name
        yield tmp_usda, tmp_geometry
        errors = compliance_errors(tmp_usda)
        if errors:
            raise InputError(out_usda, None, "USD compliance check failed: " + "; ".join(errors), "fix the USD writer or its inputs")
        for tmp, target in ((tmp_geometry, out_geometry), (tmp_usda, out_usda)):
            os.chmod(tmp, 0o644)
            os.replace(tmp, target)
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)
