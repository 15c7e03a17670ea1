"""Xacro -> validated URDF, and resolution of ``package://`` mesh URIs.

The built URDF keeps ``package://`` URIs (no absolute path reaches an output); validation resolves
them with :func:`resolve_package_uri`, the one place that knows where packages live.

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

import os
import sys
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.errors import InputError
from sim2real.files import atomic_path
from sim2real.forked import ChildGaveNoAnswer, Limits, TimeLimit, call_limited

PROJECT_ROOT = Path(__file__).resolve().parents[3]
PACKAGE_PREFIX = "package://"
ACTUATED_TYPES = ("revolute", "prismatic", "continuous")
MESH_KINDS = ("visual", "collision")


# --------------------------------------------------------------------------------------------
# package:// resolution


def package_search_dirs(robots_dir: str | Path | None = None) -> list[Path]:
    """Directories that may hold a package, in search order.

    1. ``<site-packages>/cmeel.prefix/share`` (example-robot-data installs there),
    2. the project's ``robots/`` directory (``package://panda/...`` = ``robots/panda/...``),
    3. every entry of ``ROS_PACKAGE_PATH``.
    """
    dirs: list[Path] = []
    for entry in sys.path:
        share = Path(entry or ".") / "cmeel.prefix" / "share"
        if share.is_dir() and share.resolve() not in dirs:
            dirs.append(share.resolve())
    dirs.append(Path(robots_dir) if robots_dir is not None else PROJECT_ROOT / "robots")
    for entry in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep):
        if entry:
            dirs.append(Path(entry))
    return dirs


def resolve_package_uri(
    uri: str,
    *,
    source: str | Path | None = None,
    where: str | None = None,
    robots_dir: str | Path | None = None,
) -> Path:
    """Absolute path of ``package://NAME/rel`` (or of a plain relative/absolute path).

    A package that no search directory holds is an :class:`InputError` naming ``source``/``where``.
    The file itself need not exist (callers check that, to give their own message).
    """
    if not uri.startswith(PACKAGE_PREFIX):
        if uri.startswith("file://"):
            uri = uri[len("file://"):]
        path = Path(uri)
        if not path.is_absolute() and source is not None:
            path = Path(source).parent / path
        return path
    package, _, relative = uri[len(PACKAGE_PREFIX):].partition("/")
    searched = package_search_dirs(robots_dir)
    for base in searched:
        candidate = base / package
        if candidate.is_dir():
            return candidate / relative
    raise InputError(
        source,
        where,
        f"unknown package '{package}' in '{uri}' (searched {', '.join(str(d) for d in searched)})",
        "use package://example-robot-data/... for the example-robot-data meshes, put the package under "
        "robots/, or add its parent directory to ROS_PACKAGE_PATH",
    )


# --------------------------------------------------------------------------------------------
# Xacro


# A pull request's Xacro runs in the untrusted CI job: it is expanded in a child process held to these limits (a
# robot's Xacro takes well under a second and tens of MB), and may read only files of the robot's packages.
XACRO_LIMITS = Limits(seconds=60.0, memory_bytes=1024 * 2**20)


def xacro_roots(xacro_path: str | Path) -> list[Path]:
    """The directories a Xacro may read from (its includes, its ``xacro.load_yaml``): the one holding its own
    package (``robots/`` for ``robots/<name>/<name>.urdf.xacro``) and every package search directory
    (:func:`package_search_dirs`), symlinks resolved."""
    roots = [Path(xacro_path).resolve().parent.parent, *package_search_dirs()]
    return list(dict.fromkeys(Path(os.path.realpath(root)) for root in roots))


def run_xacro(xacro_path: str | Path, args: Mapping[str, object] | None = None, *,
              allowed: tuple[str | Path, ...] = (), limits: Limits = XACRO_LIMITS) -> str:
    """Expand a Xacro file to URDF text in a child process held to ``limits``; it may read files under
    :func:`xacro_roots` and the files ``allowed`` (a calibration YAML). A Xacro error, a file outside, or a limit
    reached becomes one InputError naming the file and the element."""
    xacro_path = Path(xacro_path)
    if not xacro_path.exists():
        raise InputError(xacro_path, None, "Xacro file does not exist", "create it or correct the path")
    mappings = {str(k): ("" if v is None else _xacro_arg(v)) for k, v in (args or {}).items()}
    readable = (tuple(xacro_roots(xacro_path)), frozenset(Path(os.path.realpath(f)) for f in allowed))
    try:
        return call_limited(_expand_xacro, xacro_path, mappings, readable, limits, limits=limits)
    except ChildGaveNoAnswer as exc:
        problem = (f"expanding it ran past its time limit of {limits.seconds:g} s" if exc.timed_out else
                   f"expanding it ended without an answer (exit code {exc.exitcode}; its memory limit is "
                   f"{limits.memory_bytes / 2**20:.0f} MB)")
        raise InputError(xacro_path, "Xacro expansion", problem, XACRO_LIMIT_FIX) from None


XACRO_LIMIT_FIX = ("bound the macro recursion (a macro that calls itself until a condition) and the ranges and "
                   "repetitions of ${...} expressions")


def _expand_xacro(xacro_path: Path, mappings: Mapping[str, str], readable: tuple[tuple[Path, ...], frozenset[Path]],
                  limits: Limits) -> str:
    """The child's work (:func:`run_xacro`): xacro reads through :func:`_reading_within`; what stops it becomes an
    InputError naming the file xacro was in and the macro it was expanding."""
    import xacro  # imported lazily: xacro keeps global state, keep it out of module import

    xacro.all_includes = []
    xacro.filestack = []
    try:
        # xacro's module namespace is searched before the builtins: every file it opens (its parse of an include,
        # its load_yaml) passes the check; where the work runs in a child, the child's copy of the module is patched.
        xacro.open = _reading_within(*readable, xacro)
        return _urdf_text(xacro.process_file(str(xacro_path), mappings=mappings), xacro_path)
    except (Exception, TimeLimit) as exc:  # xacro: XacroException, NameError...; the limits: TimeLimit, MemoryError
        raise _xacro_error(exc, xacro_path, xacro, limits) from None
    finally:
        vars(xacro).pop("open", None)


def _urdf_text(doc: Any, xacro_path: Path) -> str:
    """The expanded document as the URDF's text, with sim2real's banner for xacro's (which names the input path,
    so that the output does not depend on where it ran)."""
    for node in list(doc.childNodes):
        if node.nodeType == node.COMMENT_NODE:
            doc.removeChild(node)
    root = doc.documentElement
    for node in list(root.childNodes):
        if node.nodeType == node.COMMENT_NODE:
            root.removeChild(node)
    text = doc.toprettyxml(indent="  ")
    lines = [line for line in text.splitlines() if line.strip()]
    banner = f"<!-- Generated by sim2real from {xacro_path.name}; do not edit (edit the Xacro). -->"
    return "\n".join([lines[0], banner, *lines[1:]]) + "\n"


def _reading_within(roots: tuple[Path, ...], allowed: frozenset[Path], xacro: Any) -> Callable[..., Any]:
    """xacro's ``open``: a file under ``roots`` or ``allowed`` (symlinks resolved) opens; any other is an InputError
    naming the element that reads it, told by xacro's caller: its parse of an include or its load_yaml."""
    def open_within(file: str, *args: Any, **kwargs: Any) -> Any:
        real = Path(os.path.realpath(file))
        if real in allowed or any(real.is_relative_to(root) for root in roots):
            return open(file, *args, **kwargs)
        stack = [str(f) for f in xacro.filestack if f]
        if sys._getframe(1).f_code.co_name == "load_yaml":
            source, element = stack[-1], f"xacro.load_yaml('{file}')"
        elif len(stack) > 1:
            source, element = stack[-2], f'<xacro:include filename="{stack[-1]}">'
        else:
            source, element = file, "the Xacro file itself"
        raise InputError(source, element, f"reads {real}, outside the robot's package roots "
                         f"({', '.join(map(str, roots))})",
                         "read only files of the robot's packages (its folder under robots/, robots/common, "
                         "example-robot-data's share directory, ROS_PACKAGE_PATH); copy the file there")
    return open_within


def _cause(exc: BaseException, kind: type[BaseException] | tuple[type[BaseException], ...]) -> BaseException | None:
    """The exception of ``kind`` that ``exc`` is or wraps (xacro keeps the wrapped one in ``exc``)."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        if isinstance(current, kind):
            return current
        seen.add(id(current))
        current = getattr(current, "exc", None) or current.__cause__ or current.__context__
    return None


def _xacro_error(exc: BaseException, xacro_path: Path, xacro: Any, limits: Limits) -> InputError:
    """What stopped xacro, as one InputError line: a file read outside, a limit reached, or xacro's own error, in
    the file it was in and the macro it was expanding."""
    refused = _cause(exc, InputError)
    if isinstance(refused, InputError):
        return refused
    stack = [str(f) for f in (getattr(xacro, "filestack", None) or []) if f]
    failing = stack[-1] if stack else str(xacro_path)
    macros = getattr(xacro, "macrostack", None) or []
    name = macros[-1].body.getAttribute("name") if macros and macros[-1].body is not None else ""
    where = f"macro '{name}'" if name else "Xacro expansion"  # the macro xacro was expanding, as xacro names it
    if _cause(exc, TimeLimit) is not None:
        return InputError(failing, where, f"expanding it ran past its time limit of {limits.seconds:g} s",
                          XACRO_LIMIT_FIX)
    if _cause(exc, MemoryError) is not None:
        return InputError(failing, where, f"expanding it ran past its memory limit of "
                          f"{limits.memory_bytes / 2**20:.0f} MB", XACRO_LIMIT_FIX)
    return InputError(failing, where, f"Xacro cannot expand it: {' '.join(str(exc).split())}",
                      "fix the ${...} expression, macro call or argument named above")


def _xacro_arg(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


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
