"""The excitation's finite Fourier series and the linear maps from its coefficients to the motion.

Per joint j, with base frequency w and harmonics l = 1..L:

    q_j(t)   = q_start_j + sum_l a_jl/(w l) sin(w l t) - b_jl/(w l) (cos(w l t) - 1)
    qd_j(t)  = sum_l a_jl cos(w l t) + b_jl sin(w l t)
    qdd_j(t) = sum_l -a_jl w l sin(w l t) + b_jl w l cos(w l t)

so q(0) = q_start by construction, and the trajectory is periodic with period 2 pi / w. It starts (and,
over a whole number of periods, ends) at rest when sum_l a_jl = 0 (qd(0) = 0) and sum_l l b_jl = 0
(qdd(0) = 0): two linear equalities per joint that the design imposes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FourierSeries:
    """The series of ``n_joints`` excited joints; coefficients x are [a_j1..a_jL, b_j1..b_jL] per joint."""

    omega: float  # rad/s
    harmonics: int
    n_joints: int

    @property
    def period(self) -> float:
        return 2.0 * np.pi / self.omega

    @property
    def size(self) -> int:
        return 2 * self.harmonics * self.n_joints

    def basis(self, time: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(K, 2L) matrices P, V, A with q_j - q_start_j = P @ x_j, qd_j = V @ x_j, qdd_j = A @ x_j."""
        wl = self.omega * np.arange(1, self.harmonics + 1)
        arg = np.outer(np.asarray(time, dtype=float), wl)
        sin, cos = np.sin(arg), np.cos(arg)
        position = np.hstack([sin / wl, -(cos - 1.0) / wl])
        velocity = np.hstack([cos, sin])
        acceleration = np.hstack([-sin * wl, cos * wl])
        return position, velocity, acceleration

    def motion(self, x: np.ndarray, time: np.ndarray, start: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, qd, qdd (K, n_joints) of the excited joints at ``time``."""
        coeffs = np.asarray(x, dtype=float).reshape(self.n_joints, 2 * self.harmonics)
        position, velocity, acceleration = self.basis(time)
        return start + position @ coeffs.T, velocity @ coeffs.T, acceleration @ coeffs.T

    def rest_constraints(self) -> np.ndarray:
        """(2 n_joints, size) matrix E with E @ x = 0 iff every joint starts at rest (qd = qdd = 0 at t = 0)."""
        length = self.harmonics
        rows = np.zeros((2 * self.n_joints, self.size))
        for j in range(self.n_joints):
            start = 2 * length * j
            rows[2 * j, start : start + length] = 1.0
            rows[2 * j + 1, start + length : start + 2 * length] = np.arange(1, length + 1)
        return rows

    def joint_maps(self, time: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Block-diagonal maps (K*n_joints, size), rows sample-major then joint: q - start, qd, qdd = M @ x."""
        position, velocity, acceleration = self.basis(time)
        eye = np.eye(self.n_joints)
        return tuple(_interleave(np.kron(eye, b), len(time), self.n_joints) for b in (position, velocity, acceleration))


def _interleave(block: np.ndarray, samples: int, joints: int) -> np.ndarray:
    """Rows of kron(I_joints, B) are joint-major; reorder them sample-major (row k*joints + j)."""
    order = (np.arange(joints)[None, :] * samples + np.arange(samples)[:, None]).ravel()
    return block[order]


def random_start(series: FourierSeries, rng: np.random.Generator) -> np.ndarray:
    """Random coefficients at rest at t = 0 (projected onto the rest constraints), not yet scaled."""
    x = rng.normal(size=series.size)
    rest = series.rest_constraints()
    return x - np.linalg.pinv(rest) @ (rest @ x)
