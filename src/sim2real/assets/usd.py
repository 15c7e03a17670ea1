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
and drives from :mod:`sim2real.assets.usd_bodies`; what was authored
is read back by USD's validators (:mod:`sim2real.assets.usd_validation`) before it is moved into place.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from sim2real.assets.meshes import read_parts
from sim2real.assets.meshes import BuiltMeshes
from sim2real.assets.robot_config import first_match, read_robot_config
from sim2real.assets.urdf import mesh_name
from sim2real.assets.urdf_model import RAD_PER_DEG, Geometry, UrdfModel, read_urdf, transform
from sim2real.assets.usd_bodies import Body, DriveGains, axis_frame, drive_gains, fold_bodies, matrix_to_quat, principal_inertia
from sim2real.assets.usd_validation import compliance_errors
from sim2real.errors import InputError

GEOMETRY_ROOT = "/Geometry"


def prim_name(text: str) -> str:
    """A valid USD prim name from any string."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", text)
    return name if name and not name[0].isdigit() else f"_{name}"


def _vec(values: Sequence[float]) -> Any:
    from pxr import Gf

    return Gf.Vec3f(*(float(v) for v in values))


def _set_pose(xformable: Any, pose: np.ndarray, scale: Sequence[float] | None = None) -> None:
    """translate + orient (+ scale) ops; identity parts are omitted to keep the layer minimal."""
    from pxr import Gf, UsdGeom

    translation = pose[:3, 3]
    if np.any(np.abs(translation) > 0):
        xformable.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*(float(v) for v in translation)))
    w, x, y, z = matrix_to_quat(pose[:3, :3])
    if abs(w - 1.0) > 1e-12:
        xformable.AddOrientOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Quatd(w, x, y, z))
    if scale is not None and tuple(scale) != (1.0, 1.0, 1.0):
        xformable.AddScaleOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*(float(v) for v in scale)))


def _write_mesh(stage: Any, path: str, mesh: trimesh.Trimesh) -> Any:
    from pxr import Vt, UsdGeom

    prim = UsdGeom.Mesh.Define(stage, path)
    vertices = np.asarray(mesh.vertices, dtype=np.float32)
    prim.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(vertices))
    prim.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(mesh.faces), 3, dtype=np.int32)))
    prim.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(mesh.faces, dtype=np.int32).ravel()))
    prim.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # polygonal CAD meshes, not subdivision cages
    prim.CreateExtentAttr([_vec(vertices.min(axis=0)), _vec(vertices.max(axis=0))])
    return prim


def _load_mesh(path: Path) -> trimesh.Trimesh:
    loaded = trimesh.load(path, force="mesh", process=False)
    return trimesh.Trimesh(loaded.vertices, loaded.faces, process=False)


@dataclass
class GeometryLayer:
    """Meshes written once into the geometry layer, by key."""

    stage: Any
    prims: dict[str, str] = field(default_factory=dict)  # key -> prim path in the geometry layer
    rgba: dict[str, tuple[float, ...]] = field(default_factory=dict)  # visual prim path -> color

    def visual(self, name: str, directory: Path) -> str:
        from pxr import UsdGeom

        key = f"visual/{name}"
        if key not in self.prims:
            path = f"{GEOMETRY_ROOT}/visual/{prim_name(name)}"
            UsdGeom.Xform.Define(self.stage, path)
            record = read_parts(directory)
            for index, part in enumerate(record["parts"]):
                part_path = f"{path}/part_{index:02d}"
                _write_mesh(self.stage, part_path, _load_mesh(directory / part["file"]))
                self.rgba[f"{key}/part_{index:02d}"] = tuple(float(c) for c in part["rgba"])
            self.prims[key] = path
        return self.prims[key]

    def collision(self, name: str, files: Sequence[Path]) -> str:
        from pxr import UsdGeom, UsdPhysics

        key = f"collision/{name}"
        if key not in self.prims:
            path = f"{GEOMETRY_ROOT}/collision/{prim_name(name)}"
            UsdGeom.Xform.Define(self.stage, path)
            for index, file in enumerate(files):
                mesh = _write_mesh(self.stage, f"{path}/hull_{index:02d}", _load_mesh(Path(file)))
                mesh.CreatePurposeAttr(UsdGeom.Tokens.guide)  # colliders are not rendered
                UsdPhysics.CollisionAPI.Apply(mesh.GetPrim())
                UsdPhysics.MeshCollisionAPI.Apply(mesh.GetPrim()).CreateApproximationAttr(UsdPhysics.Tokens.convexHull)
            self.prims[key] = path
        return self.prims[key]


def _stage_metadata(stage: Any, default_prim: str) -> None:
    from pxr import UsdGeom, UsdPhysics

    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
    stage.SetDefaultPrim(stage.GetPrimAtPath(default_prim))


def _material(stage: Any, looks: str, rgba: tuple[float, ...], cache: dict[tuple[float, ...], Any]) -> Any:
    from pxr import Sdf, UsdShade

    key = tuple(round(c, 6) for c in rgba)
    if key not in cache:
        path = f"{looks}/material_{len(cache):02d}"
        material = UsdShade.Material.Define(stage, path)
        shader = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
        shader.CreateIdAttr("UsdPreviewSurface")
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(_vec(key[:3]))
        shader.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(float(key[3]))
        shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.5)
        material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        cache[key] = material
    return cache[key]


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

    with _staging_dir(out_usda, out_geometry) as (tmp_usda, tmp_geometry):
        summary = _author(model, bodies, body_of, gains, home, armature_patterns, meshes.visual, meshes.collision,
                          urdf_path, tmp_usda, tmp_geometry)
    return summary


def _author(
    model: UrdfModel,
    bodies: Mapping[str, Body],
    body_of: Mapping[str, str | None],
    gains: Mapping[str, DriveGains],
    home: Mapping[str, float],
    armature_patterns: Mapping[str, Any],
    visual_by_name: Mapping[str, Path],
    collision_meshes: Mapping[str, Sequence[str | Path]],
    urdf_path: Path,
    out_usda: Path,
    out_geometry: Path,
) -> dict[str, Any]:
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics, UsdShade

    robot_path = f"/{prim_name(model.name)}"
    geometry_stage = Usd.Stage.CreateNew(str(out_geometry))
    UsdGeom.Scope.Define(geometry_stage, GEOMETRY_ROOT)
    _stage_metadata(geometry_stage, GEOMETRY_ROOT)
    geometry = GeometryLayer(geometry_stage)
    geometry_ref = f"./{out_geometry.name}"

    geometry_stage.GetRootLayer().Save()  # the robot layer references it: it must be on disk
    stage = Usd.Stage.CreateNew(str(out_usda))
    robot = UsdGeom.Xform.Define(stage, robot_path)
    _stage_metadata(stage, robot_path)
    UsdPhysics.ArticulationRootAPI.Apply(robot.GetPrim())
    looks = f"{robot_path}/Looks"
    UsdGeom.Scope.Define(stage, looks)
    materials: dict[tuple[float, ...], Any] = {}

    for body in bodies.values():
        link = model.links[body.link]
        body_path = f"{robot_path}/{prim_name(body.link)}"
        xform = UsdGeom.Xform.Define(stage, body_path)
        _set_pose(xform, body.world)
        prim = xform.GetPrim()
        UsdPhysics.RigidBodyAPI.Apply(prim)
        if link.mass > 0:
            mass_api = UsdPhysics.MassAPI.Apply(prim)
            mass_api.CreateMassAttr(float(link.mass))
            mass_api.CreateCenterOfMassAttr(Gf.Vec3f(*(float(v) for v in link.com)))
            moments, axes = principal_inertia(link.inertia)
            mass_api.CreateDiagonalInertiaAttr(Gf.Vec3f(*(float(v) for v in moments)))
            w, x, y, z = matrix_to_quat(axes)
            mass_api.CreatePrincipalAxesAttr(Gf.Quatf(w, x, y, z))
        counters = {"visual": 0, "collision": 0}
        for member, member_pose in body.members.items():
            for item in model.links[member].geometries:
                index = counters[item.kind]
                counters[item.kind] += 1
                item_path = f"{body_path}/{item.kind}_{index:02d}"
                pose = member_pose @ item.pose
                where = f"link '{member}' <{item.kind}>"
                if item.shape == "mesh":
                    name = mesh_name(item.uri)
                    holder = UsdGeom.Xform.Define(stage, item_path)
                    _set_pose(holder, pose, item.scale)
                    if item.kind == "visual":
                        if name not in visual_by_name:
                            raise InputError(urdf_path, where, f"no built visual mesh for '{item.uri}'", "build the visual meshes first")
                        source = geometry.visual(name, visual_by_name[name])
                    else:
                        files = collision_meshes.get(item.uri)
                        if not files:
                            raise InputError(urdf_path, where, f"no collision parts for '{item.uri}'", "build the collision parts first")
                        source = geometry.collision(name, [Path(f) for f in files])
                    holder.GetPrim().GetReferences().AddReference(geometry_ref, Sdf.Path(source))
                    if item.kind == "visual":
                        for part_key, rgba in geometry.rgba.items():
                            if part_key.startswith(f"visual/{name}/"):
                                part_prim = stage.OverridePrim(f"{item_path}/{part_key.rsplit('/', 1)[1]}")
                                binding = UsdShade.MaterialBindingAPI.Apply(part_prim)
                                binding.Bind(_material(stage, looks, rgba, materials))
                else:
                    shape_prim = _primitive(stage, item_path, item)
                    _set_pose(shape_prim, pose, item.size if item.shape == "box" else None)
                    if item.kind == "collision":
                        shape_prim.CreatePurposeAttr(UsdGeom.Tokens.guide)
                        UsdPhysics.CollisionAPI.Apply(shape_prim.GetPrim())

    joints_path = f"{robot_path}/joints"
    UsdGeom.Scope.Define(stage, joints_path)
    summary_joints = []
    if body_of[model.root] is not None:  # fixed base: weld the root body to the world
        anchor = UsdPhysics.FixedJoint.Define(stage, f"{joints_path}/world_fixed")
        anchor.CreateBody1Rel().SetTargets([Sdf.Path(f"{robot_path}/{prim_name(model.root)}")])
    for joint in model.joints.values():
        parent_body, child_body = body_of[joint.parent], body_of[joint.child]
        if joint.type == "fixed" and parent_body == child_body:
            continue  # folded into its parent body
        joint_path = f"{joints_path}/{prim_name(joint.name)}"
        revolute = joint.type in ("revolute", "continuous")
        if revolute:
            usd_joint = UsdPhysics.RevoluteJoint.Define(stage, joint_path)
        elif joint.type == "prismatic":
            usd_joint = UsdPhysics.PrismaticJoint.Define(stage, joint_path)
        elif joint.type == "fixed":
            usd_joint = UsdPhysics.FixedJoint.Define(stage, joint_path)
        else:
            raise InputError(urdf_path, f"joint '{joint.name}'", f"type '{joint.type}' has no USD counterpart here",
                             "use revolute, continuous, prismatic or fixed")
        token, axis_rotation = axis_frame(joint.axis)
        parent_pose = (bodies[parent_body].members[joint.parent] if parent_body is not None else np.eye(4)) @ joint.origin
        frame0 = parent_pose @ transform(axis_rotation)
        frame1 = bodies[child_body].members[joint.child] @ transform(axis_rotation)  # type: ignore[index]
        if parent_body is not None:
            usd_joint.CreateBody0Rel().SetTargets([Sdf.Path(f"{robot_path}/{prim_name(parent_body)}")])
        usd_joint.CreateBody1Rel().SetTargets([Sdf.Path(f"{robot_path}/{prim_name(child_body)}")])  # type: ignore[arg-type]
        for frame, pos_attr, rot_attr in ((frame0, usd_joint.CreateLocalPos0Attr, usd_joint.CreateLocalRot0Attr),
                                          (frame1, usd_joint.CreateLocalPos1Attr, usd_joint.CreateLocalRot1Attr)):
            pos_attr(Gf.Vec3f(*(float(v) for v in frame[:3, 3])))
            w, x, y, z = matrix_to_quat(frame[:3, :3])
            rot_attr(Gf.Quatf(w, x, y, z))
        entry: dict[str, Any] = {"name": joint.name, "type": joint.type}
        if joint.type != "fixed":
            usd_joint.CreateAxisAttr(token)
            to_usd = (1.0 / RAD_PER_DEG) if revolute else 1.0
            if joint.type != "continuous" and joint.lower is not None and joint.upper is not None:
                usd_joint.CreateLowerLimitAttr(float(joint.lower * to_usd))
                usd_joint.CreateUpperLimitAttr(float(joint.upper * to_usd))
            armature = first_match(joint.name, armature_patterns)
            if armature is not None:
                prim = usd_joint.GetPrim()
                for attr in ("newton:armature", "physxJoint:armature"):  # solver-specific, no core schema
                    prim.CreateAttribute(attr, Sdf.ValueTypeNames.Float, custom=True).Set(float(armature))
            gain = gains.get(joint.name)
            if gain is not None:
                drive = UsdPhysics.DriveAPI.Apply(usd_joint.GetPrim(), "angular" if revolute else "linear")
                drive.CreateTypeAttr(UsdPhysics.Tokens.force)
                drive.CreateStiffnessAttr(float(gain.usd_stiffness(revolute)))
                drive.CreateDampingAttr(float(gain.usd_damping(revolute)))
                if gain.max_force is not None:
                    drive.CreateMaxForceAttr(float(gain.max_force))
                if gain.kind == "position":
                    drive.CreateTargetPositionAttr(float(home.get(joint.name, 0.0) * to_usd))
                entry["drive"] = {"stiffness": gain.usd_stiffness(revolute), "damping": gain.usd_damping(revolute)}
        summary_joints.append(entry)

    geometry_stage.GetRootLayer().Save()
    stage.GetRootLayer().Save()
    return {"bodies": list(bodies), "joints": summary_joints}


def _primitive(stage: Any, path: str, item: Geometry) -> Any:
    from pxr import UsdGeom

    if item.shape == "box":
        cube = UsdGeom.Cube.Define(stage, path)
        cube.CreateSizeAttr(1.0)  # unit cube scaled to the box extents by the xform
        cube.CreateExtentAttr([_vec((-0.5, -0.5, -0.5)), _vec((0.5, 0.5, 0.5))])
        return cube
    if item.shape == "cylinder":
        radius, length = item.size
        cylinder = UsdGeom.Cylinder.Define(stage, path)
        cylinder.CreateRadiusAttr(float(radius))
        cylinder.CreateHeightAttr(float(length))
        cylinder.CreateAxisAttr(UsdGeom.Tokens.z)
        cylinder.CreateExtentAttr([_vec((-radius, -radius, -length / 2)), _vec((radius, radius, length / 2))])
        return cylinder
    radius = item.size[0]
    sphere = UsdGeom.Sphere.Define(stage, path)
    sphere.CreateRadiusAttr(float(radius))
    sphere.CreateExtentAttr([_vec((-radius,) * 3), _vec((radius,) * 3)])
    return sphere


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
