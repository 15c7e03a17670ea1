"""Cross-format equivalence: the URDF, the MJCF and the USD describe the same robot.

Each format is read with its own library (XML for the URDF, MuJoCo for the MJCF, pxr for the USD) into
one neutral shape in SI units and radians; the comparison then names every joint or link where they
differ. Unit conversions checked on the way: USD revolute limits are degrees, USD angular drive gains
are per degree, MuJoCo's are per radian.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from sim2real.errors import InputError
from sim2real.files import write_json
from sim2real.assets.urdf_model import RAD_PER_DEG, read_urdf

REL_TOL = 1e-5  # USD stores float32: ~7 significant digits
ABS_TOL = 1e-9


@dataclass
class RobotFacts:
    """What the three formats must agree on, in SI units and radians."""

    joints: list[str] = field(default_factory=list)  # 1-DoF joints, in file order
    joint_types: dict[str, str] = field(default_factory=dict)  # revolute | prismatic
    limits: dict[str, tuple[float, float] | None] = field(default_factory=dict)
    masses: dict[str, float] = field(default_factory=dict)  # links with mass > 0
    coms: dict[str, list[float]] = field(default_factory=dict)
    inertias: dict[str, list[list[float]]] = field(default_factory=dict)  # about the CoM, link axes
    gains: dict[str, tuple[float, float]] = field(default_factory=dict)  # kp, kv per rad (or per m)


def urdf_facts(urdf_path: str | Path, gains: Mapping[str, tuple[float, float]] | None = None) -> RobotFacts:
    model = read_urdf(urdf_path)
    facts = RobotFacts()
    for joint in model.joints.values():
        if joint.type == "fixed":
            continue
        facts.joints.append(joint.name)
        facts.joint_types[joint.name] = "prismatic" if joint.type == "prismatic" else "revolute"
        limited = joint.type != "continuous" and joint.lower is not None and joint.upper is not None
        facts.limits[joint.name] = (float(joint.lower), float(joint.upper)) if limited else None  # type: ignore[arg-type]
    for link in model.links.values():
        if link.mass > 0:
            facts.masses[link.name] = link.mass
            facts.coms[link.name] = link.com.tolist()
            facts.inertias[link.name] = link.inertia.tolist()
    facts.gains = dict(gains or {})
    return facts


def mjcf_facts(mjcf_path: str | Path) -> RobotFacts:
    try:
        model = mujoco.MjModel.from_xml_path(str(mjcf_path))
    except Exception as exc:  # MuJoCo raises ValueError with the compiler message
        raise InputError(mjcf_path, None, f"MuJoCo cannot load it ({exc})", "rebuild the MJCF") from exc
    facts = RobotFacts()
    for j in range(model.njnt):
        kind = int(model.jnt_type[j])
        if kind not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            continue
        name = model.joint(j).name
        facts.joints.append(name)
        facts.joint_types[name] = "revolute" if kind == int(mujoco.mjtJoint.mjJNT_HINGE) else "prismatic"
        facts.limits[name] = tuple(float(v) for v in model.jnt_range[j]) if model.jnt_limited[j] else None  # type: ignore[assignment]
    for b in range(1, model.nbody):
        if model.body_mass[b] <= 0:
            continue
        name = model.body(b).name
        facts.masses[name] = float(model.body_mass[b])
        facts.coms[name] = model.body_ipos[b].tolist()
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, model.body_iquat[b])
        rotation = rotation.reshape(3, 3)
        facts.inertias[name] = (rotation @ np.diag(model.body_inertia[b]) @ rotation.T).tolist()
    for a in range(model.nu):
        if int(model.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
            continue
        joint = model.joint(model.actuator_trnid[a, 0]).name
        if int(model.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_AFFINE) and model.actuator_gainprm[a, 0] > 0:
            kp = float(model.actuator_gainprm[a, 0])
            if not math.isclose(-model.actuator_biasprm[a, 1], kp, rel_tol=1e-12):
                continue  # not a position servo
            facts.gains[joint] = (kp, float(-model.actuator_biasprm[a, 2]))
        elif int(model.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_AFFINE):  # velocity servo: gain kv, bias -kv*qd
            facts.gains[joint] = (0.0, float(-model.actuator_biasprm[a, 2]))
        else:
            facts.gains[joint] = (0.0, 0.0)  # motor
    return facts


def usd_facts(usd_path: str | Path) -> RobotFacts:
    from pxr import Gf, Usd, UsdPhysics

    stage = Usd.Stage.Open(str(usd_path))
    if stage is None:
        raise InputError(usd_path, None, "pxr cannot open it", "rebuild the USD")
    facts = RobotFacts()
    for prim in stage.Traverse():
        name = prim.GetName()
        if prim.IsA(UsdPhysics.RevoluteJoint) or prim.IsA(UsdPhysics.PrismaticJoint):
            revolute = prim.IsA(UsdPhysics.RevoluteJoint)
            joint = UsdPhysics.RevoluteJoint(prim) if revolute else UsdPhysics.PrismaticJoint(prim)
            facts.joints.append(name)
            facts.joint_types[name] = "revolute" if revolute else "prismatic"
            to_si = RAD_PER_DEG if revolute else 1.0
            lower, upper = joint.GetLowerLimitAttr(), joint.GetUpperLimitAttr()
            if lower.HasAuthoredValue() and upper.HasAuthoredValue():
                facts.limits[name] = (float(lower.Get()) * to_si, float(upper.Get()) * to_si)
            else:
                facts.limits[name] = None
            instance = "angular" if revolute else "linear"
            if prim.HasAPI(UsdPhysics.DriveAPI, instance):
                drive = UsdPhysics.DriveAPI(prim, instance)
                # USD angular gains are per degree: N m/deg = (N m/rad) * pi/180
                facts.gains[name] = (float(drive.GetStiffnessAttr().Get()) / to_si, float(drive.GetDampingAttr().Get()) / to_si)
        if prim.HasAPI(UsdPhysics.MassAPI):
            mass_api = UsdPhysics.MassAPI(prim)
            mass = float(mass_api.GetMassAttr().Get())
            if mass <= 0:
                continue
            facts.masses[name] = mass
            facts.coms[name] = [float(v) for v in mass_api.GetCenterOfMassAttr().Get()]
            moments = np.array(mass_api.GetDiagonalInertiaAttr().Get(), dtype=float)
            rotation = np.array(Gf.Matrix3d(Gf.Rotation(mass_api.GetPrincipalAxesAttr().Get())).GetTranspose(), dtype=float)
            facts.inertias[name] = (rotation @ np.diag(moments) @ rotation.T).tolist()
    return facts


def _close(a: Any, b: Any) -> bool:
    if a is None or b is None:
        return a is None and b is None
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape:
        return False
    scale = max(float(np.max(np.abs(a))), float(np.max(np.abs(b))), 0.0)
    return bool(np.all(np.abs(a - b) <= ABS_TOL + REL_TOL * scale))


def compare(reference: RobotFacts, others: Mapping[str, RobotFacts], reference_name: str = "urdf") -> list[str]:
    """Mismatches between ``reference`` and every other format, each naming the joint or link."""
    problems: list[str] = []
    for fmt, facts in others.items():
        if facts.joints != reference.joints:
            problems.append(f"{fmt}: joint names/order {facts.joints} differ from the {reference_name}'s {reference.joints}")
        for joint in reference.joints:
            if joint not in facts.joints:
                continue
            if facts.joint_types.get(joint) != reference.joint_types[joint]:
                problems.append(f"{fmt}: joint '{joint}' is {facts.joint_types.get(joint)}, {reference_name} says {reference.joint_types[joint]}")
            if not _close(facts.limits.get(joint), reference.limits[joint]):
                problems.append(f"{fmt}: joint '{joint}' limits {facts.limits.get(joint)} != {reference_name} {reference.limits[joint]} (rad or m)")
        if set(facts.masses) != set(reference.masses):
            missing = sorted(set(reference.masses) - set(facts.masses))
            extra = sorted(set(facts.masses) - set(reference.masses))
            problems.append(f"{fmt}: links with mass differ (missing {missing}, extra {extra})")
        for link, mass in reference.masses.items():
            if link not in facts.masses:
                continue
            if not _close(facts.masses[link], mass):
                problems.append(f"{fmt}: link '{link}' mass {facts.masses[link]} != {reference_name} {mass}")
            if not _close(facts.coms[link], reference.coms[link]):
                problems.append(f"{fmt}: link '{link}' center of mass {facts.coms[link]} != {reference_name} {reference.coms[link]}")
            if not _close(facts.inertias[link], reference.inertias[link]):
                problems.append(f"{fmt}: link '{link}' inertia {facts.inertias[link]} != {reference_name} {reference.inertias[link]}")
    return problems


def check_equivalence(
    urdf_path: str | Path, mjcf_path: str | Path, usd_path: str | Path, out_json: str | Path | None = None
) -> dict[str, Any]:
    """Compare URDF, MJCF and USD; write ``out_json`` only when they agree, else raise naming the mismatch.

    Drive gains have no URDF counterpart: the MJCF actuators are the reference for the USD drives.
    """
    urdf, mjcf, usd = urdf_facts(urdf_path), mjcf_facts(mjcf_path), usd_facts(usd_path)
    problems = compare(urdf, {"mjcf": mjcf, "usd": usd})
    if set(usd.gains) != set(mjcf.gains):
        problems.append(f"usd: driven joints {sorted(usd.gains)} != mjcf actuated joints {sorted(mjcf.gains)}")
    for joint, (kp, kv) in mjcf.gains.items():
        if joint in usd.gains and not _close(usd.gains[joint], (kp, kv)):
            problems.append(
                f"usd: joint '{joint}' drive stiffness/damping {usd.gains[joint]} (converted to per rad) != mjcf actuator kp/kv {(kp, kv)}"
            )
    if problems:
        raise InputError(usd_path, "cross-format equivalence", "; ".join(problems), "rebuild the formats from the same URDF and robot.yaml")
    report = {
        "formats": {"urdf": Path(urdf_path).name, "mjcf": Path(mjcf_path).name, "usd": Path(usd_path).name},
        "tolerance": {"relative": REL_TOL, "absolute": ABS_TOL},
        "joints": [
            {
                "name": joint,
                "type": urdf.joint_types[joint],
                "limits": urdf.limits[joint],
                "usd_limits_usd_units": (
                    [round(v / RAD_PER_DEG, 6) for v in urdf.limits[joint]] if urdf.limits[joint] and urdf.joint_types[joint] == "revolute"
                    else urdf.limits[joint]
                ),
            }
            for joint in urdf.joints
        ],
        "links": {link: {"mass": mass, "com": urdf.coms[link]} for link, mass in urdf.masses.items()},
        "drives": {
            joint: {"kp": kp, "kv": kv, "usd_stiffness": usd.gains[joint][0] * (RAD_PER_DEG if urdf.joint_types[joint] == "revolute" else 1.0),
                    "usd_damping": usd.gains[joint][1] * (RAD_PER_DEG if urdf.joint_types[joint] == "revolute" else 1.0)}
            for joint, (kp, kv) in mjcf.gains.items()
        },
        "checked": ["joint names and order", "joint types", "limits", "link masses", "centers of mass", "inertia tensors", "drive gains"],
        "equivalent": True,
    }
    if out_json is not None:
        write_json(out_json, report)
    return report


# ------------------------------------------------------------------------------ dynamic equivalence


@dataclass
class HoldTrajectory:
    """Joint positions (rows: samples every ``sample_dt`` seconds) of an arm holding its home pose."""

    joints: list[str]
    times: np.ndarray
    q: np.ndarray
    q0: np.ndarray


def hold_in_mujoco(mjcf_path: str | Path, joints: list[str], duration: float, dt: float, sample_dt: float = 0.01) -> HoldTrajectory:
    """MuJoCo from the ``home`` keyframe, actuators holding it under gravity (contacts as in the MJCF)."""
    model = mujoco.MjModel.from_xml_path(str(mjcf_path))
    model.opt.timestep = dt
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    addresses = [model.jnt_qposadr[model.joint(j).id] for j in joints]
    q0 = data.qpos[addresses].copy()
    every = max(1, round(sample_dt / dt))
    samples = []
    for step in range(1, round(duration / dt) + 1):
        mujoco.mj_step(model, data)
        if step % every == 0:
            samples.append(data.qpos[addresses].copy())
    return HoldTrajectory(list(joints), np.arange(1, len(samples) + 1) * every * dt, np.array(samples), q0)


def hold_in_newton(usd_path: str | Path, home: Mapping[str, float], joints: list[str], duration: float, dt: float,
                   sample_dt: float = 0.01) -> HoldTrajectory:
    """NVIDIA Newton (CPU, Featherstone) on the USD: start at ``home``, drive targets at ``home``, gravity on.

    Contacts are not simulated (the pose holds in free space). Featherstone integrates drive damping
    explicitly, so ``dt`` must resolve kd / (link inertia + armature): 0.4 ms suits the Panda.
    """
    import newton
    import warp as wp

    wp.config.quiet = True
    builder = newton.ModelBuilder()
    builder.add_usd(str(usd_path), floating=False, enable_self_collisions=False)
    model = builder.finalize(device="cpu")
    names = [label.rsplit("/", 1)[-1] for label in model.joint_label]
    q_start = model.joint_q_start.numpy()
    q0 = model.joint_q.numpy().copy()
    for index, name in enumerate(names):
        if name in home and q_start[index + 1] - q_start[index] == 1:
            q0[q_start[index]] = home[name]
    columns = [int(q_start[names.index(j)]) for j in joints]
    state, next_state, control = model.state(), model.state(), model.control()
    state.joint_q.assign(q0)
    control.joint_target_q.assign(q0)
    newton.eval_fk(model, state.joint_q, state.joint_qd, state)
    solver = newton.solvers.SolverFeatherstone(model)
    every = max(1, round(sample_dt / dt))
    samples = []
    for step in range(1, round(duration / dt) + 1):
        state.clear_forces()
        solver.step(state, next_state, control, None, dt)
        state, next_state = next_state, state
        if step % every == 0:
            samples.append(state.joint_q.numpy()[columns].copy())
    return HoldTrajectory(list(joints), np.arange(1, len(samples) + 1) * every * dt, np.array(samples), q0[columns])
