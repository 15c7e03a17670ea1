"""Link inertial parameters: corrections to mass, first moment and inertia of every moving body.

Only the identifiable combinations (base parameters) are fitted: the stacked regressor of the
fit data is reduced by SVD to the directions it excites, and the correction is the minimum-norm
one in those directions, so unexcited directions keep their nominal (URDF) values. The fit then
keeps the result physically consistent (every body's 4x4 pseudo-inertia positive definite) by
shrinking the correction towards the nominal model when it is not.
Pinocchio's dynamic parameter order per body: m, m*c (3), I about the joint frame
(xx, xy, yy, xz, yz, zz).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.effects.base import ColumnLabel, Effect, ParameterSpec, Signals, explained_per_joint, per_joint_dict

RELATIVE_SINGULAR_TOL = 1e-3  # directions excited 1000x less than the best are left at nominal
STRUCTURAL_ZERO = 1e-9  # relative column norm below which a parameter does not act at all


def parameter_scales(inertial: np.ndarray) -> np.ndarray:
    """Typical size of each dynamic parameter of each body: m, m*0.1 m, m*(0.1 m)^2."""
    scales = []
    for b in range(len(inertial) // 10):
        mass = max(abs(float(inertial[10 * b])), 0.1)
        scales.append([mass] + [0.1 * mass] * 3 + [0.01 * mass] * 6)
    return np.asarray(scales, dtype=float).reshape(-1)


def pseudo_inertia(params: np.ndarray) -> np.ndarray:
    """4x4 pseudo-inertia matrix of one body's 10 dynamic parameters (PD iff physically consistent)."""
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = params
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    sigma = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    h = np.array([hx, hy, hz])
    out = np.zeros((4, 4))
    out[:3, :3] = sigma
    out[:3, 3] = h
    out[3, :3] = h
    out[3, 3] = m
    return out


def physically_consistent(params: np.ndarray, n_bodies: int) -> bool:
    return all(
        np.linalg.eigvalsh(pseudo_inertia(params[10 * b : 10 * b + 10])).min() > 0 for b in range(n_bodies)
    )


def to_mass_com_inertia(params: np.ndarray) -> dict[str, Any]:
    """One body's dynamic parameters -> mass, center of mass, inertia about the COM (xx, xy, xz, yy, yz, zz)."""
    m = float(params[0])
    c = np.asarray(params[1:4]) / m if abs(m) > 1e-12 else np.zeros(3)
    ixx, ixy, iyy, ixz, iyz, izz = params[4:10]
    origin = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    com_inertia = origin - m * (float(c @ c) * np.eye(3) - np.outer(c, c))
    return {
        "mass": round(m, 6),
        "com": [round(float(v), 6) for v in c],
        "inertia": [round(float(com_inertia[i, k]), 8) for i, k in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))],
    }


def min_eigenvalues(params: np.ndarray, n_bodies: int) -> np.ndarray:
    return np.array([np.linalg.eigvalsh(pseudo_inertia(params[10 * b : 10 * b + 10])).min() for b in range(n_bodies)])


# d(pseudo-inertia)/d(parameter k) for one body: the pseudo-inertia is linear in the parameters.
_PSEUDO_BASIS = np.array([pseudo_inertia(np.eye(10)[k]) for k in range(10)])


def _min_eigen_gradients(params: np.ndarray, n_bodies: int) -> tuple[np.ndarray, np.ndarray]:
    """Smallest eigenvalue per body and its gradient w.r.t. all parameters (n_bodies, 10*n_bodies)."""
    values = np.zeros(n_bodies)
    grads = np.zeros((n_bodies, 10 * n_bodies))
    for b in range(n_bodies):
        w, v = np.linalg.eigh(pseudo_inertia(params[10 * b : 10 * b + 10]))
        values[b] = w[0]
        grads[b, 10 * b : 10 * b + 10] = np.einsum("i,kij,j->k", v[:, 0], _PSEUDO_BASIS, v[:, 0])
    return values, grads


def consistent_null_offset(nominal: np.ndarray, delta: np.ndarray, null: np.ndarray, n_bodies: int) -> np.ndarray:
    """Smallest move along the weakly identified directions that makes every body consistent.

    Those directions hardly change the predicted torque, so the fit keeps its quality. Returns the
    best offset found (parameter units); the caller checks consistency and shrinks if still needed.
    """
    from scipy import optimize

    margin = np.minimum(1e-7, 0.5 * np.clip(min_eigenvalues(nominal, n_bodies), 0.0, None))
    if np.all(min_eigenvalues(nominal + delta, n_bodies) > margin):
        return np.zeros_like(delta)
    if null.shape[1] == 0:
        return np.zeros_like(delta)
    start = nominal + delta

    def constraint(z: np.ndarray) -> np.ndarray:
        return _min_eigen_gradients(start + null @ z, n_bodies)[0] - margin

    def constraint_jac(z: np.ndarray) -> np.ndarray:
        return _min_eigen_gradients(start + null @ z, n_bodies)[1] @ null

    result = optimize.minimize(
        lambda z: float(z @ z), np.zeros(null.shape[1]), jac=lambda z: 2 * z, method="SLSQP",
        constraints=[{"type": "ineq", "fun": constraint, "jac": constraint_jac}],
        options={"maxiter": 150, "ftol": 1e-10},
    )
    return null @ result.x


def consistent_shrink(nominal: np.ndarray, delta: np.ndarray, n_bodies: int) -> float:
    """Largest alpha in [0, 1] with nominal + alpha*delta physically consistent (bisection)."""
    if physically_consistent(nominal + delta, n_bodies):
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if physically_consistent(nominal + mid * delta, n_bodies):
            lo = mid
        else:
            hi = mid
    return lo


class LinkInertia(Effect):
    in_urdf = True
    name = "link_inertia"
    summary = "wrong link masses, centers of mass or inertias in the robot description"
    signature = "residual explained by the rigid-body regressor (gravity- and acceleration-shaped)"
    parameters = (
        ParameterSpec("mass", "kg", 0.0, 100.0, True, "mass of the body moved by each joint (total)"),
        ParameterSpec("com", "m", -2.0, 2.0, True, "center of mass in the joint frame"),
        ParameterSpec("inertia", "kg*m^2", -10.0, 10.0, True, "inertia about the COM (xx, xy, xz, yy, yz, zz)"),
    )
    joint_local = False

    def prepare(self, signals: Signals) -> dict[str, Any]:
        y = signals.regressor.reshape(-1, signals.regressor.shape[2])
        n_params = y.shape[1]
        # Work in relative units (parameter / its typical size on that body): the minimum-norm
        # correction and the consistency move are then the smallest *relative* changes to the URDF.
        scale = parameter_scales(np.asarray(signals.nominal["inertial"]))
        yw = y * scale
        norms = np.linalg.norm(yw, axis=0)
        # Parameters that (numerically) never act on the measured joints are not identifiable at all.
        active = np.flatnonzero(norms > STRUCTURAL_ZERO * norms.max())
        ya = yw[:, active]
        # Eigen-decomposition of the Gram matrix = SVD of the stacked regressor, much cheaper.
        eigval, eigvec = np.linalg.eigh(ya.T @ ya)
        order = np.argsort(eigval)[::-1]
        singular = np.sqrt(np.clip(eigval[order], 0.0, None))
        rank = int(np.sum(singular > RELATIVE_SINGULAR_TOL * singular[0]))
        # Basis in parameter units: delta = basis @ beta. The rest of the space barely changes the
        # torque on these data: the fit moves along it only to stay physically consistent.
        basis = np.zeros((n_params, rank))
        basis[active] = eigvec[:, order[:rank]] * scale[active, None]
        weak = np.zeros((n_params, len(active) - rank))
        weak[active] = eigvec[:, order[rank:]] * scale[active, None]
        inactive = np.setdiff1d(np.arange(n_params), active)
        structural = np.zeros((n_params, len(inactive)))
        structural[inactive, np.arange(len(inactive))] = scale[inactive]
        null = np.hstack([weak, structural])
        return {"basis": basis, "null": null, "rank": rank, "null_offset": np.zeros(n_params)}

    def offset(self, signals, state, theta):
        if not np.any(state["null_offset"]):
            return None
        return signals.regressor @ state["null_offset"]

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        basis = state["basis"]
        return signals.regressor @ basis, [ColumnLabel(f"base_{i}") for i in range(basis.shape[1])]

    def values(self, theta, nonlinear, signals, state):
        delta = state["basis"] @ theta + state["null_offset"]
        nominal = np.asarray(signals.nominal["inertial"])
        total = nominal + delta
        bodies = signals.nominal["body_links"]
        # The URDF link alone (without the fixed links Pinocchio merged into its body) plus the
        # correction: what the calibrated URDF's <inertial> must say.
        own = signals.nominal.get("link_own_inertial", {})
        urdf_links = {
            link: to_mass_com_inertia(np.asarray(own[link]) + delta[10 * b : 10 * b + 10])
            for b, link in enumerate(bodies)
            if link in own
        }
        return {
            "links": {link: to_mass_com_inertia(total[10 * b : 10 * b + 10]) for b, link in enumerate(bodies)},
            "urdf_links": urdf_links,
            "base_parameters": int(state["rank"]),
            "physically_consistent": bool(physically_consistent(total, len(bodies))),
        }

    def evidence(self, residual, signals):
        return {
            "signature": self.signature,
            "statistic": "per-joint R^2 of residual on the rigid-body regressor",
            "per_joint": per_joint_dict(signals.joint_names, explained_per_joint(residual, signals.regressor), 3),
        }

    def apply_to_spec(self, spec, values, context):
        # The MJCF is built from the calibrated URDF, which already carries these values.
        return

    def calibration(self, values, calibration):
        for link, inertial in values.get("urdf_links", {}).items():
            xx, xy, xz, yy, yz, zz = inertial["inertia"]
            calibration.setdefault("links", {})[link] = {
                "mass": inertial["mass"],
                "com": list(inertial["com"]),
                "inertia": {"ixx": xx, "ixy": xy, "ixz": xz, "iyy": yy, "iyz": yz, "izz": zz},
            }
