"""A run that tells two confounded candidates apart: maximise the difference of their predicted torques.

When the diagnosis lists two candidate effects as ``confounded`` (they predict the same torque on the runs
to within a tenth of the noise floor), the data cannot choose. Each candidate was fitted (its coefficients
are in the diagnosis's evidence); the run to record next is the one on which their predictions differ most,
each joint in units of its noise floor, within the same limits as any design:

    minimise  -log( mean_k sum_j ((tau_a(x_k) - tau_b(x_k)) / floor_j)^2 )

where tau_c is candidate c's own term (its columns times its fitted coefficients); the rest of the model is
common to both. Same interface as :class:`sim2real.excitation.information.Identification`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.identification.diagnosis.result import Candidate
from sim2real.identification.effects import EFFECTS
from sim2real.identification.effects.base import Signals
from sim2real.errors import InputError
from sim2real.identification.fitting import NominalModel

FD_STEP = 1e-6


def fitted_candidates(ladder: Mapping[str, Any], pair: Sequence[str], path: str) -> list[Candidate]:
    """The diagnosis's candidates of the pair (body link, then the actuator link), each with its coefficients."""
    sections = [ladder, ladder.get("actuator") or {}]
    for section in sections:
        diagnosis = section.get("diagnosis") or {}
        found = {c["effect"]: c for c in diagnosis.get("candidates", [])}
        if all(name in found for name in pair):
            out = []
            for name in pair:
                try:
                    out.append(Candidate.from_document(found[name]))
                except KeyError as exc:
                    raise InputError(path, f"diagnosis candidate {name}", f"has no `{exc.args[0]}` (a ladder.json of an older release)",
                                     "rebuild it with this version: snakemake results/{robot}/gap.json") from exc
            return out
    raise InputError(path, "diagnosis/candidates", f"{' and '.join(pair)} were not both tried on the current rung",
                     "design a separating run only for a pair gap.md lists as not told apart")


class Separation:
    """The predicted-torque difference of two fitted candidates as a design objective."""

    def __init__(self, nominal: NominalModel, candidates: Sequence[Candidate], noise_floor: np.ndarray,
                 path: str) -> None:
        self.nominal = nominal
        self.dynamics = nominal.dynamics
        self.effects = []
        for candidate in candidates:
            effect = EFFECTS[candidate.effect]
            if type(effect).prepare is not type(EFFECTS["viscous_friction"]).prepare:
                raise InputError(path, f"diagnosis candidate {effect.name}",
                                 "depends on a basis computed from the fit data (an inertial effect)",
                                 "separate effects with their own columns (friction, rotor inertia, gains, biases)")
            self.effects.append((effect, np.asarray(candidate.evidence.linear_coefficients, dtype=float),
                                 np.asarray(candidate.evidence.nonlinear_coefficients, dtype=float)))
        self.row_weight = 1.0 / np.asarray(noise_floor, dtype=float)
        self.names = [c.effect for c in candidates]

    def difference(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """(tau_a - tau_b) / floor at each sample (N, n)."""
        count = len(q)
        dynamics = self.dynamics
        needs_nominal = any(effect.scales_judged or effect.needs_model_torque for effect, _, _ in self.effects)
        signals = Signals(joint_names=list(dynamics.joint_names), time=np.arange(count, dtype=float), q=q, qd=qd,
                          qdd=qdd, tau_nominal=dynamics.inverse_dynamics(q, qd, qdd) if needs_nominal
                          else np.zeros_like(q), segments=[slice(0, count)],
                          regressor_fn=lambda: dynamics.regressor(q, qd, qdd), nominal=self.nominal.info,
                       gravity_fn=lambda: dynamics.unit_gravity(q))
        terms = [effect.columns(signals, {}, nonlinear)[0] @ linear for effect, linear, nonlinear in self.effects]
        return (terms[0] - terms[1]) * self.row_weight

    def value(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, objective: str = "separate") -> float:
        return -float(np.log(np.mean(np.sum(self.difference(q, qd, qdd) ** 2, axis=1)) + 1e-300))

    def state_gradient(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, objective: str = "separate"
                       ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        count, n = q.shape
        diff = self.difference(q, qd, qdd)
        energy = float(np.mean(np.sum(diff**2, axis=1)))
        states = [np.repeat(a[None], 3 * n, axis=0) for a in (q, qd, qdd)]
        for which in range(3):
            for j in range(n):
                states[which][which * n + j, :, j] += FD_STEP
        moved = self.difference(*(s.reshape(-1, n) for s in states)).reshape(3 * n, count, n)
        # d(-log E)/d state = -(2 / (N E)) sum_j diff_j d diff_j / d state
        grad = -2.0 / (count * energy) * np.einsum("scj,cj->sc", (moved - diff[None]) / FD_STEP, diff)
        return -float(np.log(energy + 1e-300)), grad[:n].T, grad[n : 2 * n].T, grad[2 * n :].T

    def rms_x_floor(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> float:
        """RMS over samples and joints of the predicted difference, in floor units."""
        return float(np.sqrt(np.mean(self.difference(q, qd, qdd) ** 2)))
