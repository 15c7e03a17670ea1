"""The robot's geometry as USD holds it (:mod:`sim2real.assets.usd` authors the layers): every mesh written once into
the geometry layer (visual parts, CoACD convex parts as colliders), the box, cylinder and sphere primitives, the
materials (UsdPreviewSurface) of the visual parts, and the poses their prims are placed at.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from sim2real.assets.meshes import read_parts
from sim2real.assets.urdf_model import Geometry
from sim2real.assets.usd_bodies import matrix_to_quat

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
