"""The nominal model the fit starts from: the URDF's rigid bodies with the MJCF armature, what the effects
need to know of it (bodies, flange, CAD inertials, collision-mesh ellipsoids and hulls), and the body
side's signals (:func:`make_signals`)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from sim2real.identification.inertial.bands import InertiaBands
from sim2real.assets.dynamics import RigidBodyModel
from sim2real.assets.robot_config import first_match
from sim2real.identification.effects import Signals
from sim2real.errors import InputError
from sim2real.cache import FitCache, digest
from sim2real.identification.fitting.data import TorqueData, link_side


def resolve_armature(patterns: Mapping[str, float] | None, joint_names: Sequence[str]) -> dict[str, float]:
    """robot.yaml ``armature`` (joint name or glob -> value; first match wins) per joint."""
    out: dict[str, float] = {}
    for joint in joint_names:
        value = first_match(joint, patterns or {})
        if value is not None:
            out[joint] = float(value)
    return out


def _urdf_link_parameters(urdf_path: Path) -> dict[str, np.ndarray]:
    """Each URDF link's own dynamic parameters (Pinocchio order, about the link frame)."""
    out: dict[str, np.ndarray] = {}
    root = ET.parse(urdf_path).getroot()
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        mass = float(inertial.find("mass").get("value", "0"))
        origin = inertial.find("origin")
        xyz = np.array([float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()])
        rpy = np.array([float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()])
        el = inertial.find("inertia")
        get = lambda k: float(el.get(k, "0")) if el is not None else 0.0  # noqa: E731
        inertia = np.array(
            [[get("ixx"), get("ixy"), get("ixz")], [get("ixy"), get("iyy"), get("iyz")], [get("ixz"), get("iyz"), get("izz")]]
        )
        rotation = pin.rpy.rpyToMatrix(rpy)
        out[link.get("name")] = pin.Inertia(mass, xyz, rotation @ inertia @ rotation.T).toDynamicParameters()
    return out


@dataclass(frozen=True)
class _MeshPart:
    """One collision shape of a link: its mesh file (or, for a URDF primitive, ``primitive``: its tag and sizes),
    and the scale and placement the URDF gives it."""

    path: Path | None
    scale: tuple[float, float, float]
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    primitive: tuple[str, tuple[float, ...]] | None = None


# A URDF primitive's sizes, in the order trimesh.creation takes them: box extents, cylinder radius and length,
# sphere radius.
_PRIMITIVE_SIZES = {"box": ("size",), "cylinder": ("radius", "length"), "sphere": ("radius",)}


def _primitive(geometry: ET.Element) -> tuple[str, tuple[float, ...]] | None:
    """A collision's primitive (tag, sizes), None when it is none of box, cylinder, sphere."""
    for tag, keys in _PRIMITIVE_SIZES.items():
        shape = geometry.find(tag)
        if shape is not None:
            return tag, tuple(float(v) for key in keys for v in shape.get(key, "0").split())
    return None


def _collision_meshes(urdf_path: Path, link: ET.Element) -> list[_MeshPart] | None:
    """A link's collision shapes as the URDF names them: meshes and primitives (an arm written with cylinders has
    hulls as one written with meshes); None when a shape can be neither read nor made."""
    from sim2real.assets.urdf import resolve_package_uri

    def triple(element: ET.Element | None, key: str, default: str) -> tuple[float, float, float]:
        x, y, z = (float(v) for v in (element.get(key, default) if element is not None else default).split())
        return (x, y, z)

    parts = []
    for collision in link.findall("collision"):
        origin = collision.find("origin")
        placement = (triple(origin, "xyz", "0 0 0"), triple(origin, "rpy", "0 0 0"))
        mesh = collision.find("geometry/mesh")
        if mesh is None:
            geometry = collision.find("geometry")
            primitive = _primitive(geometry) if geometry is not None else None
            if primitive is None:
                return None
            parts.append(_MeshPart(None, (1.0, 1.0, 1.0), *placement, primitive=primitive))
            continue
        try:
            path = Path(resolve_package_uri(mesh.get("filename", ""), source=urdf_path))
        except Exception:  # noqa: BLE001 - an unresolvable mesh only drops the optional, stronger constraint
            return None
        parts.append(_MeshPart(path, triple(mesh, "scale", "1 1 1"), *placement))
    return parts


def _part_vertices(part: _MeshPart) -> np.ndarray:
    """A shape's vertices in its own frame: the mesh file's (a glTF turned Z-up, as the assets place it), or the
    primitive's surface (a cylinder of 32 sides inside the true one by 0.5 % of its radius at most, a sphere of 162
    vertices by 1.8 %)."""
    import trimesh

    from sim2real.assets.meshes import urdf_mesh

    if part.primitive is None:
        return np.asarray(urdf_mesh(part.path).vertices)
    tag, sizes = part.primitive
    if tag == "box":
        made = trimesh.creation.box(extents=sizes)
    elif tag == "cylinder":
        made = trimesh.creation.cylinder(radius=sizes[0], height=sizes[1], sections=32)
    else:
        made = trimesh.creation.icosphere(subdivisions=2, radius=sizes[0])
    return np.asarray(made.vertices)


def _collision_points(parts: Sequence[_MeshPart] | None) -> np.ndarray | None:
    """Vertices of a link's collision shapes in the link frame (None when a mesh cannot be read)."""
    if parts is None:
        return None
    points = []
    for part in parts:
        try:
            vertices = _part_vertices(part)
        except Exception:  # noqa: BLE001 - an unreadable mesh only drops the optional, stronger constraint
            return None
        points.append(vertices * np.asarray(part.scale) @ pin.rpy.rpyToMatrix(np.asarray(part.rpy)).T
                      + np.asarray(part.xyz))
    return np.vstack(points) if points else None


def _body_meshes(urdf_path: Path, body_links: Sequence[str]) -> list[list[_MeshPart] | None]:
    """Collision meshes of each body's own link; None for the last body (it carries tools and payloads, so
    its mass may lie outside its meshes) and where a link has no mesh."""
    root = ET.parse(urdf_path).getroot()
    links = {link.get("name"): link for link in root.findall("link")}
    return [
        _collision_meshes(urdf_path, links[name]) if name in links and index < len(body_links) - 1 else None
        for index, name in enumerate(body_links)
    ]


def _body_points(urdf_path: Path, body_links: Sequence[str]) -> list[np.ndarray | None]:
    """Collision-mesh vertices of each body's own link (link frame), as :func:`_body_meshes` names them."""
    return [_collision_points(parts) for parts in _body_meshes(urdf_path, body_links)]


def _mesh_bounds(urdf_path: Path, body_links: Sequence[str]) -> tuple[list[np.ndarray | None], list[np.ndarray | None]]:
    """Each body's bounding ellipsoid and convex hull (:func:`body_ellipsoids`, :func:`body_hulls`); the meshes
    are read once for both."""
    points = _body_points(urdf_path, body_links)
    return body_ellipsoids(urdf_path, body_links, points), body_hulls(urdf_path, body_links, points)


def _mesh_contents(urdf_path: Path, body_links: Sequence[str]) -> list[Any]:
    """What the bodies' bounds depend on: the meshes' bytes and placements (a missing file as its name)."""
    out: list[Any] = []
    for parts in _body_meshes(urdf_path, body_links):
        for part in parts or []:
            if part.path is None:
                out.append((part.xyz, part.rpy, part.primitive))
                continue
            out.append((part.scale, part.xyz, part.rpy,
                        part.path.read_bytes() if part.path.is_file() else f"missing:{part.path.name}"))
        out.append(parts is None)
    return out


def body_ellipsoids(
    urdf_path: Path, body_links: Sequence[str], points: Sequence[np.ndarray | None] | None = None
) -> list[np.ndarray | None]:
    """Bounding ellipsoid (``sim2real.identification.inertial`` Q form) of each body's own link, from its collision meshes.

    The last body gets none: tools and payloads are mounted there, so its mass may lie outside its meshes.
    ``points``: the bodies' mesh vertices when already read (:func:`_body_points`).
    """
    from sim2real.identification.inertial import bounding_ellipsoid

    points = _body_points(urdf_path, body_links) if points is None else points
    return [bounding_ellipsoid(p) if p is not None and len(p) >= 4 else None for p in points]


def body_hulls(
    urdf_path: Path, body_links: Sequence[str], points: Sequence[np.ndarray | None] | None = None
) -> list[np.ndarray | None]:
    """Convex hull of each body's own collision meshes as facet equations ``(k, 4)``: ``n . x + d <= 0``
    inside, ``n`` a unit outward normal (link frame). None where :func:`body_ellipsoids` has none (the
    last body) or the vertices span no volume. Qhull on a few hundred vertices: ~1 ms a body."""
    from scipy.spatial import ConvexHull, QhullError

    points = _body_points(urdf_path, body_links) if points is None else points
    out: list[np.ndarray | None] = []
    for p in points:
        try:
            out.append(np.asarray(ConvexHull(np.asarray(p, dtype=float)).equations) if p is not None and len(p) >= 4
                       else None)
        except (QhullError, ValueError):  # flat or degenerate meshes: no volume to be inside of
            out.append(None)
    return out


@dataclass
class MeshBounds:
    """Each body's bounding ellipsoid and convex hull from its collision meshes (:func:`body_ellipsoids`,
    :func:`body_hulls`), read when first asked for: only the link inertias' fit and plausibility use them, and
    reading the meshes costs trimesh's import and about 0.1 s. ``content``: the digest of the URDF and the
    meshes, what the bounds follow from (and all a digest of the model sees of them)."""

    content: str
    body_links: list[str]
    _urdf_path: Path
    _bounds: tuple[list[np.ndarray | None], list[np.ndarray | None]] | None = None

    @property
    def ellipsoids(self) -> list[np.ndarray | None]:
        return self._read()[0]

    @property
    def hulls(self) -> list[np.ndarray | None]:
        return self._read()[1]

    def _read(self) -> tuple[list[np.ndarray | None], list[np.ndarray | None]]:
        if self._bounds is None:
            self._bounds = _mesh_bounds(self._urdf_path, self.body_links)
        return self._bounds


@dataclass
class NominalModel:
    """The URDF model the fit starts from and everything effects need to know about it."""

    dynamics: RigidBodyModel
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def joint_names(self) -> list[str]:
        return self.dynamics.joint_names


def load_nominal(
    urdf_path: str | Path,
    joint_names: Sequence[str],
    armature: Mapping[str, float] | None = None,
    flange: str | None = None,
    cache: FitCache | None = None,
    inertia_bands: InertiaBands | None = None,
) -> NominalModel:
    """Nominal model of the measured joints. ``armature``: robot.yaml patterns (the MJCF's armature);
    ``cache``: the bodies' mesh bounds (:class:`MeshBounds`) are read back from it, or read from the meshes and
    kept there, now (before the fit forks its workers); without one they are read when first asked for.
    ``inertia_bands``: how far the link inertias may move from CAD (default: :class:`InertiaBands`' defaults)."""
    urdf_path = Path(urdf_path)
    dynamics = RigidBodyModel(urdf_path, joint_names, armature=resolve_armature(armature, joint_names))
    model = dynamics.model
    # Moving body of each joint (tree order) = the URDF child link of that joint.
    body_links = []
    for jid in range(1, model.njoints):
        links = [f.name for f in model.frames if f.parentJoint == jid and f.type == pin.FrameType.BODY]
        body_links.append(links[0] if links else model.names[jid])
    last_joint = model.njoints - 1
    flange_name = flange if flange and model.existFrame(flange) else body_links[-1]
    placement = model.frames[model.getFrameId(flange_name)].placement
    if model.frames[model.getFrameId(flange_name)].parentJoint != last_joint:
        raise InputError(
            urdf_path, f"flange '{flange_name}'", "is not carried by the last measured joint",
            "set robot.yaml flange to a link fixed to the last arm link",
        )
    bounds = MeshBounds(digest(urdf_path.read_bytes(), body_links, _mesh_contents(urdf_path, body_links)),
                        body_links, urdf_path)
    if cache is not None and cache.directory is not None:
        bounds._bounds = cache.get_or_compute("mesh_bounds", cache.key(bounds), bounds._read)
    info = {
        "damping": dynamics.damping.copy(),
        "friction": dynamics.friction.copy(),
        "armature": dynamics.armature.copy(),
        "inertial": dynamics.inertial_parameters(),
        "body_links": body_links,
        "n_bodies": model.njoints - 1,
        "last_link": body_links[-1],
        "flange": flange_name,
        "flange_rotation": np.asarray(placement.rotation).copy(),
        "flange_translation": np.asarray(placement.translation).copy(),
        "link_own_inertial": _urdf_link_parameters(urdf_path),
        "mesh_bounds": bounds,  # where a body's mass and COM may plausibly lie (link_inertia)
        "inertia_bands": inertia_bands or InertiaBands(),  # how far from CAD (robot.yaml inertia_bands)
    }
    return NominalModel(dynamics, info)


def make_signals(nominal: NominalModel, data: TorqueData) -> Signals:
    """The body side's signals: the judged torque predicted from the motion by the nominal model.

    A link-side sensor measures what the links need, without the drive's rotor inertia, damping and
    friction (those lie on the drive side, :func:`sim2real.identification.sides.drive_signals`).
    """
    dynamics = nominal.dynamics
    tau_nominal = dynamics.inverse_dynamics(data.q, data.qd, data.qdd)
    info = nominal.info
    if link_side(data):
        tau_nominal = tau_nominal - dynamics.drive_torque(data.qd, data.qdd)
        # A drive effect found here acts after the sensor: it starts from nothing, not from the URDF's value.
        info = {**info, **{key: np.zeros_like(np.asarray(info[key], dtype=float))
                           for key in ("damping", "friction", "armature") if key in info}}
    return Signals(
        joint_names=list(data.joint_names), time=data.time, q=data.q, qd=data.qd, qdd=data.qdd,
        tau_nominal=tau_nominal, segments=data.segments, tau=data.tau,
        regressor_fn=lambda: dynamics.regressor(data.q, data.qd, data.qdd), nominal=info,
        gravity_fn=lambda: dynamics.unit_gravity(data.q),
    )

