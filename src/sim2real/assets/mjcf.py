"""URDF -> MJCF (MuJoCo 4) following the mujoco_menagerie conventions, by MjSpec edits only.

MuJoCo's URDF importer builds bodies, joints (limits, damping, actuator force range), inertials
and mimic equalities. It cannot read DAE meshes or ``package://`` URIs, so the URDF given to it has
its geometry removed and every geom is added back through ``mujoco.MjSpec``: visual meshes as one
geom per material part (class ``visual``), collision meshes/primitives (class ``collision``).
Actuators, armature, the ``home`` keyframe and the ``attachment_site`` come from
``configs/{robot}/robot.yaml``. The geoms, their classes and materials are added by
:mod:`sim2real.assets.mjcf_geometry`.
"""

from __future__ import annotations

import fnmatch
import os
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from sim2real.errors import InputError
from sim2real.files import atomic_path, write_text
from sim2real.assets.meshes import BuiltMeshes
from sim2real.assets.mjcf_geometry import _add_default_classes, _add_geometry
from sim2real.assets.robot_config import first_match, read_robot_config

INTEGRATORS = {
    "Euler": mujoco.mjtIntegrator.mjINT_EULER,
    "RK4": mujoco.mjtIntegrator.mjINT_RK4,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
}


def _import_urdf_without_geometry(urdf_path: Path) -> tuple[mujoco.MjSpec, ET.Element]:
    """MuJoCo's URDF importer on the kinematic tree only (geoms are added through MjSpec)."""
    root = ET.parse(urdf_path).getroot()
    stripped = ET.fromstring(ET.tostring(root))
    for link in stripped.findall("link"):
        for kind in ("visual", "collision"):
            for element in link.findall(kind):
                link.remove(element)
    try:
        spec = mujoco.MjSpec.from_string(ET.tostring(stripped, encoding="unicode"))
    except Exception as exc:
        raise InputError(urdf_path, None, f"MuJoCo's URDF importer rejects it ({exc})", "fix the URDF") from exc
    spec.compiler.fusestatic = False  # keep every URDF link (flange, TCP) as a body
    spec.compiler.discardvisual = False
    return spec, root


def build_mjcf(
    urdf_path: str | Path,
    robot_config_path: str | Path,
    meshes: BuiltMeshes,
    out_xml: str | Path,
    out_scene: str | Path,
    *,
    spec_edit: Callable[[mujoco.MjSpec], None] | None = None,
    robot_settings: Mapping[str, Any] | None = None,
) -> None:
    """Build ``out_xml`` (robot) and ``out_scene`` (floor, light, ``<include>`` of the robot).

    ``meshes``: the visual parts and the collision files; each collision file becomes one collision geom.
    ``spec_edit`` is applied last, before saving. ``robot_settings``: robot.yaml's content, when already read
    (:func:`read_robot_config`). Both files are written atomically and only after the model compiles.
    """
    urdf_path, out_xml, out_scene = Path(urdf_path), Path(out_xml), Path(out_scene)
    config = read_robot_config(robot_config_path, robot_settings)
    out_dir = out_xml.parent
    out_dir.mkdir(parents=True, exist_ok=True)

    spec, root = _import_urdf_without_geometry(urdf_path)
    spec.modelname = root.get("name", spec.modelname)
    spec.modelfiledir = str(out_dir.resolve())  # relative mesh paths resolve against the output
    _set_options(spec, config)
    _set_joint_dynamics(spec, root, config, robot_config_path)
    _add_actuators(spec, root, config, robot_config_path)
    _add_attachment_site(spec, config, robot_config_path)
    _add_home_keyframe(spec, config, robot_config_path)  # compiles the geometry-free tree: cheap
    visual_class, collision_class = _add_default_classes(spec)
    _add_geometry(spec, root, urdf_path, meshes.visual, meshes.collision, out_dir, visual_class, collision_class)
    if spec_edit is not None:
        spec_edit(spec)

    try:
        xml = spec.to_xml()  # compiles the model
    except Exception as exc:
        raise InputError(urdf_path, None, f"MuJoCo cannot compile the model ({exc})", "fix the URDF or robot.yaml") from exc
    with atomic_path(out_xml) as tmp:
        tmp.write_text(xml, encoding="utf-8")
        scene_check = out_dir / f".{out_scene.name}.{os.getpid()}.check.xml"
        try:  # the saved files load (relative mesh paths resolve) before anything is replaced
            scene_check.write_text(scene_text(tmp.name), encoding="utf-8")
            # absolute, as the spec's modelfiledir: MuJoCo's mesh cache then knows the files it just compiled
            mujoco.MjModel.from_xml_path(str(scene_check.resolve()))
        finally:
            scene_check.unlink(missing_ok=True)
    write_text(out_scene, scene_text(out_xml.name))


def _set_options(spec: mujoco.MjSpec, config: Mapping) -> None:
    options = config.get("mjcf") or {}
    if "timestep" in options:
        spec.option.timestep = float(options["timestep"])
    if "integrator" in options:
        spec.option.integrator = INTEGRATORS[options["integrator"]]


def _urdf_joints(root: ET.Element) -> dict[str, ET.Element]:
    return {j.get("name", ""): j for j in root.findall("joint")}


def _set_joint_dynamics(spec: mujoco.MjSpec, root: ET.Element, config: Mapping, config_path: str | Path) -> None:
    """URDF damping -> damping, friction -> frictionloss (explicitly, whatever the importer did); armature."""
    armature = config.get("armature") or {}
    for name, joint in _urdf_joints(root).items():
        mj_joint = spec.joint(name)
        if mj_joint is None:
            continue
        dynamics = joint.find("dynamics")
        damping = float(dynamics.get("damping", 0)) if dynamics is not None else 0.0
        friction = float(dynamics.get("friction", 0)) if dynamics is not None else 0.0
        mj_joint.damping = [damping, 0.0, 0.0]  # MuJoCo 4: polynomial damping, linear term first
        mj_joint.frictionloss = friction
        value = first_match(name, armature)
        if value is not None:
            mj_joint.armature = float(value)  # type: ignore[arg-type]


def actuated_joints(root: ET.Element) -> list[str]:
    """Non-fixed joints that are not mimic joints, in URDF order."""
    return [
        j.get("name", "")
        for j in root.findall("joint")
        if j.get("type") in ("revolute", "prismatic", "continuous") and j.find("mimic") is None
    ]


def _add_actuators(spec: mujoco.MjSpec, root: ET.Element, config: Mapping, config_path: str | Path) -> None:
    joints = _urdf_joints(root)
    assigned: dict[str, Mapping] = {}
    for index, entry in enumerate(config.get("actuators") or []):
        matched = [j for j in actuated_joints(root) if fnmatch.fnmatchcase(j, entry["joints"])]
        if not matched:
            raise InputError(
                config_path, f"actuators[{index}].joints '{entry['joints']}'",
                "matches no actuated joint of the URDF", f"use one of: {', '.join(actuated_joints(root))}",
            )
        for j in matched:
            assigned.setdefault(j, entry)
    for name in actuated_joints(root):  # URDF order
        entry = assigned.get(name)
        if entry is None:
            continue
        limit = joints[name].find("limit")
        effort = float(limit.get("effort")) if limit is not None else 0.0  # validated in the URDF stage
        actuator = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        kind = entry["type"]
        if kind == "position":
            actuator.set_to_position(kp=float(entry["kp"]), kv=float(entry.get("kv", 0.0)))
            lower, upper = float(limit.get("lower")), float(limit.get("upper"))  # type: ignore[arg-type,union-attr]
            actuator.ctrlrange = [lower, upper]
        elif kind == "velocity":
            actuator.set_to_velocity(kv=float(entry["kv"]))
            velocity = float(limit.get("velocity", 0.0)) if limit is not None else 0.0
            actuator.ctrlrange = [-velocity, velocity]
        else:
            actuator.set_to_motor()
            gear = float(entry.get("gear", 1.0))
            actuator.gear = [gear, 0, 0, 0, 0, 0]
            actuator.ctrlrange = [-effort / abs(gear), effort / abs(gear)]
        actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        actuator.forcerange = [-effort, effort]
        actuator.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE


def _add_attachment_site(spec: mujoco.MjSpec, config: Mapping, config_path: str | Path) -> None:
    flange = config["flange"]
    body = spec.body(flange)
    if body is None:
        raise InputError(config_path, f"flange '{flange}'", "is not a link of the URDF", "name the tool flange link")
    body.add_site(name="attachment_site", pos=[0, 0, 0], quat=[1, 0, 0, 0], group=5)


def _add_home_keyframe(spec: mujoco.MjSpec, config: Mapping, config_path: str | Path) -> None:
    """``home``: qpos from config (unlisted joints: 0 clipped into range); ctrl holds that pose."""
    home = dict(config.get("home") or {})
    model = spec.compile()
    names = [model.joint(i).name for i in range(model.njnt)]
    unknown = sorted(set(home) - set(names))
    if unknown:
        raise InputError(config_path, f"home: {', '.join(unknown)}", "not joints of the model", f"use: {', '.join(names)}")
    qpos = np.array(model.qpos0, dtype=float)
    for i, name in enumerate(names):
        adr = model.jnt_qposadr[i]
        value = float(home.get(name, 0.0))
        if model.jnt_limited[i]:
            lower, upper = model.jnt_range[i]
            if name in home and not lower <= value <= upper:
                raise InputError(
                    config_path, f"home: {name}", f"{value} is outside the joint range [{lower}, {upper}]",
                    "give a home position inside the limits",
                )
            value = float(np.clip(value, lower, upper))
        qpos[adr] = value
    ctrl = np.zeros(model.nu)
    for a in range(model.nu):
        if model.actuator_biastype[a] != mujoco.mjtBias.mjBIAS_NONE and model.actuator_gainprm[a, 0] > 0:
            ctrl[a] = qpos[model.jnt_qposadr[model.actuator_trnid[a, 0]]]  # position servo: hold the pose
    spec.add_key(name="home", qpos=qpos.tolist(), ctrl=ctrl.tolist())


def scene_text(robot_file: str) -> str:
    """scene.xml: the menagerie scene (sky, checker floor, light) including ``robot_file``."""
    return f"""<mujoco model="scene">
  <include file="{robot_file}"/>

  <statistic center="0.3 0 0.4" extent="1"/>

  <visual>
    <headlight diffuse="0.6 0.6 0.6" ambient="0.3 0.3 0.3" specular="0 0 0"/>
    <rgba haze="0.15 0.25 0.35 1"/>
    <global azimuth="120" elevation="-20"/>
  </visual>

  <asset>
    <texture type="skybox" builtin="gradient" rgb1="0.3 0.5 0.7" rgb2="0 0 0" width="512" height="3072"/>
    <texture type="2d" name="groundplane" builtin="checker" mark="edge" rgb1="0.2 0.3 0.4" rgb2="0.1 0.2 0.3"
      markrgb="0.8 0.8 0.8" width="300" height="300"/>
    <material name="groundplane" texture="groundplane" texuniform="true" texrepeat="5 5" reflectance="0.2"/>
  </asset>

  <worldbody>
    <light pos="0 0 1.5" dir="0 0 -1" directional="true"/>
    <geom name="floor" size="0 0 0.05" type="plane" material="groundplane"/>
  </worldbody>
</mujoco>
"""
