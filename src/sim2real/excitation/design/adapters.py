"""CasADi adapters: a numeric function of the coefficients with its numeric Jacobian as a CasADi function (IPOPT
asks for both), and a numeric matrix as a CasADi sparse one."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import casadi as ca
import numpy as np
import scipy.sparse


class _Numeric(ca.Callback):
    """A numeric function of the coefficients with its numeric Jacobian, as a CasADi function."""

    def __init__(self, name: str, input_size: int, output_size: int, value: Callable[[np.ndarray], np.ndarray],
                 jacobian: Callable[[np.ndarray], np.ndarray]) -> None:
        ca.Callback.__init__(self)
        self.input_size, self.output_size, self.value, self.jac = input_size, output_size, value, jacobian
        self.construct(name, {})

    def get_n_in(self) -> int:
        return 1

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self.input_size, 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self.output_size, 1)

    def eval(self, arg: Sequence[Any]) -> list[np.ndarray]:
        return [np.asarray(self.value(np.asarray(arg[0]).ravel()), dtype=float).reshape(-1, 1)]

    def has_jacobian(self) -> bool:
        return True

    def get_jacobian(self, name: str, inames: Any, onames: Any, opts: Any) -> ca.Callback:
        self._jacobian = _Jacobian(name, self)  # CasADi holds no reference: keep one
        return self._jacobian


class _Jacobian(ca.Callback):
    def __init__(self, name: str, parent: _Numeric) -> None:
        ca.Callback.__init__(self)
        self.parent = parent
        self.construct(name, {})

    def get_n_in(self) -> int:
        return 2

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self.parent.input_size if i == 0 else self.parent.output_size, 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self.parent.output_size, self.parent.input_size)

    def eval(self, arg: Sequence[Any]) -> list[np.ndarray]:
        return [np.asarray(self.parent.jac(np.asarray(arg[0]).ravel()), dtype=float)]


def _sparse(matrix: np.ndarray) -> ca.DM:
    """A CasADi sparse matrix: each joint's limit rows touch its own coefficients only, and IPOPT's KKT system
    stays small when CasADi knows it."""
    return ca.DM(scipy.sparse.csc_matrix(matrix))
