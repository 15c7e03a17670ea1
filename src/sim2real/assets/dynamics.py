"""Rigid-body dynamics of a robot description with Pinocchio, batched over samples.

The one place that turns a URDF into inverse dynamics and regressors; the gap report,
the fits and the diagnosis all go through it so that they judge the same model.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pinocchio as pin

from sim2real.errors import InputError

INERTIAL_PARAMS_PER_BODY = 10  # m, m*c (3), I at joint frame (6): Pinocchio's dynamic parameter order


class RigidBodyModel:
    """Pinocchio model of the measured joints; every other joint is locked.

    ``joint_names`` orders all arrays (columns of q, qd, qdd, tau). Joints of the URDF that are
    not measured (a gripper, a mimic joint) are locked at ``locked`` (default: 0 clipped into
    their limits), which is what an arm log implies: they did not move.
    URDF ``<dynamics damping friction>`` and ``armature`` enter the joint torque, as in the MJCF.
    """

    def __init__(
        self,
        urdf_path: str | Path,
        joint_names: Sequence[str] | None = None,
        locked: Mapping[str, float] | None = None,
        armature: Mapping[str, float] | None = None,
    ) -> None:
        urdf_path = Path(urdf_path)
        try:
            full = pin.buildModelFromUrdf(str(urdf_path))
        except Exception as exc:  # Pinocchio raises bare RuntimeError/ValueError
            raise InputError(urdf_path, None, f"Pinocchio cannot parse it ({exc})", "check the URDF") from exc
        names = [full.names[i] for i in range(1, full.njoints)]
        if joint_names is None:
            joint_names = names
        unknown = [j for j in joint_names if j not in names]
        if unknown:
            raise InputError(
                urdf_path, f"joint(s) {', '.join(unknown)}", "not in the robot description",
                f"use joint names of the URDF: {', '.join(names)}",
            )
        for j in joint_names:
            jmodel = full.joints[full.getJointId(j)]
            if jmodel.nq != 1 or jmodel.nv != 1:
                raise InputError(urdf_path, f"joint {j}", "is not a 1-DoF joint", "measure only revolute/prismatic joints")
        locked = dict(locked or {})
        q_lock = pin.neutral(full)
        lock_ids = []
        for name in names:
            if name in joint_names:
                continue
            jid = full.getJointId(name)
            idx = full.joints[jid].idx_q
            value = locked.get(name, 0.0)
            lo, hi = full.lowerPositionLimit[idx], full.upperPositionLimit[idx]
            q_lock[idx] = float(np.clip(value, lo, hi)) if np.isfinite(lo) and np.isfinite(hi) else value
            lock_ids.append(jid)
        self.model = pin.buildReducedModel(full, lock_ids, q_lock) if lock_ids else full
        self.data = self.model.createData()
        self.urdf_path = urdf_path
        self.joint_names = list(joint_names)
        # Reduced-model joint order follows the URDF tree; map it to the caller's order.
        reduced_names = [self.model.names[i] for i in range(1, self.model.njoints)]
        # the caller's joint r is Pinocchio's (reduced) joint pinocchio_index[r]
        self.pinocchio_index = np.array([reduced_names.index(j) for j in self.joint_names])
        self.n = len(self.joint_names)
        if armature:
            for name, value in armature.items():
                if name in reduced_names:
                    self.model.armature[self.model.joints[self.model.getJointId(name)].idx_v] = value
        self.damping = self._in_order(self.model.damping)
        self.friction = self._in_order(self.model.friction)
        self.armature = self._in_order(self.model.armature)
        self.effort_limit = self._in_order(self.model.effortLimit)
        self.lower = self._in_order(self.model.lowerPositionLimit)
        self.upper = self._in_order(self.model.upperPositionLimit)
        self.velocity_limit = self._in_order(self.model.velocityLimit)
        self.body_names = reduced_names  # one moving body per joint, in tree order

    def _in_order(self, vec: np.ndarray) -> np.ndarray:
        return np.asarray(vec, dtype=float)[self.pinocchio_index].copy()

    def _to_pin(self, x: np.ndarray) -> np.ndarray:
        """Samples (N, n) in the caller's joint order -> Pinocchio's, all at once (rows contiguous)."""
        out = np.empty_like(x)
        out[:, self.pinocchio_index] = x
        return out

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Joint torques (N, n) of the nominal model: RNEA with armature, plus URDF damping and friction."""
        q, qd, qdd = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (q, qd, qdd))
        pq, pqd, pqdd = self._to_pin(q), self._to_pin(qd), self._to_pin(qdd)
        # Pinocchio's batched RNEA (one sample per column; the same bits as pin.rnea sample by sample, without a
        # Python call per sample). One thread: the fits that call it already share the rule's cores.
        tau = np.empty((q.shape[1], q.shape[0]), order="F")
        pin.rneaInParallel(1, pin.ModelPool(self.model, 1), pq.T, pqd.T, pqdd.T, tau)
        return tau.T[:, self.pinocchio_index] + self.damping * qd + self.friction * np.sign(qd)

    def inverse_dynamics_derivatives(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """d tau / d(q, qd, qdd) of :meth:`inverse_dynamics` (3, N, n, n), the caller's joint order: Pinocchio's analytic
        RNEA derivatives (armature included) plus the URDF damping (the Coulomb term's sign is flat)."""
        q, qd, qdd = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (q, qd, qdd))
        pq, pqd, pqdd = self._to_pin(q), self._to_pin(qd), self._to_pin(qdd)
        out = np.empty((3, len(q), self.n, self.n))  # Pinocchio's joint order
        for k in range(len(q)):
            out[:, k] = pin.computeRNEADerivatives(self.model, self.data, pq[k], pqd[k], pqdd[k])
        out[2] = np.triu(out[2]) + np.swapaxes(np.triu(out[2], 1), 1, 2)  # Pinocchio fills M's upper triangle only
        out = out[:, :, self.pinocchio_index][:, :, :, self.pinocchio_index]
        out[1] += np.diag(self.damping)
        return out

    def drive_torque(self, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """The drive's part of :meth:`inverse_dynamics` (N, n): armature * qdd + damping * qd + friction * sign(qd).

        What a link-side torque sensor does not see: it sits between the gearbox and the link.
        """
        qd, qdd = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (qd, qdd))
        return self.armature * qdd + self.damping * qd + self.friction * np.sign(qd)

    def gravity(self, q: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, dtype=float))
        pq = self._to_pin(q)
        out = np.empty_like(q)
        for k in range(q.shape[0]):
            out[k] = pin.computeGeneralizedGravity(self.model, self.data, pq[k])
        return out[:, self.pinocchio_index]

    def unit_gravity(self, q: np.ndarray) -> np.ndarray:
        """(N, n, 3) the generalized gravity (the torque that holds the arm still) under unit gravity along the base
        frame's x, y and z: gravity torque is linear in the gravity vector, so under ``g`` it is this times ``g``
        (the nominal model's own is this times ``(0, 0, -9.81)``)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        pq = self._to_pin(q)
        zero = np.zeros_like(pq.T)
        out = np.empty((q.shape[0], self.n, 3))
        model = pin.Model(self.model)  # a copy: the gravity of the model every other call uses stays as it is
        for axis in range(3):
            model.gravity.linear = np.eye(3)[axis]
            tau = np.empty((q.shape[1], q.shape[0]), order="F")
            pin.rneaInParallel(1, pin.ModelPool(model, 1), pq.T, zero, zero, tau)
            out[:, :, axis] = tau.T[:, self.pinocchio_index]
        return out

    def inertial_parameters(self) -> np.ndarray:
        """Dynamic parameters (10 per body, Pinocchio order) of the moving bodies, shape (n_bodies*10,)."""
        return np.concatenate([self.model.inertias[i].toDynamicParameters() for i in range(1, self.model.njoints)])

    def regressor(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Joint-torque regressor, shape (N, n, 10*n_bodies): rnea (without armature) = Y @ params."""
        q, qd, qdd = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (q, qd, qdd))
        pq, pqd, pqdd = self._to_pin(q), self._to_pin(qd), self._to_pin(qdd)
        out = np.empty((q.shape[0], self.n, INERTIAL_PARAMS_PER_BODY * (self.model.njoints - 1)))
        for k in range(q.shape[0]):
            out[k] = np.asarray(pin.computeJointTorqueRegressor(self.model, self.data, pq[k], pqd[k], pqdd[k]))[self.pinocchio_index]
        return out
