"""The articulation's parts as USD wants them, from the URDF reader's records: rigid bodies (massless links
folded into their parent), joint frames (axis token and rotation), principal inertia and the drives' gains."""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from sim2real.assets.urdf_model import AXIS_TOKENS, RAD_PER_DEG, Joint, UrdfModel, transform
from sim2real.errors import InputError

def principal_inertia(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments (ascending) and the rotation whose columns are the principal axes (det +1).

    Eigenvector signs are fixed (largest component positive) so the quaternion is deterministic.
    """
    moments, axes = np.linalg.eigh(0.5 * (inertia + inertia.T))
    for k in range(3):
        if axes[np.argmax(np.abs(axes[:, k])), k] < 0:
            axes[:, k] *= -1
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1
    return moments, axes


def matrix_to_quat(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """Rotation matrix -> unit quaternion (w, x, y, z) with w >= 0."""
    w, x, y, z = trimesh.transformations.quaternion_from_matrix(transform(rotation))
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    return float(w), float(x), float(y), float(z)


def axis_frame(axis: np.ndarray) -> tuple[str, np.ndarray]:
    """USD joint axis token and the rotation R (joint frame in link frame) with R @ e_token = axis."""
    for k, token in enumerate(AXIS_TOKENS):
        if abs(abs(axis[k]) - 1.0) < 1e-9:
            if axis[k] > 0:
                return token, np.eye(3)
            other = np.zeros(3)
            other[(k + 1) % 3] = 1.0  # half turn about another axis flips the joint axis
            return token, trimesh.transformations.rotation_matrix(math.pi, other)[:3, :3]
    unit_x = np.array([1.0, 0.0, 0.0])
    return "X", trimesh.geometry.align_vectors(unit_x, axis)[:3, :3]


@dataclass
class Body:
    """A USD rigid body: a URDF link with mass plus the massless links folded into it."""

    link: str
    world: np.ndarray  # zero-configuration pose
    members: dict[str, np.ndarray] = field(default_factory=dict)  # link -> pose in the body frame


def fold_bodies(model: UrdfModel) -> tuple[dict[str, Body], dict[str, str | None]]:
    """Bodies and link -> body name (None: the world, for a massless root link)."""
    children: dict[str, list[Joint]] = {}
    for joint in model.joints.values():
        children.setdefault(joint.parent, []).append(joint)
    bodies: dict[str, Body] = {}
    body_of: dict[str, str | None] = {}
    world_pose: dict[str, np.ndarray] = {model.root: np.eye(4)}
    root_is_world = model.links[model.root].mass <= 0.0
    if root_is_world:
        body_of[model.root] = None
    else:
        bodies[model.root] = Body(model.root, np.eye(4), {model.root: np.eye(4)})
        body_of[model.root] = model.root
    stack = [model.root]
    while stack:  # depth-first in URDF order: deterministic
        parent = stack.pop(0)
        for joint in children.get(parent, []):
            child = joint.child
            world_pose[child] = world_pose[parent] @ joint.origin
            parent_body = body_of[parent]
            if joint.type == "fixed" and model.links[child].mass <= 0.0 and parent_body is not None:
                body_of[child] = parent_body
                body = bodies[parent_body]
                body.members[child] = body.members[parent] @ joint.origin
            else:
                bodies[child] = Body(child, world_pose[child], {child: np.eye(4)})
                body_of[child] = child
        stack[0:0] = [j.child for j in children.get(parent, [])]
    return bodies, body_of


@dataclass(frozen=True)
class DriveGains:
    """MJCF actuator gains in MuJoCo units (N m/rad, N m s/rad or N/m, N s/m) and the USD drive."""

    kind: str  # position | velocity | motor
    kp: float
    kv: float
    max_force: float | None

    def usd_stiffness(self, revolute: bool) -> float:
        return self.kp * RAD_PER_DEG if revolute else self.kp

    def usd_damping(self, revolute: bool) -> float:
        return self.kv * RAD_PER_DEG if revolute else self.kv


def drive_gains(model: UrdfModel, robot_config: Mapping[str, Any], config_path: str | Path | None = None) -> dict[str, DriveGains]:
    """Actuated joint -> gains, matched like the MJCF builder: first ``actuators`` entry whose glob matches."""
    actuated = [
        name for name, j in model.joints.items() if j.type in ("revolute", "prismatic", "continuous") and j.mimic is None
    ]
    out: dict[str, DriveGains] = {}
    for index, entry in enumerate(robot_config.get("actuators") or []):
        matched = [j for j in actuated if fnmatch.fnmatchcase(j, entry["joints"])]
        if not matched:
            raise InputError(config_path, f"actuators[{index}].joints '{entry['joints']}'", "matches no actuated joint",
                             f"use one of: {', '.join(actuated)}")
        for name in matched:
            if name in out:
                continue
            kind = entry["type"]
            kp = float(entry["kp"]) if kind == "position" else 0.0
            kv = float(entry.get("kv", 0.0)) if kind in ("position", "velocity") else 0.0
            out[name] = DriveGains(kind, kp, kv, model.joints[name].effort)
    return {name: out[name] for name in actuated if name in out}  # URDF order
