"""What can be randomized, and where it lives in an ``MjModel``.

* :data:`PARAMETERS` / :data:`NOISE_TERMS`: the randomizable model quantities and observation-noise
  terms, with their MJCF element kind, unit and physical bound.
* :func:`get_values` / :func:`set_values`: read nominal values and write randomized ones
  (arrays are ``(n_elements, width)``); :func:`candidate_elements`, :func:`geom_label` and
  :func:`geom_id`: the elements a selector can name.
* :func:`apply_operation` / :func:`declared_nominal`: how a value sampled in declared space maps
  onto an element's nominal value (``scale``, ``add``, ``abs``), shared by the resolution and the sampler.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

_HINGE_OR_SLIDE = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
AFFINE = int(mujoco.mjtBias.mjBIAS_AFFINE)


# ---------------------------------------------------------------------------------------------
# What can be randomized


@dataclass(frozen=True)
class Parameter:
    """One randomized model quantity: where it lives in the MjModel and what is physical."""

    term: str  # key under physics_randomization
    channel: str  # name of the quantity (a term may hold several, e.g. kp and kd)
    range_key: str  # key holding its declared range
    element: str  # body | geom | joint | actuator | model
    unit: str
    width: int  # values per element (3 for vectors)
    lower_bound: float | None  # absolute values must be >= (or > if strict) this
    strict: bool
    default_operation: str
    quantity: str  # words for messages


PARAMETERS: tuple[Parameter, ...] = (
    Parameter("body_mass", "mass", "range", "body", "kg", 1, 0.0, True, "scale", "mass"),
    Parameter("body_com_offset", "com_offset", "range", "body", "m", 3, None, False, "add", "center-of-mass offset"),
    Parameter("surface_friction", "sliding_friction", "range", "geom", "1", 1, 0.0, False, "abs", "friction coefficient"),
    Parameter("actuator_gains", "kp", "kp_range", "actuator", "gain", 1, 0.0, True, "scale", "actuator gain kp"),
    Parameter("actuator_gains", "kd", "kd_range", "actuator", "gain", 1, 0.0, False, "scale", "actuator gain kd"),
    Parameter("joint_damping", "damping", "range", "joint", "N*m*s/rad", 1, 0.0, False, "scale", "joint damping"),
    Parameter("joint_armature", "armature", "range", "joint", "kg*m^2", 1, 0.0, False, "scale", "joint armature"),
    Parameter("joint_frictionloss", "frictionloss", "range", "joint", "N*m", 1, 0.0, False, "scale", "joint friction loss"),
    Parameter("action_delay", "delay", "delay_range", "actuator", "s", 1, 0.0, False, "abs", "action delay"),
    Parameter("action_lag", "lag", "lag_range", "actuator", "s", 1, 0.0, False, "abs",
              "action lag (a first-order filter's time constant)"),
    Parameter("gravity", "gravity", "range", "model", "m/s^2", 3, None, False, "add", "gravity"),
    # The base's mount (effects.base_mount): its tilt about the world's x, then y, of the robot's root body.
    Parameter("base_tilt", "base_tilt", "range", "model", "rad", 2, None, False, "add",
              "base tilt (about the world's x, then y)"),
)
PARAMETER_BY_CHANNEL = {p.channel: p for p in PARAMETERS}
SELECTOR_KEY = {"body": "body_names", "geom": "geom_names", "joint": "joint_names", "actuator": "actuator_names"}


@dataclass(frozen=True)
class NoiseTerm:
    term: str
    element: str  # joint | sensor
    unit: str
    sensor_type: int | None = None


NOISE_TERMS: dict[str, NoiseTerm] = {
    "joint_position": NoiseTerm("joint_position", "joint", "rad or m"),
    "joint_velocity": NoiseTerm("joint_velocity", "joint", "rad/s or m/s"),
    "imu_angular_velocity": NoiseTerm("imu_angular_velocity", "sensor", "rad/s", int(mujoco.mjtSensor.mjSENS_GYRO)),
    "imu_linear_acceleration": NoiseTerm(
        "imu_linear_acceleration", "sensor", "m/s^2", int(mujoco.mjtSensor.mjSENS_ACCELEROMETER)
    ),
}


# ---------------------------------------------------------------------------------------------
# Model access: read nominal values / write randomized ones (arrays are (n_elements, width))


def _joint_dofs(model: mujoco.MjModel, ids: np.ndarray) -> np.ndarray:
    return model.jnt_dofadr[ids]


def get_values(model: mujoco.MjModel, channel: str, ids: np.ndarray) -> np.ndarray:
    """Current values of ``channel`` for element ids, shape (n, width)."""
    if channel == "mass":
        return model.body_mass[ids][:, None].copy()
    if channel == "com_offset":
        return model.body_ipos[ids].copy()
    if channel == "sliding_friction":
        return model.geom_friction[ids, 0][:, None].copy()
    if channel == "kp":
        return model.actuator_gainprm[ids, 0][:, None].copy()
    if channel == "kd":
        return -model.actuator_biasprm[ids, 2][:, None]
    if channel == "damping":
        return model.dof_damping[_joint_dofs(model, ids)][:, None].copy()
    if channel == "armature":
        return model.dof_armature[_joint_dofs(model, ids)][:, None].copy()
    if channel == "frictionloss":
        return model.dof_frictionloss[_joint_dofs(model, ids)][:, None].copy()
    if channel == "delay":
        return model.actuator_delay[ids][:, None].copy()
    if channel == "lag":
        return model.actuator_dynprm[ids, 0][:, None].copy()
    if channel == "gravity":
        return np.asarray(model.opt.gravity, dtype=float)[None, :].copy()
    if channel == "base_tilt":
        return np.array([base_tilt(model.body_quat[ids[0]])])
    raise KeyError(channel)


def root_body(model: mujoco.MjModel) -> int:
    """The robot's root body: the world's first child (the base_tilt channel's element)."""
    children = np.flatnonzero(model.body_parentid[1:] == 0) + 1
    return int(children[0]) if children.size else 0


def _tilt_quat(tilt_x: float, tilt_y: float) -> np.ndarray:
    """The turn about the world's x by ``tilt_x``, then about its y by ``tilt_y`` (a URDF rpy (x, y, 0))."""
    about_x = np.array([np.cos(tilt_x / 2), np.sin(tilt_x / 2), 0.0, 0.0])
    about_y = np.array([np.cos(tilt_y / 2), 0.0, np.sin(tilt_y / 2), 0.0])
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, about_y, about_x)
    return out


def base_tilt(quat: np.ndarray) -> np.ndarray:
    """(tilt_x, tilt_y) of a body's orientation: where its z axis points, as :func:`_tilt_quat` turns it."""
    matrix = np.zeros(9)
    mujoco.mju_quat2Mat(matrix, np.asarray(quat, dtype=float))
    z = matrix.reshape(3, 3)[:, 2]  # R = Ry(b) Rx(a): z axis = (sin b cos a, -sin a, cos b cos a)
    return np.array([np.arctan2(-z[1], np.hypot(z[0], z[2])), np.arctan2(z[0], z[2])])


def _set_base_tilt(model: mujoco.MjModel, base: mujoco.MjModel, body: int, tilt: np.ndarray) -> None:
    """Turn ``body`` about the world's origin to ``tilt``, keeping whatever else the base's own orientation holds
    (its turn about z)."""
    nominal = np.asarray(base.body_quat[body], dtype=float)
    undo, turn = np.zeros(4), np.zeros(4)
    mujoco.mju_negQuat(undo, _tilt_quat(*base_tilt(nominal)))
    mujoco.mju_mulQuat(turn, _tilt_quat(float(tilt[0]), float(tilt[1])), undo)  # from the nominal tilt to this one
    out, pos = np.zeros(4), np.zeros(3)
    mujoco.mju_mulQuat(out, turn, nominal)
    mujoco.mju_rotVecQuat(pos, np.asarray(base.body_pos[body], dtype=float), turn)
    model.body_quat[body], model.body_pos[body] = out, pos


def set_values(model: mujoco.MjModel, base: mujoco.MjModel, channel: str, ids: np.ndarray, values: np.ndarray) -> None:
    """Write ``values`` (n, width) into ``model``; coupled fields are derived from ``base``."""
    if channel == "mass":
        mass = values[:, 0]
        model.body_mass[ids] = mass
        # Scale inertia with mass so the body keeps its shape (density changes, geometry does not).
        ratio = mass / base.body_mass[ids]
        model.body_inertia[ids] = base.body_inertia[ids] * ratio[:, None]
    elif channel == "com_offset":
        model.body_ipos[ids] = values
    elif channel == "sliding_friction":
        model.geom_friction[ids, 0] = values[:, 0]
    elif channel == "kp":
        kp = values[:, 0]
        model.actuator_gainprm[ids, 0] = kp
        # Position servos carry -kp in biasprm[1], velocity servos -kv in biasprm[2]: keep them tied.
        base_gain = base.actuator_gainprm[ids, 0]
        affine = base.actuator_biastype[ids] == AFFINE
        for column in (1, 2):
            tied = affine & (base.actuator_biasprm[ids, column] == -base_gain) & (base_gain != 0)
            if column == 2:
                tied &= base.actuator_biasprm[ids, 1] == 0
            model.actuator_biasprm[ids[tied], column] = -kp[tied]
    elif channel == "kd":
        model.actuator_biasprm[ids, 2] = -values[:, 0]
    elif channel == "damping":
        model.dof_damping[_joint_dofs(model, ids)] = values[:, 0]
    elif channel == "armature":
        model.dof_armature[_joint_dofs(model, ids)] = values[:, 0]
    elif channel == "frictionloss":
        model.dof_frictionloss[_joint_dofs(model, ids)] = values[:, 0]
    elif channel == "delay":
        model.actuator_delay[ids] = values[:, 0]
    elif channel == "lag":
        model.actuator_dynprm[ids, 0] = values[:, 0]
    elif channel == "gravity":
        model.opt.gravity[:] = values[0]
    elif channel == "base_tilt":
        _set_base_tilt(model, base, int(ids[0]), values[0])
    else:
        raise KeyError(channel)


# Actuator dynamics with a first-order filter's time constant in dynprm[0] (the action_lag channel's elements).
_FILTERS = (int(mujoco.mjtDyn.mjDYN_FILTER), int(mujoco.mjtDyn.mjDYN_FILTEREXACT))

# Channels whose change alters quantities MuJoCo precomputes at qpos0 (mj_setConst).
CONST_CHANNELS = frozenset({"mass", "com_offset", "armature", "base_tilt"})


def _names(model: mujoco.MjModel, obj: mujoco.mjtObj, count: int) -> list[str]:
    return [mujoco.mj_id2name(model, obj, i) or "" for i in range(count)]


def candidate_elements(model: mujoco.MjModel, parameter_element: str, channel: str | None = None) -> list[tuple[int, str]]:
    """(id, name) of the elements a selector can pick for this kind of parameter, in id order."""
    if parameter_element == "body":
        names = _names(model, mujoco.mjtObj.mjOBJ_BODY, model.nbody)
        # World is not randomizable; a massless frame has no mass to scale.
        return [(i, n) for i, n in enumerate(names) if i > 0 and n and (channel != "mass" or model.body_mass[i] > 0)]
    if parameter_element == "geom":
        names = [geom_label(model, i) for i in range(model.ngeom)]
        colliding = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
        return [(i, n) for i, n in enumerate(names) if n and colliding[i]]
    if parameter_element == "joint":
        names = _names(model, mujoco.mjtObj.mjOBJ_JOINT, model.njnt)
        return [(i, n) for i, n in enumerate(names) if n and int(model.jnt_type[i]) in _HINGE_OR_SLIDE]
    if parameter_element == "actuator":
        names = _names(model, mujoco.mjtObj.mjOBJ_ACTUATOR, model.nu)
        if channel == "lag":  # a time constant only a first-order filter has
            return [(i, n) for i, n in enumerate(names) if n and int(model.actuator_dyntype[i]) in _FILTERS]
        return [(i, n) for i, n in enumerate(names) if n]
    raise KeyError(parameter_element)


def geom_label(model: mujoco.MjModel, geom_id: int) -> str:
    """The geom's name, or ``<body>/geom<k>`` (k-th geom of its body) for unnamed geoms, which
    URDF-derived MJCF is full of."""
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geom_id)
    if name:
        return name
    body = int(model.geom_bodyid[geom_id])
    body_name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, body) or f"body{body}"
    return f"{body_name}/geom{geom_id - int(model.body_geomadr[body])}"


def geom_id(model: mujoco.MjModel, label: str) -> int:
    """Inverse of :func:`geom_label`; -1 when absent."""
    found = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, label)
    if found >= 0 or "/geom" not in label:
        return found
    body_name, _, index = label.rpartition("/geom")
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body_name)
    if body < 0 or not index.isdigit() or int(index) >= int(model.body_geomnum[body]):
        return -1
    return int(model.body_geomadr[body]) + int(index)


def sensor_candidates(model: mujoco.MjModel, sensor_type: int) -> list[tuple[int, str]]:
    names = _names(model, mujoco.mjtObj.mjOBJ_SENSOR, model.nsensor)
    return [(i, n) for i, n in enumerate(names) if n and int(model.sensor_type[i]) == sensor_type]


# ---------------------------------------------------------------------------------------------
# Operations: declared space -> absolute values


def apply_operation(operation: str, nominal: np.ndarray, declared: np.ndarray) -> np.ndarray:
    """Absolute values; an overflow gives inf, which resolve_config refuses with the key to fix."""
    with np.errstate(over="ignore"):
        if operation == "scale":
            return nominal * declared
        if operation == "add":
            return nominal + declared
    if operation == "abs":
        if np.shape(declared) == nominal.shape:
            return np.array(declared, dtype=float)
        return np.broadcast_to(declared, np.broadcast_shapes(nominal.shape, np.shape(declared))).copy()
    raise KeyError(operation)


def declared_nominal(operation: str, nominal: np.ndarray) -> np.ndarray:
    """The nominal model expressed in declared space (what a curriculum level shrinks toward)."""
    if operation == "scale":
        return np.ones_like(nominal)
    if operation == "add":
        return np.zeros_like(nominal)
    return nominal.copy()


def is_physical(value: float, parameter: Parameter) -> bool:
    if parameter.lower_bound is None:
        return True
    return value > parameter.lower_bound if parameter.strict else value >= parameter.lower_bound


def bound_words(parameter: Parameter) -> str:
    return f"{'>' if parameter.strict else '>='} {fmt(parameter.lower_bound or 0.0)}"


# ---------------------------------------------------------------------------------------------
# Numbers in messages and in dr.json


def rounded(x: Any) -> float:
    """12 significant digits: readable JSON without float noise like 3.5514600000000005."""
    return float(f"{float(x):.12g}")


def fmt(x: float) -> str:
    return f"{x:.6g}"
