"""Distance to collision along a trajectory, by MuJoCo on the built MJCF and its CoACD collision parts.

The obstacles of the design (planes, boxes) are added to the world with MjSpec. MuJoCo's own contact
filter decides which pairs can collide (bodies welded together and a body with its parent never do),
and every collision geom is given a margin, so that its collision pass also reports pairs that come
within that margin of each other, with their distance. The smallest distance over those contacts is
the sample's clearance (``search`` when no pair is that close). A body welded to the world (the
robot's base) is not checked against the link its first joint moves, which touches it by design.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from sim2real.errors import InputError

COLLISION_GROUP = 3  # menagerie convention, as sim2real.assets.mjcf writes it
OBSTACLE_GROUP = 4


def _quat_from_normal(normal: np.ndarray) -> np.ndarray:
    """Quaternion (w x y z) turning +z into ``normal`` (a plane geom's free side)."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, normal)
    s, c = np.linalg.norm(axis), float(np.dot(z, normal))
    if s < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0]) if c > 0 else np.array([0.0, 1.0, 0.0, 0.0])
    angle = np.arctan2(s, c)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis / s])


class Clearance:
    """The arm of ``mjcf_path`` with ``obstacles``; distances for poses of ``joints``."""

    def __init__(self, mjcf_path: str | Path, joints: Sequence[str], obstacles: Sequence[Mapping[str, Any]],
                 search: float, config_path: str | Path | None = None, key: str = "obstacles") -> None:
        spec = mujoco.MjSpec.from_file(str(mjcf_path))
        self.search = float(search)
        # Only the collision parts take part: the visual geoms and their meshes go (most of the compile's time).
        for geom in list(spec.geoms):
            if geom.group == COLLISION_GROUP:
                geom.contype, geom.conaffinity, geom.margin = 1, 1, self.search
            else:
                spec.delete(geom)
        used = {geom.meshname for geom in spec.geoms}
        for mesh in list(spec.meshes):
            if mesh.name not in used:
                spec.delete(mesh)
        self.obstacle_names = []
        for k, obstacle in enumerate(obstacles):
            name = f"obstacle_{obstacle['name']}"
            geom = spec.worldbody.add_geom(name=name, group=OBSTACLE_GROUP, contype=1, conaffinity=1,
                                           margin=self.search)
            if obstacle["type"] == "plane":
                normal = np.asarray(obstacle["normal"], dtype=float)
                if np.linalg.norm(normal) == 0:
                    raise InputError(config_path, f"{key}/{k}/normal", "is the zero vector",
                                     "give the plane's normal pointing to the free side")
                geom.type = mujoco.mjtGeom.mjGEOM_PLANE
                geom.size = [0.0, 0.0, 1.0]
                geom.pos = obstacle["point"]
                geom.quat = _quat_from_normal(normal / np.linalg.norm(normal))
            else:
                geom.type = mujoco.mjtGeom.mjGEOM_BOX
                geom.size = obstacle["half_size"]
                geom.pos = obstacle["center"]
                if "quat" in obstacle:
                    geom.quat = obstacle["quat"]
            self.obstacle_names.append(name)
        # MuJoCo filters a body against its parent, except when the parent is welded to the world: the
        # robot's base and its first moving link touch at their joint, so exclude that pair too.
        welded = {spec.worldbody.name}  # bodies welded to the world: no joint between them and it
        base, moving = [], []
        for body in spec.bodies:  # depth first, parents before children: the compiled model's order
            if body.name == spec.worldbody.name:
                continue
            if body.parent.name in welded and not body.joints:
                welded.add(body.name)
                base.append(body.name)
            elif body.parent.name in welded:
                moving.append(body.name)
        for name in moving:
            for fixed in base:
                spec.add_exclude(bodyname1=fixed, bodyname2=name)
        self.model = spec.compile()
        self.model.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        self.data = mujoco.MjData(self.model)
        if self.model.nkey:  # joints the design does not move (the fingers) stay at the home keyframe
            mujoco.mj_resetDataKeyframe(self.model, self.data, 0)
        self.qadr = np.array([self.model.jnt_qposadr[self.model.joint(j).id] for j in joints])
        self.dofadr = np.array([self.model.jnt_dofadr[self.model.joint(j).id] for j in joints])

    def _pair_name(self, g1: int, g2: int) -> str:
        def name(g: int) -> str:
            geom = self.model.geom(g)
            return geom.name if geom.name.startswith("obstacle_") else self.model.body(self.model.geom_bodyid[g]).name
        return f"{name(g1)} / {name(g2)}"

    def _nearest_contact(self, q: np.ndarray) -> int | None:
        """Pose the arm at ``q``; the index of its nearest contact (None: nothing within the search distance)."""
        self.data.qpos[self.qadr] = q
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_collision(self.model, self.data)
        if self.data.ncon == 0:
            return None
        return int(np.argmin(self.data.contact.dist[: self.data.ncon]))

    def closest(self, q: np.ndarray) -> tuple[float, str | None]:
        """Smallest distance (m, negative: penetration) at pose ``q`` and the pair it is between."""
        k = self._nearest_contact(q)
        if k is None:
            return self.search, None
        contact = self.data.contact
        return float(contact.dist[k]), self._pair_name(int(contact.geom1[k]), int(contact.geom2[k]))

    def distances(self, q: np.ndarray) -> np.ndarray:
        """Smallest distance at each pose of ``q`` (N, n)."""
        return np.array([self.closest(row)[0] for row in np.atleast_2d(q)])

    def gradient(self, q: np.ndarray) -> np.ndarray:
        """d(smallest distance)/dq at one pose: the nearest points of the two geoms moved along the contact normal
        (``n' (J_2 - J_1)``, MuJoCo's point Jacobians), one collision pass instead of one per joint."""
        k = self._nearest_contact(q)
        if k is None:
            return np.zeros(len(q))
        model, data = self.model, self.data
        mujoco.mj_comPos(model, data)  # the Jacobians need the dofs' motion axes
        contact = data.contact
        normal = np.array(contact.frame[k][:3])  # from geom1 to geom2
        half = 0.5 * float(contact.dist[k]) * normal
        difference = np.zeros((3, model.nv))
        for geom, point, sign in ((contact.geom1[k], contact.pos[k] - half, -1.0),
                                  (contact.geom2[k], contact.pos[k] + half, 1.0)):
            jacobian = np.zeros((3, model.nv))
            mujoco.mj_jac(model, data, jacobian, None, np.asarray(point, dtype=float), int(model.geom_bodyid[geom]))
            difference += sign * jacobian
        return normal @ difference[:, self.dofadr]
