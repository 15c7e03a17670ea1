"""What a trajectory lets the fit identify: the regressor of the current model on its samples.

The columns are those the fit estimates (:mod:`sim2real.identification.fitting`): Pinocchio's inertial regressor of
the moving bodies plus each effect's columns (:meth:`sim2real.identification.effects.base.Effect.columns`) at its
default nonlinear parameters. Effects that move the inertias (``link_inertia``, ``payload``) live in the
inertial columns; a delay has none. Without a friction effect in the model, viscous and Coulomb friction
are added: every identification of a real arm has to separate friction from inertia.

Not all of those columns are identifiable from joint torques: the **base** columns are chosen once, on
random states spanning the limits, by QR with column pivoting (Gautier 1990): a set of independent
columns whose span holds every other. A trajectory is then judged on its base columns, each joint's rows
divided by that joint's noise floor (so a wrist 10x quieter weighs as much as a shoulder):

- ``d_optimal``: -log det(W'W), the volume of the parameters' confidence ellipsoid;
- ``condition``: log of the condition number of W with unit-norm columns (invariant to the units).

Both come with their gradient with respect to each sample's state: the columns of a sample depend on
that sample alone. The inertial columns' part is exact (:mod:`.regressor`: CasADi's reverse mode on the
regressor); the effects' few diagonal columns are differenced centrally, batched.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.linalg

from sim2real.assets.dynamics import INERTIAL_PARAMS_PER_BODY
from sim2real.excitation.config import identification_effects  # noqa: F401  (re-exported: the design's columns)
from sim2real.excitation.regressor import SymbolicRegressor
from sim2real.identification.effects import EFFECTS
from sim2real.identification.effects.base import Effect, Signals
from sim2real.identification.fitting import NominalModel

BASE_SAMPLES = 400
BASE_TOLERANCE = 1e-6  # |R_ii| / |R_00| of the unit-norm columns below this: a dependent column
FD_STEP = 1e-6


class Identification:
    """The identification columns of ``effects`` on the nominal model, reduced to a base."""

    def __init__(self, nominal: NominalModel, effects: Sequence[str], noise_floor: np.ndarray | None,
                 lower: np.ndarray, upper: np.ndarray, velocity: np.ndarray, acceleration: np.ndarray,
                 seed: int = 0) -> None:
        self.nominal = nominal
        self.dynamics = nominal.dynamics
        self.effect_names = list(effects)
        self.effects: list[Effect] = [EFFECTS[name] for name in self.effect_names]
        n = self.dynamics.n
        self.row_weight = np.ones(n) if noise_floor is None else 1.0 / np.asarray(noise_floor, dtype=float)
        rng = np.random.default_rng(seed)
        q = rng.uniform(lower, upper, size=(BASE_SAMPLES, n))
        qd = rng.uniform(-velocity, velocity, size=(BASE_SAMPLES, n))
        qdd = rng.uniform(-acceleration, acceleration, size=(BASE_SAMPLES, n))
        probe = self._signals(q, qd, qdd)
        self._nonlinear = [effect.nonlinear_init(probe) for effect in self.effects]
        full = self.full(q, qd, qdd).reshape(-1, self.width)
        norms = np.linalg.norm(full, axis=0)
        active = np.flatnonzero(norms > 1e-9 * norms.max())
        _, r, pivots = scipy.linalg.qr(full[:, active] / norms[active], mode="economic", pivoting=True)
        diagonal = np.abs(np.diag(r))
        rank = int(np.sum(diagonal > BASE_TOLERANCE * diagonal[0]))
        self.base = np.sort(active[pivots[:rank]])  # base columns in their natural order
        self.inertial_width = INERTIAL_PARAMS_PER_BODY * (self.dynamics.model.njoints - 1)
        self._symbolic: SymbolicRegressor | None = None  # built when a gradient is first asked for

    @property
    def size(self) -> int:
        return len(self.base)

    def _signals(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> Signals:
        count = len(q)
        dynamics = self.dynamics
        needs_nominal = any(effect.scales_judged or effect.needs_model_torque for effect in self.effects)
        tau_nominal = dynamics.inverse_dynamics(q, qd, qdd) if needs_nominal else np.zeros_like(q)
        return Signals(joint_names=list(dynamics.joint_names), time=np.arange(count, dtype=float), q=q, qd=qd,
                       qdd=qdd, tau_nominal=tau_nominal, segments=[slice(0, count)],
                       regressor_fn=lambda: dynamics.regressor(q, qd, qdd), nominal=self.nominal.info,
                       gravity_fn=lambda: dynamics.unit_gravity(q))

    @property
    def width(self) -> int:
        return self._width

    def full(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Every column (N, n, p): the inertial regressor, then each effect's columns."""
        signals = self._signals(q, qd, qdd)
        out = np.concatenate([signals.regressor, self._effect_columns(signals)], axis=2)
        self._width = out.shape[2]
        return out

    def _effect_columns(self, signals: Signals) -> np.ndarray:
        """The effects' columns (N, n, p - inertial), at their default nonlinear parameters."""
        nonlinear = getattr(self, "_nonlinear", None)
        blocks = [np.zeros((len(signals.q), signals.n, 0))]
        for k, effect in enumerate(self.effects):
            init = nonlinear[k] if nonlinear is not None else effect.nonlinear_init(signals)
            blocks.append(effect.columns(signals, {}, init)[0])
        return np.concatenate(blocks, axis=2)

    def columns(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """The weighted base columns (N, n, r): each joint's rows divided by its noise floor (read-only).

        The last state's are kept: IPOPT asks for the gradient at the point whose value its line search has just
        accepted, and the regressor is most of either's cost."""
        key = (q.tobytes(), qd.tobytes(), qdd.tobytes())
        if getattr(self, "_last_columns", (None, None))[0] != key:
            columns = self.full(q, qd, qdd)[:, :, self.base] * self.row_weight[None, :, None]
            columns.flags.writeable = False
            self._last_columns = (key, columns)
        return self._last_columns[1]

    def matrix(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """The stacked weighted regressor W (N*n, r)."""
        return self.columns(q, qd, qdd).reshape(-1, self.size)

    def value(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, objective: str) -> float:
        """The objective alone: what IPOPT's line search asks for, at a fraction of the gradient's cost."""
        return objective_value(self.matrix(q, qd, qdd), objective)

    def state_gradient(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, objective: str
                       ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """The objective and its gradient with respect to q, qd and qdd of each sample (each (N, n))."""
        count, n = q.shape
        base = self.columns(q, qd, qdd)
        value, dw = objective_and_gradient(base.reshape(-1, self.size), objective)
        weights = np.zeros((count, n, self.width))  # d objective / d every unweighted column
        weights[:, :, self.base] = dw.reshape(base.shape) * self.row_weight[None, :, None]
        if self._symbolic is None:
            self._symbolic = SymbolicRegressor(self.dynamics)
        grad = np.stack(self._symbolic.contracted_gradient(q, qd, qdd, weights[:, :, : self.inertial_width]))
        effect_weights = weights[:, :, self.inertial_width :]
        if np.any(effect_weights):
            # Central differences of the effects' columns alone: 3n perturbations each way, every sample at once.
            states = [np.repeat(a[None], 6 * n, axis=0) for a in (q, qd, qdd)]
            for which in range(3):
                for j in range(n):
                    states[which][which * n + j, :, j] += FD_STEP
                    states[which][3 * n + which * n + j, :, j] -= FD_STEP
            signals = self._signals(*(s.reshape(-1, n) for s in states))
            moved = self._effect_columns(signals).reshape(2, 3 * n, count, n, -1)
            difference = np.einsum("scjr,cjr->sc", moved[0] - moved[1], effect_weights) / (2 * FD_STEP)
            grad += difference.reshape(3, n, count).transpose(0, 2, 1)
        return value, grad[0], grad[1], grad[2]


def _unit_columns(w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """W with unit-norm columns (V), the norms and the Gram matrix V'V: the objectives need no more than the
    Gram matrix (r x r), not a factorisation of the tall W."""
    norms = np.linalg.norm(w, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    v = w / norms
    return v, norms, v.T @ v


def objective_value(w: np.ndarray, objective: str) -> float:
    """The design objective (minimised) of the stacked regressor (:func:`objective_and_gradient` without the
    gradient)."""
    _, norms, gram = _unit_columns(w)
    if objective == "d_optimal":
        chol = np.linalg.cholesky(gram + 1e-12 * np.eye(len(gram)))
        return -2.0 * float(np.sum(np.log(np.diag(chol)))) - 2.0 * float(np.sum(np.log(norms)))
    if objective == "condition":
        eigenvalues = np.linalg.eigvalsh(gram)
        return 0.5 * float(np.log(eigenvalues[-1] / eigenvalues[0]))
    raise ValueError(f"unknown objective {objective}")


def objective_and_gradient(w: np.ndarray, objective: str) -> tuple[float, np.ndarray]:
    """The design objective (minimised) of the stacked regressor and its gradient with respect to it."""
    v, norms, gram = _unit_columns(w)
    if objective == "d_optimal":
        # -log det(W'W) = -log det(V'V) - 2 sum log norms; d/dW = -2 W (W'W)^-1 = -2 V (V'V)^-1 / norms.
        chol = np.linalg.cholesky(gram + 1e-12 * np.eye(len(gram)))
        value = -2.0 * float(np.sum(np.log(np.diag(chol)))) - 2.0 * float(np.sum(np.log(norms)))
        return value, -2.0 * np.linalg.solve(gram, v.T).T / norms
    if objective == "condition":
        # log(s_max / s_min) of V from the eigenpairs (s^2, e) of V'V: d s_k / dV = u_k e_k' with u_k = V e_k / s_k,
        # so d/dV = V (e_max e_max' / s_max^2 - e_min e_min' / s_min^2).
        eigenvalues, vectors = np.linalg.eigh(gram)
        value = 0.5 * float(np.log(eigenvalues[-1] / eigenvalues[0]))
        largest, smallest = vectors[:, -1], vectors[:, 0]
        dv = v @ (np.outer(largest, largest) / eigenvalues[-1] - np.outer(smallest, smallest) / eigenvalues[0])
        # Through the normalisation: d v_c / d w_c = (I - v_c v_c') / |w_c|.
        return value, (dv - v * np.sum(v * dv, axis=0)) / norms
    raise ValueError(f"unknown objective {objective}")


def condition_number(w: np.ndarray) -> float:
    """Condition number of the stacked regressor with unit-norm columns (independent of parameter units)."""
    norms = np.linalg.norm(w, axis=0)
    s = np.linalg.svd(w / np.where(norms > 0, norms, 1.0), compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
