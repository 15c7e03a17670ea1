"""The torque-driven arm built from the MJCF: unmeasured joints welded, one torque motor per measured joint.

The virtual lab (:mod:`sim2real.lab.simulate`) drives it as its "reality", and the gap report's replay
(:mod:`sim2real.report.replay`) as the model, so both drive the robot the same way: ``ctrl`` = joint torque.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np

from sim2real.errors import InputError


def arm_spec(mjcf_path: str | Path, joints: Sequence[str]) -> mujoco.MjSpec:
    """The MJCF as a torque-driven arm: unmeasured joints welded, one motor per measured joint.

    Existing actuators, equalities and tendons are removed (they involve the welded gripper or
    implement position control); contacts are disabled (free-space motion). Used by the lab and by
    the gap report's replay so both drive the robot the same way: ``ctrl`` = joint torque.
    """
    mjcf_path = Path(mjcf_path)
    try:
        spec = mujoco.MjSpec.from_file(str(mjcf_path))
    except Exception as exc:
        raise InputError(mjcf_path, None, f"MuJoCo cannot load it ({exc})", "rebuild the MJCF") from exc
    names = [j.name for j in spec.joints]
    unknown = [j for j in joints if j not in names]
    if unknown:
        raise InputError(mjcf_path, f"joint(s) {', '.join(unknown)}", "not in the MJCF", f"use {', '.join(names)}")
    for actuator in list(spec.actuators):
        spec.delete(actuator)
    for equality in list(spec.equalities):
        spec.delete(equality)
    for tendon in list(spec.tendons):
        spec.delete(tendon)
    for sensor in list(spec.sensors):
        spec.delete(sensor)
    for joint in list(spec.joints):
        if joint.name not in joints:
            spec.delete(joint)
    for key in list(spec.keys):
        spec.delete(key)
    for body in spec.bodies:
        body.gravcomp = 0.0
    for name in joints:
        actuator = spec.add_actuator()
        actuator.name = f"motor_{name}"
        actuator.target = name
        actuator.trntype = mujoco.mjtTrn.mjTRN_JOINT
        actuator.ctrllimited = 0
        actuator.forcelimited = 0
        actuator.set_to_motor()
        spec.joint(name).actfrclimited = 0
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    return spec


def compile_arm(spec: mujoco.MjSpec, joints: Sequence[str]) -> tuple[mujoco.MjModel, np.ndarray, np.ndarray]:
    """Compile; return the model and the qpos/dof indices of the joints in the caller's order."""
    model = spec.compile()
    qadr = np.array([model.jnt_qposadr[model.joint(j).id] for j in joints])
    dadr = np.array([model.jnt_dofadr[model.joint(j).id] for j in joints])
    if model.nq != len(joints) or model.nv != len(joints):
        raise InputError(None, "MJCF", f"arm has nq={model.nq}, nv={model.nv} for {len(joints)} measured joints",
                         "measure every 1-DoF joint of the arm (others are welded)")
    return model, qadr, dadr


def meshes_inert(spec: mujoco.MjSpec) -> bool:
    """Whether the mesh geoms of bodies with an explicit inertia change no number of the arm's motion.

    They do not when contacts are off (``arm_spec``), fluid forces are off (the ellipsoid model reads geoms),
    sleeping is off (it reads ``dof_length``, which the compiler takes from the geoms) and the compiler keeps
    explicit inertias (it then ignores the geoms' masses).
    """
    return bool(spec.option.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
                and not spec.option.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP
                and not spec.option.density and not spec.option.viscosity
                and spec.compiler.inertiafromgeom != mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE)


def drop_inert_meshes(spec: mujoco.MjSpec) -> None:
    """Delete the mesh geoms (and their meshes) that cannot change a number of the arm's motion, the lab's or the
    replay's (:func:`meshes_inert`).

    Loading and processing the meshes is most of a compile (about 1.2 s of 1.3 s on the Panda).
    """
    if not meshes_inert(spec):
        return
    for geom in list(spec.geoms):
        if geom.type == mujoco.mjtGeom.mjGEOM_MESH and geom.parent.explicitinertial:
            spec.delete(geom)
    used = {geom.meshname for geom in spec.geoms}
    for mesh in list(spec.meshes):
        if mesh.name not in used:
            spec.delete(mesh)
