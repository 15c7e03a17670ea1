"""The geoms of the MJCF (:mod:`sim2real.assets.mjcf` builds the rest), added back through ``mujoco.MjSpec`` after the
URDF importer saw none: the menagerie's default classes (``visual``: no contacts, group 2; ``collision``: group 3),
each visual mesh as one geom per material part with its material, each collision file as one collision geom, and
the box, cylinder and sphere primitives, placed as the URDF's origins put them.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco

from sim2real.errors import InputError
from sim2real.files import relative_path
from sim2real.assets.meshes import read_parts
from sim2real.assets.urdf import mesh_name
from sim2real.assets.urdf_model import float_list

VISUAL_CLASS = "visual"
COLLISION_CLASS = "collision"


@dataclass(frozen=True)
class UrdfGeometry:
    link: str
    kind: str  # "visual" | "collision"
    element: ET.Element  # the <geometry> child: mesh, box, cylinder, sphere
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    material: tuple[str, tuple[float, ...]] | None = None  # a visual's URDF material: name, rgba


def _floats(text: str | None, default: Sequence[float]) -> tuple[float, ...]:
    return tuple(float(v) for v in float_list(text, default))


def rpy_to_quat(rpy: Sequence[float]) -> tuple[float, float, float, float]:
    """URDF roll-pitch-yaw (fixed axes X, Y, Z) -> MuJoCo quaternion (w, x, y, z)."""
    roll, pitch, yaw = rpy
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def _urdf_materials(root: ET.Element) -> dict[str, tuple[float, ...]]:
    """The URDF's named top-level materials that carry a color: name -> rgba."""
    return {
        material.get("name", ""): _floats(material.find("color").get("rgba"), (0.5, 0.5, 0.5, 1))  # type: ignore[union-attr]
        for material in root.findall("material")
        if material.find("color") is not None
    }


def _visual_material(element: ET.Element, named: Mapping[str, tuple[float, ...]]) -> tuple[str, tuple[float, ...]] | None:
    """A visual's material as (name, rgba): its own color, or the top-level material it names; None without one."""
    material = element.find("material")
    if material is None:
        return None
    name = material.get("name", "")
    color = material.find("color")
    if color is not None:
        return name, _floats(color.get("rgba"), (0.5, 0.5, 0.5, 1))
    return (name, named[name]) if name in named else None


def urdf_geometries(root: ET.Element) -> list[UrdfGeometry]:
    out = []
    named = _urdf_materials(root)
    for link in root.findall("link"):
        for kind in ("visual", "collision"):
            for element in link.findall(kind):
                geometry = element.find("geometry")
                if geometry is None or len(geometry) == 0:
                    continue
                origin = element.find("origin")
                xyz = _floats(origin.get("xyz") if origin is not None else None, (0, 0, 0))
                rpy = _floats(origin.get("rpy") if origin is not None else None, (0, 0, 0))
                material = _visual_material(element, named) if kind == "visual" else None
                out.append(UrdfGeometry(link.get("name", ""), kind, geometry[0], xyz, rpy_to_quat(rpy),  # type: ignore[arg-type]
                                        material))
    return out


def _add_default_classes(spec: mujoco.MjSpec) -> tuple[mujoco.MjsDefault, mujoco.MjsDefault]:
    """Menagerie classes: visual (no contacts, group 2) and collision (group 3)."""
    visual = spec.add_default(VISUAL_CLASS, spec.default)
    visual.geom.type = mujoco.mjtGeom.mjGEOM_MESH
    visual.geom.contype = 0
    visual.geom.conaffinity = 0
    visual.geom.group = 2
    visual.geom.density = 0
    collision = spec.add_default(COLLISION_CLASS, spec.default)
    collision.geom.group = 3
    return visual, collision


def _add_geometry(
    spec: mujoco.MjSpec,
    root: ET.Element,
    urdf_path: Path,
    visual_by_name: Mapping[str, Path],
    collision_meshes: Mapping[str, Sequence[str | Path]],
    out_dir: Path,
    visual_class: mujoco.MjsDefault,
    collision_class: mujoco.MjsDefault,
) -> None:
    meshes_added: set[str] = set()
    materials_added: set[str] = set()
    counters: dict[tuple[str, str], int] = {}

    def geom_name(link: str, kind: str) -> str:
        index = counters.get((link, kind), 0)
        counters[(link, kind)] = index + 1
        return f"{link}_{kind}" if index == 0 else f"{link}_{kind}_{index}"

    for geometry in urdf_geometries(root):
        body = spec.body(geometry.link)
        if body is None:
            continue
        element = geometry.element
        where = f"link '{geometry.link}' <{geometry.kind}>"
        if element.tag == "mesh":
            uri = element.get("filename", "")
            scale = _floats(element.get("scale"), (1, 1, 1))
            suffix = "" if scale == (1.0, 1.0, 1.0) else "_s" + "_".join(f"{s:g}" for s in scale)
            name = mesh_name(uri)
            if geometry.kind == "visual":
                directory = visual_by_name.get(name)
                if directory is None:
                    raise InputError(urdf_path, where, f"no converted visual mesh for '{uri}'", "build the visual meshes first")
                record = read_parts(directory)
                for index, part in enumerate(record["parts"]):
                    mesh_id = f"{name}_{index}{suffix}"
                    if mesh_id not in meshes_added:
                        spec.add_mesh(name=mesh_id, file=relative_path(directory / part["file"], out_dir), scale=list(scale))
                        meshes_added.add(mesh_id)
                    material_id = f"{name}_{index}"
                    if material_id not in materials_added:
                        spec.add_material(name=material_id, rgba=list(part["rgba"]))
                        materials_added.add(material_id)
                    body.add_geom(
                        visual_class, name=geom_name(geometry.link, "visual"), type=mujoco.mjtGeom.mjGEOM_MESH,
                        meshname=mesh_id, material=material_id, **_placement(geometry),
                    )
            else:
                files = collision_meshes.get(uri)
                if not files:
                    raise InputError(urdf_path, where, f"no collision mesh file given for '{uri}'", "build the collision meshes first")
                for index, file in enumerate(files):
                    mesh_id = f"{name}_collision{'' if len(files) == 1 else f'_{index}'}{suffix}"
                    if mesh_id not in meshes_added:
                        spec.add_mesh(name=mesh_id, file=relative_path(file, out_dir), scale=list(scale))
                        meshes_added.add(mesh_id)
                    body.add_geom(
                        collision_class, name=geom_name(geometry.link, "collision"), type=mujoco.mjtGeom.mjGEOM_MESH,
                        meshname=mesh_id, **_placement(geometry),
                    )
        else:
            geom_type, size = _primitive(element, urdf_path, where)
            is_visual = geometry.kind == "visual"
            # A primitive visual takes its URDF material's color, as a mesh's parts take theirs.
            colored = {}
            if is_visual and geometry.material is not None:
                material_id, rgba = geometry.material
                if material_id not in materials_added:
                    spec.add_material(name=material_id, rgba=list(rgba))
                    materials_added.add(material_id)
                colored = {"material": material_id}
            body.add_geom(
                visual_class if is_visual else collision_class,
                name=geom_name(geometry.link, geometry.kind), type=geom_type, size=size,
                **_placement(geometry), **colored,
            )


def _placement(geometry: UrdfGeometry) -> dict[str, list[float]]:
    """pos/quat keyword arguments, omitted when identity (keeps the MJCF minimal)."""
    out = {}
    if any(v != 0 for v in geometry.pos):
        out["pos"] = list(geometry.pos)
    if geometry.quat != (1.0, 0.0, 0.0, 0.0):
        out["quat"] = list(geometry.quat)
    return out


def _primitive(element: ET.Element, urdf_path: Path, where: str) -> tuple[mujoco.mjtGeom, list[float]]:
    if element.tag == "box":
        return mujoco.mjtGeom.mjGEOM_BOX, [s / 2 for s in _floats(element.get("size"), (0, 0, 0))]
    if element.tag == "cylinder":
        return mujoco.mjtGeom.mjGEOM_CYLINDER, [float(element.get("radius", 0)), float(element.get("length", 0)) / 2, 0]
    if element.tag == "sphere":
        return mujoco.mjtGeom.mjGEOM_SPHERE, [float(element.get("radius", 0)), 0, 0]
    raise InputError(urdf_path, where, f"unsupported geometry <{element.tag}>", "use mesh, box, cylinder or sphere")
