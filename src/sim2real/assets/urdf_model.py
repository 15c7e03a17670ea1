"""The URDF as records: links (inertial, visual and collision geometry), joints (origin, axis, limits) and the
transforms between them. The one URDF reader the asset stages share (the USD writer, the equivalence check)."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim2real.errors import InputError

RAD_PER_DEG = math.pi / 180.0


AXIS_TOKENS = ("X", "Y", "Z")


def float_list(text: str | None, default: Sequence[float]) -> np.ndarray:
    """A URDF attribute of numbers (``xyz``, ``rpy``, ``scale``, ``size``), ``default`` where it is absent."""
    return np.array([float(v) for v in text.split()] if text else list(default), dtype=float)


def rpy_matrix(rpy: Sequence[float]) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes X, then Y, then Z) -> rotation matrix."""
    roll, pitch, yaw = rpy
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def transform(rotation: np.ndarray | None = None, translation: Sequence[float] | None = None) -> np.ndarray:
    out = np.eye(4)
    if rotation is not None:
        out[:3, :3] = rotation
    if translation is not None:
        out[:3, 3] = translation
    return out


def origin_transform(element: ET.Element | None) -> np.ndarray:
    origin = element.find("origin") if element is not None else None
    xyz = float_list(origin.get("xyz") if origin is not None else None, (0, 0, 0))
    rpy = float_list(origin.get("rpy") if origin is not None else None, (0, 0, 0))
    return transform(rpy_matrix(rpy), xyz)


@dataclass
class Geometry:
    kind: str  # "visual" | "collision"
    shape: str  # "mesh" | "box" | "cylinder" | "sphere"
    pose: np.ndarray  # in the link frame
    uri: str = ""
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    size: tuple[float, ...] = ()  # box: full extents; cylinder: radius, length; sphere: radius


@dataclass
class Link:
    name: str
    mass: float = 0.0
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))  # about the CoM, link axes
    geometries: list[Geometry] = field(default_factory=list)


@dataclass
class Joint:
    name: str
    type: str  # revolute | continuous | prismatic | fixed
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float | None = None
    upper: float | None = None
    effort: float | None = None
    velocity: float | None = None
    mimic: str | None = None


@dataclass
class UrdfModel:
    name: str
    links: dict[str, Link]  # URDF order
    joints: dict[str, Joint]  # URDF order
    root: str


def read_urdf(urdf_path: str | Path) -> UrdfModel:
    """The kinematic and inertial content of a URDF that the USD and the equivalence check need."""
    urdf_path = Path(urdf_path)
    try:
        root_element = ET.parse(urdf_path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise InputError(urdf_path, None, f"cannot be read as URDF ({exc})", "rebuild the URDF") from exc
    links: dict[str, Link] = {}
    for element in root_element.findall("link"):
        link = Link(element.get("name", ""))
        inertial = element.find("inertial")
        if inertial is not None and inertial.find("mass") is not None:
            pose = origin_transform(inertial)
            link.mass = float(inertial.find("mass").get("value", 0.0))  # type: ignore[union-attr]
            link.com = pose[:3, 3].copy()
            node = inertial.find("inertia")
            values = {k: float(node.get(k, 0.0)) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")} if node is not None else {}
            local = np.array([
                [values.get("ixx", 0.0), values.get("ixy", 0.0), values.get("ixz", 0.0)],
                [values.get("ixy", 0.0), values.get("iyy", 0.0), values.get("iyz", 0.0)],
                [values.get("ixz", 0.0), values.get("iyz", 0.0), values.get("izz", 0.0)],
            ])
            rotation = pose[:3, :3]
            link.inertia = rotation @ local @ rotation.T
        for kind in ("visual", "collision"):
            for item in element.findall(kind):
                geometry = item.find("geometry")
                if geometry is None or len(geometry) == 0:
                    continue
                shape = geometry[0]
                pose = origin_transform(item)
                if shape.tag == "mesh":
                    scale = tuple(float_list(shape.get("scale"), (1, 1, 1)))
                    link.geometries.append(Geometry(kind, "mesh", pose, uri=shape.get("filename", ""), scale=scale))  # type: ignore[arg-type]
                elif shape.tag == "box":
                    link.geometries.append(Geometry(kind, "box", pose, size=tuple(float_list(shape.get("size"), (0, 0, 0)))))
                elif shape.tag == "cylinder":
                    link.geometries.append(Geometry(kind, "cylinder", pose, size=(float(shape.get("radius", 0)), float(shape.get("length", 0)))))
                elif shape.tag == "sphere":
                    link.geometries.append(Geometry(kind, "sphere", pose, size=(float(shape.get("radius", 0)),)))
        links[link.name] = link
    joints: dict[str, Joint] = {}
    for element in root_element.findall("joint"):
        limit = element.find("limit")
        mimic = element.find("mimic")

        def limit_value(key: str, limit: ET.Element | None = limit) -> float | None:
            return float(limit.get(key)) if limit is not None and limit.get(key) is not None else None  # type: ignore[arg-type]

        axis = float_list(element.find("axis").get("xyz") if element.find("axis") is not None else None, (1, 0, 0))  # type: ignore[union-attr]
        joint = Joint(
            name=element.get("name", ""), type=element.get("type", ""),
            parent=element.find("parent").get("link", ""), child=element.find("child").get("link", ""),  # type: ignore[union-attr]
            origin=origin_transform(element), axis=axis / np.linalg.norm(axis),
            lower=limit_value("lower"), upper=limit_value("upper"), effort=limit_value("effort"),
            velocity=limit_value("velocity"), mimic=mimic.get("joint") if mimic is not None else None,
        )
        joints[joint.name] = joint
    children = {j.child for j in joints.values()}
    roots = [name for name in links if name not in children]
    if len(roots) != 1:
        raise InputError(urdf_path, "link tree", f"has {len(roots)} root links ({', '.join(roots)})", "connect every link to one root")
    return UrdfModel(root_element.get("name", urdf_path.stem), links, joints, roots[0])
