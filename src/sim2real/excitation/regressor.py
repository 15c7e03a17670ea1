"""Exact state derivatives of Pinocchio's joint-torque regressor: the regressor as a CasADi expression.

The design's objective depends on the samples' states through the regressor Y (N, n, 10 n). Its gradient needs,
per sample, d/d(q, qd, qdd) of sum_jc G_jc Y_jc for the objective's weights G: a vector-Jacobian product. Here one
sample's regressor is written symbolically (RNEA as Pinocchio writes it: motions [linear; angular], gravity as an
upward acceleration of the base), that product is taken by CasADi's reverse mode, and the resulting function is
mapped over the samples: one call for all of them, exact, instead of 3n perturbed regressors per sample.

- forward, each body's spatial velocity and acceleration in its joint frame;
- each body's regressor ``I a + v x* I v`` per dynamic parameter is linear in ``a`` and quadratic in ``v``: one
  constant matrix taken from ``pin.bodyRegressor`` on unit motions, applied to ``[a, v_r v_s]``;
- row i, body b's columns: ``S_i' X* Y_b``, the joint axis S_i carried down to body b's frame dotted with Y_b.

Only 1-DoF revolute and prismatic joints (any axis): those :class:`RigidBodyModel` accepts. Written here because the
``pin`` wheel ships neither Pinocchio's CasADi bindings nor derivatives of the regressor; it is checked against
``pin.computeJointTorqueRegressor`` (tests/test_excitation.py).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pinocchio as pin

from sim2real.assets.dynamics import INERTIAL_PARAMS_PER_BODY, RigidBodyModel

_PAIRS = [(r, s) for r in range(6) for s in range(r, 6)]  # the products v_r v_s the body regressor needs


def _body_regressor_map() -> np.ndarray:
    """M (6 + 21, 6 * 10) with vec(bodyRegressor(v, a)) = [a, v_r v_s (r <= s)] @ M (row-major), from Pinocchio."""
    def vec(v: np.ndarray, a: np.ndarray) -> np.ndarray:
        return np.asarray(pin.bodyRegressor(pin.Motion(v), pin.Motion(a))).ravel()

    zero, eye = np.zeros(6), np.eye(6)
    rows = [vec(zero, eye[c]) for c in range(6)]
    for r, s in _PAIRS:
        if r == s:
            rows.append(vec(eye[r], zero))
        else:  # the cross term of a quadratic form: Q(e_r + e_s) - Q(e_r) - Q(e_s)
            rows.append(vec(eye[r] + eye[s], zero) - vec(eye[r], zero) - vec(eye[s], zero))
    return np.array(rows)


class SymbolicRegressor:
    """One sample's regressor of ``dynamics`` as CasADi SX (rows and states in its joint order), and the mapped
    vector-Jacobian product of it."""

    def __init__(self, dynamics: RigidBodyModel) -> None:
        model = dynamics.model
        self.n = n = model.njoints - 1
        self.width = INERTIAL_PARAMS_PER_BODY * n
        perm = dynamics.pinocchio_index  # the caller's joint r is Pinocchio's joint perm[r]
        q, qd, qdd = (ca.SX.sym(name, n) for name in ("q", "qd", "qdd"))
        pq, pqd, pqdd = ([a[int(np.flatnonzero(perm == i)[0])] for i in range(n)] for a in (q, qd, qdd))
        parents = [int(model.parents[i]) - 1 for i in range(1, model.njoints)]  # -1: the world
        children = [[c for c in range(n) if parents[c] == i] for i in range(n)]
        transforms, subspaces = [], []
        for i in range(n):
            joint = model.joints[i + 1]
            data = joint.createData()
            joint.calc(data, pin.neutral(model)[joint.idx_q : joint.idx_q + joint.nq])
            subspace = np.asarray(data.S.matrix() if hasattr(data.S, "matrix") else data.S, dtype=float).ravel()
            revolute = bool(np.linalg.norm(subspace[3:]) > 0.5)
            off_axis = subspace[:3] if revolute else subspace[3:]
            if joint.nq != 1 or subspace.size != 6 or np.linalg.norm(off_axis) > 1e-12:
                raise ValueError(f"joint {model.names[i + 1]} ({joint.shortname()}) is neither revolute nor prismatic")
            subspaces.append(ca.DM(subspace))
            transforms.append(_child_transform(np.linalg.inv(model.jointPlacements[i + 1].action),
                                               subspace[3:] if revolute else subspace[:3], revolute, pq[i]))
        body_map = _body_regressor_map()
        gravity = np.concatenate([-np.asarray(model.gravity.linear, dtype=float), np.zeros(3)])
        velocities: list[ca.SX] = []
        accelerations: list[ca.SX] = []
        bodies = []
        for i in range(n):
            v = ca.SX.zeros(6) if parents[i] < 0 else transforms[i] @ velocities[parents[i]]
            a = ca.SX(ca.DM(gravity)) if parents[i] < 0 else transforms[i] @ accelerations[parents[i]]
            joint_v = subspaces[i] * pqd[i]
            v = v + joint_v
            a = a + subspaces[i] * pqdd[i] + _motion_cross(v, joint_v)  # + v x (S qd)
            velocities.append(v)
            accelerations.append(a)
            features = ca.vertcat(a, *[v[r] * v[s] for r, s in _PAIRS])
            bodies.append(ca.reshape(ca.mtimes(ca.DM(body_map).T, features), INERTIAL_PARAMS_PER_BODY, 6).T)
        rows = [[ca.SX.zeros(1, INERTIAL_PARAMS_PER_BODY) for _ in range(n)] for _ in range(n)]
        for i in range(n):  # joint i's axis, carried down its subtree
            stack = [(i, ca.SX(subspaces[i]))]
            while stack:
                body, axis = stack.pop()
                rows[i][body] = axis.T @ bodies[body]
                stack.extend((c, transforms[c] @ axis) for c in children[body])
        pin_rows = [ca.horzcat(*row) for row in rows]
        regressor = ca.vertcat(*[pin_rows[int(perm[r])] for r in range(n)])  # (n, 10 n), caller's row order
        weights = ca.SX.sym("weights", n * self.width)  # column-major (n, width), so that samples map to columns
        contracted = ca.sum1(ca.sum2(ca.reshape(weights, n, self.width) * regressor))
        state = ca.vertcat(q, qd, qdd)
        self.function = ca.Function("regressor", [q, qd, qdd], [regressor])
        self._vjp = ca.Function("regressor_vjp", [q, qd, qdd, weights], [ca.gradient(contracted, state)])
        self._mapped: dict[int, ca.Function] = {}

    def __call__(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """(N, n, 10 n) as :meth:`RigidBodyModel.regressor` (for the tests: the design evaluates Pinocchio's)."""
        return np.stack([np.asarray(self.function(q[k], qd[k], qdd[k])) for k in range(len(q))])

    def contracted_gradient(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, weights: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """d/d(q, qd, qdd) of sum_jc weights[k, j, c] Y_k[j, c], per sample: three (N, n)."""
        count, n = q.shape
        if count not in self._mapped:
            self._mapped[count] = self._vjp.map(count, "serial")
        # CasADi's matrices are column-major: sample k is column k, its weights column k of the (n * width) rows.
        flat = np.asarray(weights, dtype=float).transpose(0, 2, 1).reshape(count, -1).T
        out = np.asarray(self._mapped[count](q.T, qd.T, qdd.T, flat))  # (3n, N)
        return out[:n].T, out[n : 2 * n].T, out[2 * n :].T


def _child_transform(placement_inverse: np.ndarray, axis: np.ndarray, revolute: bool, angle: ca.SX) -> ca.SX:
    """The 6 x 6 map of motions from joint i's parent frame to joint i's frame at ``angle``: the placement's inverse,
    then the joint's own motion undone (a rotation about the axis, or a translation along it)."""
    skew = ca.DM(np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]]))
    if revolute:  # R' = I - sin skew + (1 - cos) skew^2 (Rodrigues, angle negated)
        inverse = ca.DM.eye(3) - ca.sin(angle) * skew + (1.0 - ca.cos(angle)) * (skew @ skew)
        joint = ca.diagcat(inverse, inverse)
    else:  # lin -= (d axis) x ang
        joint = ca.blockcat([[ca.DM.eye(3), -angle * skew], [ca.DM.zeros(3, 3), ca.DM.eye(3)]])
    return joint @ ca.DM(placement_inverse)


def _motion_cross(v: ca.SX, m: ca.SX) -> ca.SX:
    """v x m of two motions [lin; ang]."""
    return ca.vertcat(ca.cross(v[3:], m[:3]) + ca.cross(v[:3], m[3:]), ca.cross(v[3:], m[3:]))
