"""Resolution of dr.yaml against the built MJCF: the document written to ``results/{robot}/dr.json``.

Every selector becomes concrete element names (glob patterns against the model, each pattern must
match), every declared range becomes an absolute range per element around its MJCF nominal value,
and the action delay gets the actuator history-buffer size it needs. The model-free checks of each
term come first (:mod:`sim2real.dr.config`), then the checks that need the model (selectors, kd on
actuators without damping, absolute values that are not physical).
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from sim2real.dr.config import DeclaredTerm, curriculum_levels, declared_noise, declared_physics, validate_config
from sim2real.dr.parameters import (
    root_body,
    AFFINE,
    NOISE_TERMS,
    PARAMETERS,
    SELECTOR_KEY,
    Parameter,
    apply_operation,
    bound_words,
    candidate_elements,
    fmt,
    get_values,
    is_physical,
    rounded,
    sensor_candidates,
)
from sim2real.errors import InputError
from sim2real.files import read_yaml

FORMAT_VERSION = 1
# MuJoCo allocates an actuator's history buffer of this many samples per actuator at most (a delay of
# 100 s at 1 ms): beyond it a delay range is a typo, not a bus latency.
MAX_HISTORY_SAMPLES = 100_000


def _plural(what: str) -> str:
    """'body with mass' -> 'bodies with mass', 'colliding geom' -> 'colliding geoms'."""
    head, with_, rest = what.partition(" with ")
    words = head.split(" ")
    words[-1] = words[-1][:-1] + "ies" if words[-1].endswith("y") else words[-1] + "s"
    return " ".join(words) + with_ + rest


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
                f"correct the pattern (glob, case-sensitive) or remove it; available {_plural(what)}: {shown}",
            )
    return [(i, n) for i, n in candidates if any(fnmatch.fnmatchcase(n, p) for p in patterns)]


def _resolve_physics_channel(
    term_cfg: Mapping[str, Any],
    parameter: Parameter,
    model: mujoco.MjModel,
    path: str | Path | None,
    mjcf_label: str,
) -> dict[str, Any]:
    declared = declared_physics(term_cfg, parameter, path)
    elements = _physics_elements(term_cfg, parameter, model, path, mjcf_label, declared.key)
    ids = np.array([i for i, _ in elements], dtype=int)
    nominal = get_values(model, parameter.channel, ids)
    if parameter.channel == "kd":
        _check_kd(elements, nominal, model, path, mjcf_label, declared.key)
    targets = [_physics_target(name, nominal_row, parameter, declared, path) for (_, name), nominal_row in zip(elements, nominal)]

    resolved: dict[str, Any] = {
        "term": parameter.term,
        "channel": parameter.channel,
        "element": parameter.element,
        "unit": parameter.unit,
        "mode": declared.mode,
        "distribution": declared.distribution,
        "operation": declared.operation,
        "range": [declared.lo, declared.hi],
        "shared": bool(term_cfg.get("shared", False)),
        "targets": targets,
    }
    if declared.distribution == "gaussian":
        resolved["mean"] = declared.mean
        resolved["std"] = declared.std
    if parameter.element == "actuator":
        # Name the joint each actuator drives: identified values are usually keyed by joint.
        for target, (element_id, _) in zip(targets, elements):
            joint_id = int(model.actuator_trnid[element_id, 0])
            trn_joint = int(model.actuator_trntype[element_id]) == int(mujoco.mjtTrn.mjTRN_JOINT)
            target["joint"] = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, joint_id) if trn_joint else None
    return resolved


def _physics_elements(
    term_cfg: Mapping[str, Any],
    parameter: Parameter,
    model: mujoco.MjModel,
    path: str | Path | None,
    mjcf_label: str,
    base_key: str,
) -> list[tuple[int, str]]:
    """The channel's selector -> the elements it names (the model's gravity, or its root body, for a model channel)."""
    if parameter.element == "model":
        if parameter.channel == "base_tilt":
            body = root_body(model)
            return [(body, mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, body) or "base")]
        return [(0, "gravity")]
    selector_key = SELECTOR_KEY[parameter.element]
    patterns = term_cfg.get(selector_key, ["*"])
    what = {"body": "body with mass" if parameter.channel == "mass" else "body", "geom": "colliding geom",
            "joint": "hinge/slide joint",
            "actuator": ("actuator with a first-order filter (dyntype filter or filterexact, which '- actuation_lag' "
                         "in model.yaml writes into the calibrated MJCF)" if parameter.channel == "lag"
                         else "actuator")}[parameter.element]
    return _match_selector(
        patterns,
        candidate_elements(model, parameter.element, parameter.channel),
        path,
        f"{base_key}/{selector_key}",
        what,
        mjcf_label,
    )


def _check_kd(
    elements: Sequence[tuple[int, str]],
    nominal: np.ndarray,
    model: mujoco.MjModel,
    path: str | Path | None,
    mjcf_label: str,
    base_key: str,
) -> None:
    """kd scales an actuator's derivative gain: every selected actuator must have one."""
    no_kd = [name for (i, name), value in zip(elements, nominal[:, 0]) if value <= 0 or model.actuator_biastype[i] != AFFINE]
    if no_kd:
        raise InputError(
            path,
            f"key '{base_key}/kd_range'",
            f"actuators {', '.join(no_kd)} have no derivative gain (kv) in {mjcf_label}, so kd cannot be scaled",
            "select only position actuators with kv > 0 in 'actuator_names', or drop 'kd_range'",
        )


def _physics_target(
    name: str, nominal_row: np.ndarray, parameter: Parameter, declared: DeclaredTerm, path: str | Path | None
) -> dict[str, Any]:
    """One element's nominal value and absolute range, which must stay physical."""
    operation, lo, hi = declared.operation, declared.lo, declared.hi
    absolute_lo = apply_operation(operation, nominal_row, np.full(parameter.width, lo))
    absolute_hi = apply_operation(operation, nominal_row, np.full(parameter.width, hi))
    # A scale of a negative nominal flips the order; keep [min, max].
    low_abs, high_abs = np.minimum(absolute_lo, absolute_hi), np.maximum(absolute_lo, absolute_hi)
    bad = [v for v in low_abs if not is_physical(float(v), parameter)]
    if bad:
        raise InputError(
            path,
            f"key '{declared.range_key}' ({parameter.element} '{name}')",
            f"{operation} [{fmt(lo)}, {fmt(hi)}] on the nominal {parameter.quantity} {fmt(float(nominal_row[0]))} "
            f"{parameter.unit} reaches {fmt(float(bad[0]))} {parameter.unit}, which is not physical "
            f"(must be {bound_words(parameter)})",
            "narrow the range or use operation 'scale' with a positive range",
        )
    return {
        "name": name,
        "nominal": [rounded(v) for v in nominal_row],
        "range": [[rounded(a), rounded(b)] for a, b in zip(low_abs, high_abs)],
    }


def _resolve_noise(
    name: str, term_cfg: Mapping[str, Any], model: mujoco.MjModel, path: str | Path | None, mjcf_label: str
) -> dict[str, Any]:
    resolved = declared_noise(name, term_cfg, path)
    noise = NOISE_TERMS[name]
    base_key = f"observation_noise/{name}"
    if noise.element == "joint":
        selector_key = "joint_names"
        candidates = candidate_elements(model, "joint")
        what = "hinge/slide joint"
    else:
        selector_key = "sensor_names"
        candidates = sensor_candidates(model, int(noise.sensor_type or 0))
        what = "gyro sensor" if name == "imu_angular_velocity" else "accelerometer sensor"
    elements = _match_selector(term_cfg.get(selector_key, ["*"]), candidates, path, f"{base_key}/{selector_key}", what, mjcf_label)
    resolved["targets"] = [{"name": n} for _, n in elements]
    return resolved


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

    Parameters
    ----------
    config : mapping
        dr.yaml's content (schema ``schemas/dr.schema.json``); selectors are glob patterns on MJCF element names.
    model : mujoco.MjModel
    config_path, mjcf_label, robot : optional
        How dr.yaml and the MJCF are named in messages and in the document, and the robot's name.

    Returns
    -------
    dict
        The dr.json document.

    Raises
    ------
    InputError
        Naming the key path and the fix: a pattern matching nothing, a range beyond floating point, a delay too long.

    Examples
    --------
    >>> model = mujoco.MjModel.from_xml_string(
    ...     '<mujoco><worldbody><body name="link1"><joint/><geom size="0.05" mass="1"/></body></worldbody></mujoco>')
    >>> mass = dict(mode="reset", distribution="uniform", operation="scale", range=[0.9, 1.1], body_names=["link*"])
    >>> resolved = resolve_config({"physics_randomization": {"body_mass": mass}}, model, robot="arm")
    >>> [(c["channel"], c["targets"]) for c in resolved["physics"]]
    [('mass', [{'name': 'link1', 'nominal': [1.0], 'range': [[0.9, 1.1]]}])]
    """
    validate_config(config, config_path)
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

    for channel in physics:
        _check_finite(channel, config_path)
    timestep = float(model.opt.timestep)
    delay_samples = 0
    for channel in physics:
        if channel["channel"] == "delay":
            max_delay = max(t["range"][0][1] for t in channel["targets"])
            # Compare in floating point first: a huge delay over the time step overflows to inf.
            if max_delay / timestep > MAX_HISTORY_SAMPLES - 1:  # ceil(ratio) + 1 samples
                raise InputError(
                    config_path, f"key 'physics_randomization/{channel['term']}'",
                    f"a delay of {fmt(max_delay)} s needs more than {MAX_HISTORY_SAMPLES} actuator history "
                    f"samples at the {fmt(timestep)} s time step",
                    "randomize delays of milliseconds to a fraction of a second",
                )
            delay_samples = required_history_samples(max_delay, timestep)
    return {
        "format_version": FORMAT_VERSION,
        "robot": robot,
        "mjcf": mjcf_label,
        "timestep": timestep,
        "physics": physics,
        "observation_noise": noise,
        "curriculum": curriculum_levels(config, config_path),
        "actuator_history_samples": delay_samples,
    }


def _check_finite(channel: Mapping[str, Any], path: str | Path | None) -> None:
    """Every resolved number is finite: a huge scale times a nominal value overflows to inf."""

    def numbers(value: Any) -> list[float]:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return [float(value)]
        if isinstance(value, Mapping):
            return [x for v in value.values() for x in numbers(v)]
        if isinstance(value, (list, tuple)):
            return [x for v in value for x in numbers(v)]
        return []

    for target in channel["targets"]:
        if not all(math.isfinite(x) for x in numbers(target)):
            raise InputError(
                path, f"key 'physics_randomization/{channel['term']}'",
                f"the range resolves to a value beyond floating point on '{target.get('name')}' ({channel['channel']})",
                "use a range whose bounds (times the nominal value, for operation: scale) stay finite",
            )


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


def load_resolved(dr_json: str | Path) -> dict[str, Any]:
    import json

    return json.loads(Path(dr_json).read_text(encoding="utf-8"))
