"""The lab's hidden effects that live in the model itself (link inertias, payload, armature, damping, dry friction),
written into the torque-driven arm (:mod:`sim2real.assets.arm`), and the per-joint gains and offsets of the motor and
the sensor."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from sim2real.errors import InputError
from sim2real.lab.config import _per_joint, _per_joint_vectors


def _apply_spec_effects(spec: mujoco.MjSpec, joints: Sequence[str], effects: Mapping[str, Any],
                        path: Path | None) -> dict[str, Any]:
    """Effects that live in the model itself; returns the resolved hidden values for truth.yaml."""
    truth: dict[str, Any] = {}
    _base_mount(spec, effects, path, truth)
    if "viscous_friction" in effects:
        values = _per_joint(effects["viscous_friction"]["coefficient"], joints, "viscous_friction", path)
        for j, v in zip(joints, values):
            # MuJoCo 4 joint damping is a polynomial in velocity: only the linear term is viscous.
            damping = np.array(spec.joint(j).damping, dtype=float).reshape(-1)
            damping[0] += v
            spec.joint(j).damping = damping
        truth["viscous_friction"] = {"coefficient": dict(zip(joints, values.tolist()))}
    coulomb = effects.get("coulomb_friction")
    if coulomb and coulomb.get("model", "sign") == "sign":
        values = _per_joint(coulomb["coefficient"], joints, "coulomb_friction", path)
        for j, v in zip(joints, values):
            spec.joint(j).frictionloss = spec.joint(j).frictionloss + v
        truth["coulomb_friction"] = {"model": "sign", "coefficient": dict(zip(joints, values.tolist()))}
    if "rotor_inertia" in effects:
        values = _per_joint(effects["rotor_inertia"]["armature"], joints, "rotor_inertia", path)
        for j, v in zip(joints, values):
            spec.joint(j).armature = spec.joint(j).armature + v
        truth["rotor_inertia"] = {"armature": dict(zip(joints, values.tolist()))}
    if "link_inertia" in effects:
        link = effects["link_inertia"]
        moving = [spec.joint(j).parent for j in joints]
        scales = _per_joint(link.get("scale", 1.0), joints, "link_inertia/scale", path)
        scales = scales * _per_joint(link.get("mass_scale", 1.0), joints, "link_inertia/mass_scale", path)
        if np.any(scales <= 0):
            raise InputError(path, "link_inertia/mass_scale", "a mass scale is not positive", "give factors > 0")
        offsets = _per_joint_vectors(link.get("com_offset", {}), joints, "link_inertia/com_offset", path)
        for body, scale, offset in zip(moving, scales, offsets):
            body.mass = body.mass * scale
            body.inertia = np.asarray(body.inertia) * scale
            if np.all(np.isfinite(body.fullinertia)):
                body.fullinertia = np.asarray(body.fullinertia) * scale
            body.ipos = np.asarray(body.ipos) + offset
        truth["link_inertia"] = {
            "mass_scale": {b.name: float(s) for b, s in zip(moving, scales)},
            "com_offset": {b.name: o.tolist() for b, o in zip(moving, offsets) if np.any(o)},
        }
    if "payload" in effects:
        payload = effects["payload"]
        body_name = payload.get("body") or spec.joint(joints[-1]).parent.name
        parent = spec.body(body_name)
        if parent is None:
            raise InputError(path, "payload/body", f"no body '{body_name}'", "name a body of the MJCF")
        com = np.asarray(payload.get("com", [0.0, 0.0, 0.0]), dtype=float)
        mass = float(payload["mass"])
        radius = float(payload.get("radius", 0.03))
        child = parent.add_body()
        child.name = "lab_payload"
        child.pos = com
        child.mass = mass
        child.inertia = np.full(3, 0.4 * mass * radius**2)  # solid sphere
        child.explicitinertial = True
        truth["payload"] = {"mass": mass, "com": com.tolist(), "body": body_name, "radius": radius}
    return truth


def _base_mount(spec: mujoco.MjSpec, effects: Mapping[str, Any], path: Path | None, truth: dict[str, Any]) -> None:
    """``base_mount`` ``{tilt_x_deg, tilt_y_deg}``: the real arm's base turned by ``tilt_x_deg`` about the world's x,
    then ``tilt_y_deg`` about the world's y (a URDF origin's rpy): gravity, seen from the base, is the world's turned back (the lab turns the
    gravity vector of its torque-driven arm, whose base is the world). Recorded in ``truth`` (degrees)."""
    mount = effects.get("base_mount")
    if not mount:
        return
    angles = [mount.get(key, 0.0) for key in ("tilt_x_deg", "tilt_y_deg")]
    if not all(isinstance(v, (int, float)) and np.isfinite(v) and abs(v) < 90 for v in angles):
        raise InputError(path, "base_mount", "a tilt is not a finite angle below 90 degrees",
                         "give tilt_x_deg and tilt_y_deg in degrees, e.g. {tilt_x_deg: 1.5, tilt_y_deg: -1.0}")
    a, b = np.radians(angles)
    magnitude = float(np.linalg.norm(spec.option.gravity))
    spec.option.gravity = magnitude * np.array([np.sin(b), -np.sin(a) * np.cos(b), -np.cos(a) * np.cos(b)])
    truth["base_mount"] = {"tilt_x_deg": float(angles[0]), "tilt_y_deg": float(angles[1])}


# Per-joint gains and offsets: (effect, its key, the value when absent). The motor's act on the command
# before the joint, the sensor's on the measured torque after it.
GAINS_AND_BIASES = (("actuator_gain", "gain", 1.0), ("command_bias", "bias", 0.0),
                    ("torque_gain", "gain", 1.0), ("torque_bias", "bias", 0.0))


def _gains_and_biases(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None,
                      truth: dict[str, Any]) -> dict[str, np.ndarray]:
    """Each of :data:`GAINS_AND_BIASES` per joint; the hidden ones are recorded in ``truth``."""
    out = {}
    for name, key, absent in GAINS_AND_BIASES:
        out[name] = np.full(len(joints), absent)
        if name in effects:
            out[name] = _per_joint(effects[name][key], joints, name, path)
            truth[name] = {key: dict(zip(joints, out[name].tolist()))}
    return out
