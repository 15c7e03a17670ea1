"""Domain randomization: validate ``configs/{robot}/dr.yaml`` against the built MJCF, resolve it
to ``results/{robot}/dr.json``, and apply it in memory at runtime.

Three layers, each usable without Snakemake:

* :func:`resolve_config` -- schema + checks beyond the schema (selectors against the MJCF, modes,
  range order, physical values) -> the resolved document (concrete element names, absolute ranges).
* :func:`check_coverage` -- identified values from ``results/{robot}/sysid/params.yaml`` that a
  randomization touches must lie inside its range (the shape read is documented there).
* :class:`DomainRandomizer` -- from ``dr.json`` and a base ``MjModel``: a randomized model in
  memory per episode (no file written), reproducible under a seed; action delay through MuJoCo's
  actuator ``delay`` (history buffer); observation noise per step.

Sampling happens in the *declared* space (a mass scale, a friction value, an offset) and the
operation maps it onto the element's nominal value: ``scale`` -> nominal * x, ``add`` -> nominal + x,
``abs`` -> x. Curriculum levels shrink each range toward the nominal model:
``level range = nominal + s * (declared range - nominal)`` (in declared space the nominal is 1 for
``scale``, 0 for ``add`` and the element's MJCF value for ``abs``); a noise std is multiplied by ``s``.
"""

from __future__ import annotations

import copy
import fnmatch
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from scipy.special import ndtr, ndtri

from sim2real.errors import InputError
from sim2real.io import read_yaml, validate

SCHEMA_NAME = "dr.schema.json"
FORMAT_VERSION = 1
PHYSICS_MODES = ("startup", "reset")
_HINGE_OR_SLIDE = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
_AFFINE = int(mujoco.mjtBias.mjBIAS_AFFINE)


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
    Parameter("gravity", "gravity", "range", "model", "m/s^2", 3, None, False, "add", "gravity"),
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
    if channel == "gravity":
        return np.asarray(model.opt.gravity, dtype=float)[None, :].copy()
    raise KeyError(channel)


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
        affine = base.actuator_biastype[ids] == _AFFINE
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
    elif channel == "gravity":
        model.opt.gravity[:] = values[0]
    else:
        raise KeyError(channel)


# Channels whose change alters quantities MuJoCo precomputes at qpos0 (mj_setConst).
_CONST_CHANNELS = frozenset({"mass", "com_offset", "armature"})


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


def _sensor_candidates(model: mujoco.MjModel, sensor_type: int) -> list[tuple[int, str]]:
    names = _names(model, mujoco.mjtObj.mjOBJ_SENSOR, model.nsensor)
    return [(i, n) for i, n in enumerate(names) if n and int(model.sensor_type[i]) == sensor_type]


# ---------------------------------------------------------------------------------------------
# Resolution: dr.yaml + MjModel -> resolved document


def _rounded(x: Any) -> float:
    """12 significant digits: readable JSON without float noise like 3.5514600000000005."""
    return float(f"{float(x):.12g}")


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def _preschema_checks(config: Any, path: str | Path | None) -> None:
    """Friendlier errors than the schema would give for template keys MuJoCo cannot represent."""
    if not isinstance(config, Mapping):
        return
    friction = (config.get("physics_randomization") or {}).get("surface_friction")
    if isinstance(friction, Mapping):
        for key in ("static_friction_range", "dynamic_friction_range", "restitution_range"):
            if key in friction:
                raise InputError(
                    path,
                    f"key 'physics_randomization/surface_friction/{key}'",
                    "MuJoCo has a single Coulomb (sliding) friction coefficient per geom and no restitution coefficient",
                    "replace the static/dynamic/restitution ranges by one 'range: [low, high]' for the sliding friction",
                )


def _check_range(lo_hi: Sequence[float], path: str | Path | None, key: str) -> tuple[float, float]:
    lo, hi = float(lo_hi[0]), float(lo_hi[1])
    if lo > hi:
        raise InputError(path, f"key '{key}'", f"range [{_fmt(lo)}, {_fmt(hi)}] is reversed", f"write it as [{_fmt(hi)}, {_fmt(lo)}]")
    if lo == hi:
        raise InputError(
            path,
            f"key '{key}'",
            f"range [{_fmt(lo)}, {_fmt(hi)}] is empty (zero width), it randomizes nothing",
            "widen it to [low, high] with low < high, or remove the term",
        )
    return lo, hi


def _match_selector(
    patterns: Sequence[str],
    candidates: Sequence[tuple[int, str]],
    path: str | Path | None,
    key: str,
    what: str,
    mjcf_label: str,
) -> list[tuple[int, str]]:
    """Elements matched by any pattern, in id order; every pattern must match something."""
    names = [name for _, name in candidates]
    for index, pattern in enumerate(patterns):
        if not any(fnmatch.fnmatchcase(name, pattern) for name in names):
            shown = ", ".join(names[:12]) + (", ..." if len(names) > 12 else "") if names else "none"
            raise InputError(
                path,
                f"key '{key}[{index}]'",
                f"pattern '{pattern}' matches no {what} in {mjcf_label}",
                f"correct the pattern (glob, case-sensitive) or remove it; available {what}s: {shown}",
            )
    return [(i, n) for i, n in candidates if any(fnmatch.fnmatchcase(n, p) for p in patterns)]


def _apply_operation(operation: str, nominal: np.ndarray, declared: np.ndarray) -> np.ndarray:
    if operation == "scale":
        return nominal * declared
    if operation == "add":
        return nominal + declared
    if operation == "abs":
        if np.shape(declared) == nominal.shape:
            return np.array(declared, dtype=float)
        return np.broadcast_to(declared, np.broadcast_shapes(nominal.shape, np.shape(declared))).copy()
    raise KeyError(operation)


def _declared_nominal(operation: str, nominal: np.ndarray) -> np.ndarray:
    """The nominal model expressed in declared space (what a curriculum level shrinks toward)."""
    if operation == "scale":
        return np.ones_like(nominal)
    if operation == "add":
        return np.zeros_like(nominal)
    return nominal.copy()


def _is_physical(value: float, parameter: Parameter) -> bool:
    if parameter.lower_bound is None:
        return True
    return value > parameter.lower_bound if parameter.strict else value >= parameter.lower_bound


def _bound_words(parameter: Parameter) -> str:
    return f"{'>' if parameter.strict else '>='} {_fmt(parameter.lower_bound or 0.0)}"


def _resolve_physics_channel(
    term_cfg: Mapping[str, Any],
    parameter: Parameter,
    model: mujoco.MjModel,
    path: str | Path | None,
    mjcf_label: str,
) -> dict[str, Any]:
    base_key = f"physics_randomization/{parameter.term}"
    mode = term_cfg["mode"]
    if mode not in PHYSICS_MODES:
        raise InputError(
            path,
            f"key '{base_key}/mode'",
            f"physics parameter '{parameter.term}' is randomized at '{mode}': a model parameter that changes every "
            "step is not a physical robot and breaks the integrator's assumptions",
            "use 'mode: reset' (one draw per episode) or 'mode: startup' (one draw per sampler)",
        )
    operation = term_cfg.get("operation", parameter.default_operation)
    distribution = term_cfg["distribution"]
    range_key = f"{base_key}/{parameter.range_key}"
    unit_factor = 1e-3 if term_cfg.get("unit") == "milliseconds" else 1.0

    raw_range = term_cfg.get(parameter.range_key)
    if raw_range is None:
        # Only gaussian without a truncation range can get here (schema requires ranges otherwise).
        raise InputError(
            path,
            f"key '{base_key}'",
            f"gaussian '{parameter.term}' has no '{parameter.range_key}' to bound it, so it could draw non-physical values",
            f"add '{parameter.range_key}: [low, high]' as the truncation interval",
        )
    lo, hi = _check_range([v * unit_factor for v in raw_range], path, range_key)
    mean = std = None
    if distribution == "gaussian":
        mean = float(term_cfg["mean"]) * unit_factor
        std = float(term_cfg["std"]) * unit_factor
        if not lo <= mean <= hi:
            raise InputError(
                path,
                f"key '{base_key}/mean'",
                f"mean {_fmt(mean)} lies outside the truncation range [{_fmt(lo)}, {_fmt(hi)}]",
                "move the mean inside the range or widen the range",
            )
    if distribution == "log_uniform" and lo <= 0:
        raise InputError(
            path,
            f"key '{range_key}'",
            f"log_uniform needs a positive range, got [{_fmt(lo)}, {_fmt(hi)}]",
            "use a range with low > 0, or distribution 'uniform'",
        )
    # Declared-space physical checks (independent of the model).
    if operation == "scale" and parameter.lower_bound is not None:
        if lo < 0 or (parameter.strict and lo == 0):
            raise InputError(
                path,
                f"key '{range_key}'",
                f"a {parameter.quantity} scale of {_fmt(lo)} is not physical (scale must be {'> 0' if parameter.strict else '>= 0'})",
                f"use a lower bound {'> 0' if parameter.strict else '>= 0'}, e.g. [{_fmt(max(0.5, lo))}, {_fmt(max(hi, 1.5))}]",
            )
    if operation == "abs" and not _is_physical(lo, parameter):
        raise InputError(
            path,
            f"key '{range_key}'",
            f"a {parameter.quantity} of {_fmt(lo)} {parameter.unit} is not physical (must be {_bound_words(parameter)})",
            f"raise the lower bound to {_bound_words(parameter)}",
        )

    # Selector -> elements.
    if parameter.element == "model":
        elements: list[tuple[int, str]] = [(0, "gravity")]
    else:
        selector_key = SELECTOR_KEY[parameter.element]
        patterns = term_cfg.get(selector_key, ["*"])
        what = {"body": "body with mass" if parameter.channel == "mass" else "body", "geom": "colliding geom",
                "joint": "hinge/slide joint", "actuator": "actuator"}[parameter.element]
        elements = _match_selector(
            patterns,
            candidate_elements(model, parameter.element, parameter.channel),
            path,
            f"{base_key}/{selector_key}",
            what,
            mjcf_label,
        )
    ids = np.array([i for i, _ in elements], dtype=int)
    nominal = get_values(model, parameter.channel, ids)

    if parameter.channel == "kd":
        no_kd = [name for (i, name), value in zip(elements, nominal[:, 0]) if value <= 0 or model.actuator_biastype[i] != _AFFINE]
        if no_kd:
            raise InputError(
                path,
                f"key '{base_key}/kd_range'",
                f"actuators {', '.join(no_kd)} have no derivative gain (kv) in {mjcf_label}, so kd cannot be scaled",
                "select only position actuators with kv > 0 in 'actuator_names', or drop 'kd_range'",
            )

    targets = []
    for (element_id, name), nominal_row in zip(elements, nominal):
        absolute_lo = _apply_operation(operation, nominal_row, np.full(parameter.width, lo))
        absolute_hi = _apply_operation(operation, nominal_row, np.full(parameter.width, hi))
        # A scale of a negative nominal flips the order; keep [min, max].
        low_abs, high_abs = np.minimum(absolute_lo, absolute_hi), np.maximum(absolute_lo, absolute_hi)
        bad = [v for v in low_abs if not _is_physical(float(v), parameter)]
        if bad:
            raise InputError(
                path,
                f"key '{range_key}' ({parameter.element} '{name}')",
                f"{operation} [{_fmt(lo)}, {_fmt(hi)}] on the nominal {parameter.quantity} {_fmt(float(nominal_row[0]))} "
                f"{parameter.unit} reaches {_fmt(float(bad[0]))} {parameter.unit}, which is not physical "
                f"(must be {_bound_words(parameter)})",
                "narrow the range or use operation 'scale' with a positive range",
            )
        targets.append(
            {
                "name": name,
                "nominal": [_rounded(v) for v in nominal_row],
                "range": [[_rounded(a), _rounded(b)] for a, b in zip(low_abs, high_abs)],
            }
        )
        del element_id

    resolved: dict[str, Any] = {
        "term": parameter.term,
        "channel": parameter.channel,
        "element": parameter.element,
        "unit": parameter.unit,
        "mode": mode,
        "distribution": distribution,
        "operation": operation,
        "range": [lo, hi],
        "shared": bool(term_cfg.get("shared", False)),
        "targets": targets,
    }
    if distribution == "gaussian":
        resolved["mean"] = mean
        resolved["std"] = std
    if parameter.element == "actuator":
        # Name the joint each actuator drives: identified values are usually keyed by joint.
        for target, (element_id, _) in zip(targets, elements):
            joint_id = int(model.actuator_trnid[element_id, 0])
            trn_joint = int(model.actuator_trntype[element_id]) == int(mujoco.mjtTrn.mjTRN_JOINT)
            target["joint"] = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, joint_id) if trn_joint else None
    return resolved


def _resolve_noise(
    name: str, term_cfg: Mapping[str, Any], model: mujoco.MjModel, path: str | Path | None, mjcf_label: str
) -> dict[str, Any]:
    noise = NOISE_TERMS[name]
    base_key = f"observation_noise/{name}"
    mode = term_cfg["mode"]
    if mode != "step":
        raise InputError(
            path,
            f"key '{base_key}/mode'",
            f"observation noise '{name}' is drawn at '{mode}': one draw held for a whole episode is a sensor bias, "
            "not noise, and the policy learns to cancel it",
            "use 'mode: step' (a fresh draw at every observation)",
        )
    distribution = term_cfg["distribution"]
    resolved: dict[str, Any] = {"term": name, "element": noise.element, "unit": noise.unit, "mode": mode,
                                "distribution": distribution}
    if distribution == "gaussian":
        resolved["mean"] = float(term_cfg.get("mean", 0.0))
        resolved["std"] = float(term_cfg["std"])
    else:
        resolved["range"] = list(_check_range(term_cfg["range"], path, f"{base_key}/range"))
    if noise.element == "joint":
        selector_key = "joint_names"
        candidates = candidate_elements(model, "joint")
        what = "hinge/slide joint"
    else:
        selector_key = "sensor_names"
        candidates = _sensor_candidates(model, int(noise.sensor_type or 0))
        what = "gyro sensor" if name == "imu_angular_velocity" else "accelerometer sensor"
    elements = _match_selector(term_cfg.get(selector_key, ["*"]), candidates, path, f"{base_key}/{selector_key}", what, mjcf_label)
    resolved["targets"] = [{"name": n} for _, n in elements]
    return resolved


def _resolve_curriculum(config: Mapping[str, Any], path: str | Path | None) -> dict[str, Any]:
    curriculum = config.get("curriculum")
    if not curriculum:
        return {"levels": [{"name": "full", "scale": 1.0}], "default_level": "full"}
    levels = [{"name": str(level["name"]), "scale": float(level["scale"])} for level in curriculum["levels"]]
    names = [level["name"] for level in levels]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise InputError(path, "key 'curriculum/levels'", f"level names repeat: {', '.join(duplicates)}", "give each level a unique name")
    default_level = curriculum.get("default_level", names[-1])
    if default_level not in names:
        raise InputError(
            path,
            "key 'curriculum/default_level'",
            f"'{default_level}' is not a level",
            f"use one of: {', '.join(names)}",
        )
    return {"levels": levels, "default_level": default_level}


def resolve_config(
    config: Any,
    model: mujoco.MjModel,
    *,
    config_path: str | Path | None = None,
    mjcf_label: str = "the MJCF",
    robot: str | None = None,
) -> dict[str, Any]:
    """Validate ``config`` (parsed dr.yaml) and resolve it against ``model``.

    Returns the JSON-ready document written to ``results/{robot}/dr.json``: per physics channel the
    concrete element names with nominal values and absolute ranges, per noise term the elements,
    the curriculum levels, and the history-buffer size the action delay needs.
    Raises :class:`InputError` naming the key path and the fix for every bad input.
    """
    _preschema_checks(config, config_path)
    validate(config, SCHEMA_NAME, config_path)
    physics_cfg: Mapping[str, Any] = config.get("physics_randomization") or {}
    noise_cfg: Mapping[str, Any] = config.get("observation_noise") or {}

    physics = []
    for parameter in PARAMETERS:
        term_cfg = physics_cfg.get(parameter.term)
        if term_cfg is None:
            continue
        if parameter.range_key != "range" and parameter.range_key not in term_cfg:
            continue  # e.g. actuator_gains with kp_range only
        physics.append(_resolve_physics_channel(term_cfg, parameter, model, config_path, mjcf_label))
    noise = [_resolve_noise(name, noise_cfg[name], model, config_path, mjcf_label) for name in sorted(noise_cfg)]

    timestep = float(model.opt.timestep)
    delay_samples = 0
    for channel in physics:
        if channel["channel"] == "delay":
            max_delay = max(t["range"][0][1] for t in channel["targets"])
            delay_samples = required_history_samples(max_delay, timestep)
    return {
        "format_version": FORMAT_VERSION,
        "robot": robot,
        "mjcf": mjcf_label,
        "timestep": timestep,
        "physics": physics,
        "observation_noise": noise,
        "curriculum": _resolve_curriculum(config, config_path),
        "actuator_history_samples": delay_samples,
    }


def required_history_samples(max_delay: float, timestep: float) -> int:
    """Samples an actuator history buffer needs to hold ``max_delay`` (MuJoCo caps longer delays
    silently at the buffer length, so one sample of margin is added for interpolation)."""
    if max_delay <= 0:
        return 0
    return int(math.ceil(max_delay / timestep - 1e-9)) + 1


def resolve_files(
    config_path: str | Path, mjcf_path: str | Path, robot: str | None = None
) -> dict[str, Any]:
    """Read dr.yaml and the MJCF and resolve; paths appear in messages and output as given."""
    model = mujoco.MjModel.from_xml_path(str(mjcf_path))
    return resolve_config(read_yaml(config_path), model, config_path=config_path, mjcf_label=str(mjcf_path), robot=robot)


# ---------------------------------------------------------------------------------------------
# Coverage against identified values


# Names the sysid step may use for a parameter -> the randomized channel it corresponds to.
IDENTIFIED_ALIASES: dict[str, str] = {
    "viscous_friction": "damping",
    "damping": "damping",
    "joint_damping": "damping",
    "coulomb_friction": "frictionloss",
    "frictionloss": "frictionloss",
    "friction_loss": "frictionloss",
    "joint_frictionloss": "frictionloss",
    "rotor_inertia": "armature",
    "armature": "armature",
    "joint_armature": "armature",
    "actuation_delay": "delay",
    "action_delay": "delay",
    "delay": "delay",
    "mass": "mass",
    "body_mass": "mass",
    "link_mass": "mass",
    "kp": "kp",
    "kd": "kd",
    "sliding_friction": "sliding_friction",
    "surface_friction": "sliding_friction",
}
GLOBAL_ELEMENT = "*"


@dataclass(frozen=True)
class IdentifiedValue:
    parameter: str  # as named in params.yaml
    channel: str
    element: str  # element name, or GLOBAL_ELEMENT for a value shared by all elements
    value: float
    interval: tuple[float, float]  # confidence interval (value, value when none given)


def _as_value(entry: Any) -> tuple[float, tuple[float, float]] | None:
    """A number, or a mapping with 'value' and optional 'ci'/'interval'/'ci95'/'lower'+'upper'."""
    if isinstance(entry, bool):
        return None
    if isinstance(entry, (int, float)):
        return float(entry), (float(entry), float(entry))
    if isinstance(entry, Mapping) and isinstance(entry.get("value"), (int, float)) and not isinstance(entry.get("value"), bool):
        value = float(entry["value"])
        for key in ("ci", "ci95", "interval", "confidence_interval"):
            ci = entry.get(key)
            if isinstance(ci, Sequence) and not isinstance(ci, str) and len(ci) == 2:
                return value, (float(min(ci)), float(max(ci)))
        if isinstance(entry.get("lower"), (int, float)) and isinstance(entry.get("upper"), (int, float)):
            return value, (float(entry["lower"]), float(entry["upper"]))
        return value, (value, value)
    return None


# sysid's params.yaml: (effect, quantity) -> randomized channel.
SYSID_QUANTITIES: dict[tuple[str, str], str] = {
    ("viscous_friction", "damping"): "damping",
    ("coulomb_friction", "friction"): "frictionloss",
    ("rotor_inertia", "armature"): "armature",
    ("actuation_delay", "delay"): "delay",
}


def _read_sysid_effects(params: Mapping[str, Any]) -> list[IdentifiedValue]:
    """The sysid stage's shape: ``effects: {effect: {quantity: {joint: value} | value}}`` with
    ``intervals`` of the same shape holding ``[low, high]`` (absent for some quantities)."""
    found = []
    intervals = params.get("intervals") or {}
    for effect, quantities in (params.get("effects") or {}).items():
        if not isinstance(quantities, Mapping):
            continue
        for quantity, values in quantities.items():
            channel = SYSID_QUANTITIES.get((str(effect), str(quantity)))
            if channel is None:
                continue
            effect_intervals = intervals.get(effect) if isinstance(intervals, Mapping) else None
            quantity_intervals = effect_intervals.get(quantity) if isinstance(effect_intervals, Mapping) else None
            per_element = values.items() if isinstance(values, Mapping) else [(GLOBAL_ELEMENT, values)]
            for element, value in per_element:
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    continue
                ci = quantity_intervals.get(element) if isinstance(quantity_intervals, Mapping) else quantity_intervals
                interval = (float(min(ci)), float(max(ci))) if isinstance(ci, list) and len(ci) == 2 else (float(value), float(value))
                found.append(IdentifiedValue(f"{effect}.{quantity}", channel, str(element), float(value), interval))
    return found


def read_identified(params: Any) -> list[IdentifiedValue]:
    """Identified values from a parsed ``results/{robot}/sysid/params.yaml``.

    The sysid stage's own shape (``effects`` + ``intervals``, see :func:`_read_sysid_effects`;
    mapping in :data:`SYSID_QUANTITIES`) is read first. Otherwise this simple shape (anything
    else is ignored, unknown parameter names too)::

        parameters:                      # optional wrapper
          viscous_friction:              # parameter name, see IDENTIFIED_ALIASES
            panda_joint1: {value: 0.21, ci: [0.19, 0.23]}   # element -> value (+ interval)
            panda_joint2: 0.18                              # bare number: no interval
          actuation_delay: {value: 0.012, ci: [0.010, 0.014]}  # no element: applies to all

    A list of records ``[{parameter|effect|name, element|joint|body|actuator, value, ci}]`` is also
    accepted, under ``parameters`` or at the top level.
    """
    if isinstance(params, Mapping) and isinstance(params.get("effects"), Mapping):
        return _read_sysid_effects(params)
    root = params.get("parameters", params) if isinstance(params, Mapping) else params
    found: list[IdentifiedValue] = []

    def add(parameter: str, element: str, entry: Any) -> None:
        channel = IDENTIFIED_ALIASES.get(str(parameter))
        parsed = _as_value(entry)
        if channel is not None and parsed is not None:
            found.append(IdentifiedValue(str(parameter), channel, str(element), parsed[0], parsed[1]))

    if isinstance(root, Mapping):
        for parameter, body in root.items():
            if _as_value(body) is not None:
                add(parameter, GLOBAL_ELEMENT, body)
            elif isinstance(body, Mapping):
                for element, entry in body.items():
                    add(parameter, element, entry)
    elif isinstance(root, Sequence) and not isinstance(root, str):
        for record in root:
            if not isinstance(record, Mapping):
                continue
            parameter = record.get("parameter", record.get("effect", record.get("name")))
            element = next((record[k] for k in ("element", "joint", "body", "actuator", "geom") if k in record), GLOBAL_ELEMENT)
            if parameter is not None:
                add(parameter, element, record)
    return found


def check_coverage(resolved: Mapping[str, Any], identified: Sequence[IdentifiedValue]) -> list[dict[str, Any]]:
    """Every identified value (with its interval) that a randomization touches must lie inside the
    randomized absolute range. Returns one record per touched value with ``covered`` true/false."""
    records = []
    for channel in resolved["physics"]:
        for item in identified:
            if item.channel != channel["channel"]:
                continue
            for target in channel["targets"]:
                names = {target["name"], target.get("joint")}
                if item.element != GLOBAL_ELEMENT and item.element not in names:
                    continue
                lo, hi = target["range"][0]
                covered = lo <= item.interval[0] and item.interval[1] <= hi
                records.append(
                    {
                        "term": channel["term"],
                        "channel": channel["channel"],
                        "element": target["name"],
                        "identified_as": item.parameter,
                        "value": item.value,
                        "interval": list(item.interval),
                        "range": [lo, hi],
                        "covered": covered,
                    }
                )
    return sorted(records, key=lambda r: (r["term"], r["channel"], r["element"], r["identified_as"]))


def coverage_summary(
    resolved: Mapping[str, Any], params_path: str | Path | None, *, strict: bool = False
) -> dict[str, Any]:
    """Coverage for ``params_path`` (skipped when None or absent). Uncovered values raise with
    ``strict``, else they are listed under ``warnings``."""
    if params_path is None or not Path(params_path).exists():
        return {"status": "skipped", "reason": "no identified parameters (sysid/params.yaml absent)", "records": [], "warnings": []}
    records = check_coverage(resolved, read_identified(read_yaml(params_path)))
    uncovered = [r for r in records if not r["covered"]]
    warnings = [
        f"{r['term']}/{r['element']}: identified {r['identified_as']} {_fmt(r['value'])} "
        f"(interval [{_fmt(r['interval'][0])}, {_fmt(r['interval'][1])}]) outside the randomized range "
        f"[{_fmt(r['range'][0])}, {_fmt(r['range'][1])}]"
        for r in uncovered
    ]
    if uncovered and strict:
        raise InputError(
            params_path,
            "identified values outside the randomized ranges",
            "; ".join(warnings),
            "widen the matching ranges in configs/<robot>/dr.yaml so they contain the identified intervals",
        )
    return {"status": "checked" if records else "nothing touched", "records": records, "warnings": warnings}


# ---------------------------------------------------------------------------------------------
# Runtime


def load_resolved(dr_json: str | Path) -> dict[str, Any]:
    import json

    return json.loads(Path(dr_json).read_text(encoding="utf-8"))


def load_model(mjcf_path: str | Path, resolved: Mapping[str, Any]) -> mujoco.MjModel:
    """Compile the MJCF with actuator history buffers long enough for the randomized delay.

    MuJoCo sizes the buffer at compile time (``nsample``) and silently caps a longer runtime
    ``actuator_delay`` at it, so the buffer is widened here via MjSpec; nothing is written to disk.
    """
    spec = mujoco.MjSpec.from_file(str(mjcf_path))
    samples = int(resolved.get("actuator_history_samples", 0))
    delayed = {t["name"] for c in resolved["physics"] if c["channel"] == "delay" for t in c["targets"]}
    if samples:
        for actuator in spec.actuators:
            if actuator.name in delayed and actuator.nsample < samples:
                actuator.nsample = samples
    return spec.compile()


@dataclass
class _Channel:
    name: str
    parameter: Parameter
    mode: str
    distribution: str
    operation: str
    shared: bool
    ids: np.ndarray
    nominal: np.ndarray  # (n, width), absolute, from the base model
    anchor: np.ndarray  # nominal in declared space
    declared_lo: float
    declared_hi: float
    mean: float | None
    std: float | None
    # per-level arrays, filled by set_level
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    level_mean: np.ndarray | None = None
    level_std: float | None = None


@dataclass
class _Noise:
    term: str
    distribution: str
    mean: float
    std: float
    lo: float
    hi: float
    read: Callable[[mujoco.MjData], np.ndarray]
    names: list[str]
    level_scale: float = 1.0


class DomainRandomizer:
    """Randomized copies of a base model, per episode, in memory.

    ``reset()`` redraws every ``reset``-mode parameter into ``self.model`` (one working model,
    updated in place: cheap enough for every episode) and returns it; ``startup`` parameters are
    drawn once at construction. ``sample()`` returns an independent deep copy instead.
    The same ``seed`` gives the same sequence of models; observation noise uses its own stream,
    so the number of observations taken does not change the models drawn.
    """

    def __init__(
        self,
        resolved: Mapping[str, Any],
        base_model: mujoco.MjModel,
        *,
        seed: int | None = 0,
        level: str | None = None,
    ) -> None:
        self.resolved = resolved
        self.base_model = base_model
        self.model = copy.deepcopy(base_model)
        self._scratch = mujoco.MjData(self.model)
        model_seed, noise_seed = np.random.SeedSequence(seed).spawn(2)
        self.rng = np.random.default_rng(model_seed)
        self.noise_rng = np.random.default_rng(noise_seed)
        self.levels = {lvl["name"]: float(lvl["scale"]) for lvl in resolved["curriculum"]["levels"]}
        self.channels = [self._compile_channel(c) for c in resolved["physics"]]
        self.noise = [self._compile_noise(n) for n in resolved["observation_noise"]]
        self.last_draw: dict[str, np.ndarray] = {}
        self._check_delay_capacity()
        self.set_level(level or resolved["curriculum"]["default_level"])
        self._draw(("startup",))

    @classmethod
    def from_files(
        cls, dr_json: str | Path, mjcf_path: str | Path, *, seed: int | None = 0, level: str | None = None
    ) -> DomainRandomizer:
        resolved = load_resolved(dr_json)
        return cls(resolved, load_model(mjcf_path, resolved), seed=seed, level=level)

    # -- construction ------------------------------------------------------------------------

    def _ids(self, obj: mujoco.mjtObj, names: Sequence[str], where: str) -> np.ndarray:
        ids = []
        for name in names:
            if obj == mujoco.mjtObj.mjOBJ_GEOM:
                element_id = geom_id(self.base_model, name)
            else:
                element_id = mujoco.mj_name2id(self.base_model, obj, name)
            if element_id < 0:
                raise InputError(
                    None,
                    where,
                    f"element '{name}' of dr.json is not in the base model",
                    "rebuild dr.json from the same MJCF (snakemake all) or pass the matching model",
                )
            ids.append(element_id)
        return np.array(ids, dtype=int)

    def _compile_channel(self, c: Mapping[str, Any]) -> _Channel:
        parameter = PARAMETER_BY_CHANNEL[c["channel"]]
        obj = {"body": mujoco.mjtObj.mjOBJ_BODY, "geom": mujoco.mjtObj.mjOBJ_GEOM, "joint": mujoco.mjtObj.mjOBJ_JOINT,
               "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR}.get(parameter.element)
        names = [t["name"] for t in c["targets"]]
        ids = np.zeros(1, dtype=int) if obj is None else self._ids(obj, names, f"dr.json physics '{c['term']}/{c['channel']}'")
        nominal = get_values(self.base_model, parameter.channel, ids)
        return _Channel(
            name=f"{c['term']}/{c['channel']}",
            parameter=parameter,
            mode=c["mode"],
            distribution=c["distribution"],
            operation=c["operation"],
            shared=bool(c.get("shared", False)),
            ids=ids,
            nominal=nominal,
            anchor=_declared_nominal(c["operation"], nominal),
            declared_lo=float(c["range"][0]),
            declared_hi=float(c["range"][1]),
            mean=c.get("mean"),
            std=c.get("std"),
        )

    def _compile_noise(self, n: Mapping[str, Any]) -> _Noise:
        names = [t["name"] for t in n["targets"]]
        if n["element"] == "joint":
            ids = self._ids(mujoco.mjtObj.mjOBJ_JOINT, names, f"dr.json observation_noise '{n['term']}'")
            index = self.base_model.jnt_qposadr[ids] if n["term"] == "joint_position" else self.base_model.jnt_dofadr[ids]
            field = "qpos" if n["term"] == "joint_position" else "qvel"

            def read(data: mujoco.MjData, index: np.ndarray = index, field: str = field) -> np.ndarray:
                return getattr(data, field)[index]
        else:
            ids = self._ids(mujoco.mjtObj.mjOBJ_SENSOR, names, f"dr.json observation_noise '{n['term']}'")
            index = np.concatenate(
                [np.arange(a, a + d) for a, d in zip(self.base_model.sensor_adr[ids], self.base_model.sensor_dim[ids])]
            )

            def read(data: mujoco.MjData, index: np.ndarray = index) -> np.ndarray:
                return data.sensordata[index]

        lo, hi = n.get("range", [0.0, 0.0])
        return _Noise(n["term"], n["distribution"], float(n.get("mean", 0.0)), float(n.get("std", 0.0)), float(lo), float(hi), read, names)

    def _check_delay_capacity(self) -> None:
        timestep = float(self.base_model.opt.timestep)
        for channel in self.channels:
            if channel.parameter.channel != "delay":
                continue
            needed = int(math.ceil(max(channel.declared_hi, float(channel.nominal.max())) / timestep - 1e-9))
            for element_id in channel.ids:
                held = int(self.base_model.actuator_history[element_id, 0])
                if held < needed:
                    name = mujoco.mj_id2name(self.base_model, mujoco.mjtObj.mjOBJ_ACTUATOR, int(element_id))
                    raise InputError(
                        None,
                        f"actuator '{name}'",
                        f"its history buffer holds {held} samples ({_fmt(held * timestep)} s) but action_delay reaches "
                        f"{_fmt(channel.declared_hi)} s; MuJoCo would silently cap the delay",
                        "load the model with sim2real.dr.load_model(mjcf, resolved) (or DomainRandomizer.from_files), "
                        f"or set nsample=\"{needed + 1}\" on the actuator in the MJCF",
                    )

    # -- curriculum --------------------------------------------------------------------------

    def set_level(self, level: str) -> None:
        """Shrink every range toward the nominal model by the level's scale (see module doc)."""
        if level not in self.levels:
            raise InputError(None, f"curriculum level '{level}'", "is not defined in dr.json", f"use one of: {', '.join(self.levels)}")
        self.level = level
        s = self.levels[level]
        for c in self.channels:
            c.lo = c.anchor + s * (c.declared_lo - c.anchor)
            c.hi = c.anchor + s * (c.declared_hi - c.anchor)
            if c.distribution == "gaussian":
                c.level_mean = c.anchor + s * (float(c.mean or 0.0) - c.anchor)
                c.level_std = float(c.std or 0.0) * s
        for n in self.noise:
            n.level_scale = s

    # -- sampling ----------------------------------------------------------------------------

    def _declared_draw(self, c: _Channel) -> np.ndarray:
        assert c.lo is not None and c.hi is not None
        shape = (1, c.parameter.width) if c.shared else c.nominal.shape
        u = self.rng.random(shape)
        if c.distribution == "uniform":
            return c.lo + (c.hi - c.lo) * u
        if c.distribution == "log_uniform":
            log_lo, log_hi = np.log(c.lo), np.log(c.hi)
            return np.exp(log_lo + (log_hi - log_lo) * u)
        # Truncated gaussian by inverse CDF: exact, and one uniform per value keeps streams aligned.
        assert c.level_mean is not None and c.level_std is not None
        a = ndtr((c.lo - c.level_mean) / c.level_std)
        b = ndtr((c.hi - c.level_mean) / c.level_std)
        return np.clip(c.level_mean + c.level_std * ndtri(a + (b - a) * u), c.lo, c.hi)

    def _draw(self, modes: Sequence[str]) -> None:
        touched_const = False
        for c in self.channels:
            if c.mode not in modes:
                continue
            declared = self._declared_draw(c)
            values = _apply_operation(c.operation, c.nominal, declared)
            set_values(self.model, self.base_model, c.parameter.channel, c.ids, values)
            self.last_draw[c.name] = values
            touched_const |= c.parameter.channel in _CONST_CHANNELS
        if touched_const:
            # Keep the qpos0-derived constants (subtree mass, inverse weights) as a compile would.
            mujoco.mj_setConst(self.model, self._scratch)

    def reset(self) -> mujoco.MjModel:
        """Redraw every reset-mode parameter into ``self.model`` and return it (in place)."""
        self._draw(("reset",))
        return self.model

    def sample(self) -> mujoco.MjModel:
        """An independent randomized model (deep copy): for keeping several models alive."""
        return copy.deepcopy(self.reset())

    def reset_data(self, data: mujoco.MjData, ctrl: np.ndarray | None = None, keyframe: int | None = None) -> None:
        """Reset ``data`` for the current model (to ``keyframe`` when given, which also sets its
        ctrl), optionally override ``ctrl``, and hold that command in every actuator history, so a
        delayed actuator starts from it instead of replaying zeros for the length of the delay."""
        if keyframe is None:
            mujoco.mj_resetData(self.model, data)
        else:
            mujoco.mj_resetDataKeyframe(self.model, data, keyframe)
        if ctrl is not None:
            data.ctrl[:] = ctrl
        for actuator_id in range(self.model.nu):
            samples = int(self.model.actuator_history[actuator_id, 0])
            if samples > 0:
                value = np.full((samples, 1), float(data.ctrl[actuator_id]))
                mujoco.mj_initCtrlHistory(self.model, data, actuator_id, None, value)
        mujoco.mj_forward(self.model, data)

    # -- observation noise -------------------------------------------------------------------

    def add_noise(self, term: str, values: np.ndarray) -> np.ndarray:
        """``values`` (ordered as the term's targets in dr.json) plus one step of noise."""
        noise = next((n for n in self.noise if n.term == term), None)
        if noise is None:
            raise InputError(None, f"observation noise '{term}'", "is not declared in dr.json",
                             f"declare it under observation_noise in dr.yaml, or use one of: {', '.join(n.term for n in self.noise)}")
        values = np.asarray(values, dtype=float)
        s = noise.level_scale
        if noise.distribution == "gaussian":
            return values + s * noise.mean + s * noise.std * self.noise_rng.standard_normal(values.shape)
        return values + s * self.noise_rng.uniform(noise.lo, noise.hi, values.shape)

    def observe(self, data: mujoco.MjData) -> dict[str, np.ndarray]:
        """Noisy observations of every declared noise term, read from ``data``."""
        return {n.term: self.add_noise(n.term, n.read(data)) for n in self.noise}


# ---------------------------------------------------------------------------------------------
# Summary for the report


def summary_rows(resolved: Mapping[str, Any], coverage: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One row per randomized element (vector components flattened), with the identified value."""
    identified = {(r["term"], r["channel"], r["element"]): r for r in coverage.get("records", [])}
    rows = []
    for channel in resolved["physics"]:
        for target in channel["targets"]:
            match = identified.get((channel["term"], channel["channel"], target["name"]))
            for axis, ((low, high), nominal) in enumerate(zip(target["range"], target["nominal"])):
                suffix = "xyz"[axis] if len(target["range"]) == 3 else ""
                rows.append(
                    {
                        "term": channel["term"],
                        "channel": channel["channel"] + (f".{suffix}" if suffix else ""),
                        "element": target["name"],
                        "unit": channel["unit"],
                        "mode": channel["mode"],
                        "distribution": channel["distribution"],
                        "operation": channel["operation"],
                        "nominal": nominal,
                        "low": low,
                        "high": high,
                        "identified": match["value"] if match else None,
                        "identified_low": match["interval"][0] if match else None,
                        "identified_high": match["interval"][1] if match else None,
                        "covered": match["covered"] if match else None,
                    }
                )
    return rows


def summary_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """Tab-separated table of :func:`summary_rows` (empty cells for missing values)."""
    columns = ["term", "channel", "element", "unit", "mode", "distribution", "operation", "nominal", "low", "high",
               "identified", "identified_low", "identified_high", "covered"]

    def cell(value: Any) -> str:
        if value is None:
            return ""
        if isinstance(value, float):
            return _fmt(value)
        return str(value).lower() if isinstance(value, bool) else str(value)

    return "\n".join(["\t".join(columns)] + ["\t".join(cell(row[c]) for c in columns) for row in rows]) + "\n"


def plot_summary(rows: Sequence[Mapping[str, Any]], title: str, target: str | Path) -> None:
    """One panel per randomized channel: the absolute range of each element (bar), its nominal
    value (black tick) and the identified interval when known (green inside / red outside)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sim2real.io import atomic_path

    channels: dict[str, list[Mapping[str, Any]]] = {}
    for row in rows:
        channels.setdefault(f"{row['term']} / {row['channel']}", []).append(row)
    heights = [max(len(v), 1) * 0.22 + 0.6 for v in channels.values()] or [1.0]
    with matplotlib.rc_context({"svg.hashsalt": "sim2real-dr", "font.size": 7}):
        fig, axes = plt.subplots(len(heights), 1, figsize=(7.0, sum(heights) + 0.6),
                                 gridspec_kw={"height_ratios": heights}, squeeze=False)
        for ax, (label, channel_rows) in zip(axes[:, 0], channels.items()):
            y = np.arange(len(channel_rows))
            lows = np.array([r["low"] for r in channel_rows])
            highs = np.array([r["high"] for r in channel_rows])
            ax.barh(y, highs - lows, left=lows, height=0.6, color="#9ecae1", edgecolor="#3182bd", linewidth=0.5)
            ax.scatter([r["nominal"] for r in channel_rows], y, marker="|", color="black", s=60, zorder=3)
            for yi, r in zip(y, channel_rows):
                if r["identified"] is not None:
                    color = "#2ca02c" if r["covered"] else "#d62728"
                    ax.errorbar(r["identified"], yi, xerr=[[r["identified"] - r["identified_low"]],
                                                          [r["identified_high"] - r["identified"]]],
                                fmt="o", color=color, markersize=3, capsize=2, zorder=4)
            ax.set_yticks(y, [r["element"] for r in channel_rows])
            ax.invert_yaxis()
            first = channel_rows[0]
            ax.set_title(f"{label} [{first['unit']}]  ({first['mode']}, {first['distribution']}, {first['operation']})",
                         loc="left", fontsize=7)
        fig.suptitle(title, fontsize=8)
        fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.25 / (sum(heights) + 0.6)))
        with atomic_path(target) as tmp:
            fig.savefig(tmp, format="svg", metadata={"Date": None, "Creator": None})
        plt.close(fig)


def build_summary(
    dr_json: str | Path,
    params_path: str | Path | None,
    coverage_out: str | Path,
    table_out: str | Path,
    figure_out: str | Path,
    *,
    strict: bool = False,
) -> dict[str, Any]:
    """Coverage check + summary table + figure for one robot (the ``dr_summary`` rule)."""
    from sim2real.io import write_json, write_text

    resolved = load_resolved(dr_json)
    coverage = coverage_summary(resolved, params_path, strict=strict)
    rows = summary_rows(resolved, coverage)
    write_json(coverage_out, coverage)
    write_text(table_out, summary_table(rows))
    robot = resolved.get("robot") or "robot"
    plot_summary(rows, f"Domain randomization: {robot} (level ranges at scale 1)", figure_out)
    return coverage
