"""Xacro -> validated URDF: the URDF's checks, and the build that expands the Xacro in its sandbox
(:mod:`sim2real.assets.xacro_sandbox`) and validates the result. Mesh URIs are resolved by
:mod:`sim2real.assets.packages`.

Calibration YAML (Xacro argument ``calibration:=<path>``, written by the system-identification
stage; every key optional, values in SI units, frames as in the URDF)::

    joints:                      # per joint: URDF <dynamics>
      panda_joint1:
        damping: 0.12            # viscous, N m s/rad (N s/m for prismatic)
        friction: 0.35           # Coulomb, N m (N)
    links:                       # per link: replaces the nominal <inertial> values given
      panda_link7:
        mass: 0.74               # kg
        com: [0.01, -0.004, 0.06]            # m, in the link frame
        inertia: {ixx: 0.0125, ixy: 0.0, ixz: 0.0, iyy: 0.01, iyz: 0.0, izz: 0.0048}  # kg m^2 at the COM
    payload:                     # a fixed link "payload" (joint "payload_joint") at the flange
      mass: 0.5
      com: [0.0, 0.0, 0.05]      # m, in the flange frame
      inertia: {ixx: 1.0e-3, ixy: 0.0, ixz: 0.0, iyy: 1.0e-3, iyz: 0.0, izz: 1.0e-3}

The flange is ``panda_link8`` (Panda) / ``tool0`` (UR5), see ``robots/common/calibration.xacro``.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim2real.assets.packages import resolve_package_uri
from sim2real.assets.xacro_sandbox import XACRO_LIMITS, run_xacro
from sim2real.errors import InputError
from sim2real.files import atomic_path
from sim2real.forked import Limits

ACTUATED_TYPES = ("revolute", "prismatic", "continuous")
MESH_KINDS = ("visual", "collision")


# --------------------------------------------------------------------------------------------
# Validation


@dataclass(frozen=True)
class MeshRef:
    """One mesh referenced by a link."""

    kind: str  # "visual" | "collision"
    link: str
    uri: str


def mesh_refs(root: ET.Element) -> list[MeshRef]:
    refs = []
    for link in root.findall("link"):
        for kind in MESH_KINDS:
            for element in link.findall(kind):
                mesh = element.find("geometry/mesh")
                if mesh is not None:
                    refs.append(MeshRef(kind, link.get("name", "?"), mesh.get("filename", "")))
    return refs


def mesh_uris(urdf_path: str | Path) -> dict[str, list[str]]:
    """Unique mesh URIs of a URDF per kind ("visual", "collision"), sorted."""
    root = _parse_xml(Path(urdf_path), Path(urdf_path).read_text(encoding="utf-8"))
    out: dict[str, list[str]] = {kind: [] for kind in MESH_KINDS}
    for ref in mesh_refs(root):
        if ref.uri not in out[ref.kind]:
            out[ref.kind].append(ref.uri)
    return {kind: sorted(uris) for kind, uris in out.items()}


def mesh_name(uri: str) -> str:
    """Build name of a mesh: its file stem (unique per kind within a robot)."""
    return Path(uri.rsplit("/", 1)[-1]).stem


def mesh_names(urdf_path: str | Path) -> dict[str, dict[str, str]]:
    """``{kind: {name: uri}}``; two meshes of one kind sharing a stem are an InputError."""
    out: dict[str, dict[str, str]] = {}
    for kind, uris in mesh_uris(urdf_path).items():
        names: dict[str, str] = {}
        for uri in uris:
            name = mesh_name(uri)
            if name in names:
                raise InputError(
                    urdf_path, f"{kind} meshes '{names[name]}' and '{uri}'",
                    f"two {kind} meshes share the file name '{name}'", "rename one of the mesh files",
                )
            names[name] = uri
        out[kind] = names
    return out


def _parse_xml(path: Path, text: str) -> ET.Element:
    try:
        return ET.fromstring(text)
    except ET.ParseError as exc:
        raise InputError(path, f"line {exc.position[0]}", f"is not well-formed XML ({exc})", "fix the XML") from exc


def _float_attr(element: ET.Element | None, name: str, default: float | None = None,
                source: Path | None = None, where: str | None = None) -> float | None:
    """The attribute as a float (``default`` when absent); a non-number is an InputError naming ``where``."""
    if element is None or element.get(name) is None:
        return default
    text = element.get(name, "")
    try:
        return float(text)
    except ValueError:
        raise InputError(source, f"{where} <{element.tag}> {name}", f"'{text}' is not a number",
                         f"write {name} as one decimal number") from None


def check_inertial(link: ET.Element, source: Path) -> None:
    """Mass > 0, inertia symmetric positive definite and obeying the triangle inequality."""
    name = link.get("name", "?")
    inertial = link.find("inertial")
    if inertial is None:
        return  # a massless frame link (flange, TCP) is fine: it is fused or fixed
    where = f"link '{name}' <inertial>"
    mass = _float_attr(inertial.find("mass"), "value", None, source, where)
    if mass is None or not np.isfinite(mass) or mass < 0:
        raise InputError(source, where, f"mass {mass} is not a finite non-negative number", "give a mass in kg >= 0")
    inertia = inertial.find("inertia")
    values = {k: _float_attr(inertia, k, 0.0, source, where) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
    if mass == 0:
        if any(v != 0 for v in values.values()):
            raise InputError(source, where, "zero mass with a non-zero inertia", "give the link its mass, or zero inertia")
        return
    tensor = np.array([
        [values["ixx"], values["ixy"], values["ixz"]],
        [values["ixy"], values["iyy"], values["iyz"]],
        [values["ixz"], values["iyz"], values["izz"]],
    ], dtype=float)
    if not np.all(np.isfinite(tensor)):
        raise InputError(source, where, "inertia has non-finite entries", "give finite ixx..izz in kg m^2")
    principal = np.linalg.eigvalsh(tensor)
    if principal[0] <= 0:
        raise InputError(
            source, where,
            f"inertia is not positive definite (principal moments {np.array2string(principal, precision=6)})",
            "correct ixx..izz (kg m^2 about the COM); all principal moments must be > 0",
        )
    tolerance = 1e-9 * principal[2]
    if principal[0] + principal[1] < principal[2] - tolerance:
        raise InputError(
            source, where,
            f"inertia violates the triangle inequality (principal moments {np.array2string(principal, precision=6)}: "
            f"{principal[0]:.6g} + {principal[1]:.6g} < {principal[2]:.6g})",
            "correct ixx..izz: no rigid body has one principal moment larger than the sum of the other two",
        )


def check_joint(joint: ET.Element, source: Path) -> None:
    """Every actuated joint has an effort limit, and position limits unless continuous."""
    name = joint.get("name", "?")
    jtype = joint.get("type", "")
    if jtype not in ACTUATED_TYPES:
        return
    where = f"joint '{name}' ({jtype})"
    limit = joint.find("limit")
    if limit is None:
        raise InputError(
            source, where, "has no <limit>",
            'add <limit lower="..." upper="..." effort="..." velocity="..."/> with the joint range and torque/force',
        )
    effort = _float_attr(limit, "effort", None, source, where)
    if effort is None or not 0 < effort < math.inf:
        raise InputError(source, where, f"<limit> effort is {effort}", "set a finite effort (N m or N) > 0 in <limit>")
    velocity = _float_attr(limit, "velocity", None, source, where)
    if velocity is not None and not 0 < velocity < math.inf:
        raise InputError(source, where, f"<limit> velocity is {velocity}",
                         "set a finite velocity (rad/s or m/s) > 0 in <limit>, or leave it out")
    if jtype != "continuous":
        lower, upper = _float_attr(limit, "lower", None, source, where), _float_attr(limit, "upper", None, source, where)
        if lower is None or upper is None or not -math.inf < lower < upper < math.inf:
            raise InputError(
                source, where, f"<limit> lower={lower} upper={upper} is not a range",
                "set finite lower < upper in <limit> (rad or m)",
            )


def validate_urdf(urdf_path: str | Path, source: str | Path | None = None) -> None:
    """Validate a URDF file; errors name ``source`` (the Xacro, by default the URDF itself).

    Checks: well-formed; parses with yourdfpy and with Pinocchio; every mesh resolves to an existing
    file; inertias physical; every actuated joint has limits and effort.
    """
    urdf_path = Path(urdf_path)
    source_path = Path(source) if source is not None else urdf_path
    text = urdf_path.read_text(encoding="utf-8")
    root = _parse_xml(source_path, text)
    if root.tag != "robot":
        raise InputError(source_path, f"<{root.tag}>", "root element is not <robot>", "make <robot> the root")

    for ref in mesh_refs(root):
        where = f"link '{ref.link}' <{ref.kind}> mesh"
        if not ref.uri:
            raise InputError(source_path, where, "mesh has no filename", "set filename to a package:// URI")
        path = resolve_package_uri(ref.uri, source=source_path, where=where)
        if not path.is_file():
            raise InputError(
                source_path, where, f"mesh '{ref.uri}' does not exist (resolved to {path})",
                "correct the filename or add the mesh file",
            )
    for link in root.findall("link"):
        check_inertial(link, source_path)
    for joint in root.findall("joint"):
        check_joint(joint, source_path)
    _parse_with_yourdfpy(urdf_path, source_path)
    _parse_with_pinocchio(text, source_path)


def _parse_with_yourdfpy(urdf_path: Path, source: Path) -> None:
    import yourdfpy

    def handler(fname: str) -> str:
        return str(resolve_package_uri(fname, source=source))

    try:
        robot = yourdfpy.URDF.load(
            str(urdf_path), load_meshes=False, build_scene_graph=True, build_collision_scene_graph=False,
            load_collision_meshes=False, filename_handler=handler,
        )
    except Exception as exc:
        raise InputError(source, None, f"yourdfpy cannot parse the URDF ({exc})", "fix the URDF structure") from exc
    if not robot.validate():
        raise InputError(source, None, "yourdfpy reports an invalid URDF", "check links/joints named in the log")


def _parse_with_pinocchio(text: str, source: Path) -> None:
    import pinocchio as pin

    try:
        pin.buildModelFromXML(text)
    except Exception as exc:
        raise InputError(source, None, f"Pinocchio cannot parse the URDF ({exc})", "fix the joint/link tree") from exc


# --------------------------------------------------------------------------------------------
# Build


def build_urdf(xacro_path: str | Path, out_path: str | Path, args: Mapping[str, object] | None = None, *,
               limits: Limits = XACRO_LIMITS) -> None:
    """Expand ``xacro_path`` with ``args`` (e.g. ``{"hand": "true", "calibration": "<yaml>"}``), validate,
    and write ``out_path`` atomically: nothing is written if expansion or validation fails. The Xacro may read the
    files of the robot's packages and the calibration YAML, within ``limits`` (:func:`run_xacro`).

    See the module docstring for the calibration YAML shape.
    """
    xacro_path = Path(xacro_path)
    args = dict(args or {})
    if args.get("calibration"):
        # xacro resolves relative paths against the Xacro file; the caller means the working directory
        calibration = Path(str(args["calibration"])).resolve()
        if not calibration.is_file():
            raise InputError(calibration, None, "calibration file does not exist", "run the sysid stage or correct the path")
        args["calibration"] = str(calibration)
    allowed = (str(args["calibration"]),) if args.get("calibration") else ()
    text = run_xacro(xacro_path, args, allowed=allowed, limits=limits)
    with atomic_path(out_path) as tmp:
        tmp.write_text(text, encoding="utf-8")
        validate_urdf(tmp, source=xacro_path)
