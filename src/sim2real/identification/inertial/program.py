"""The consistent fit's convex program (:func:`solve_consistent`): laid out once per structure in Clarabel's
standard form (:mod:`sim2real.identification.inertial.conic`), solved for any data and prior weight."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sim2real.identification.inertial.bands import BodyBounds
from sim2real.identification.inertial.conic import ConicForm, SolverFailed
from sim2real.identification.inertial.geometry import PARAMS_PER_BODY, PD_MARGIN, PSEUDO_BASIS, InertialBlock, pseudo_inertia
from sim2real.identification.inertial.judged import SolveCheck
from sim2real.identification.inertial.rows import DesignRows, _as_rows, _column_scale, _normal_equations

@dataclass
class ConsistentSolution:
    coefficients: np.ndarray
    status: str  # as cvxpy names it ("optimal", "optimal_inaccurate", ...)
    solve_time_s: float
    objective: float
    # how the solver's word was judged (conic.ConicForm.solve); None where SCS solved, or not precisely
    check: SolveCheck | None = None


class InfeasibleFit(RuntimeError):
    """The convex program has no solution: the constraints contradict each other or the solver failed."""


class _ConsistentProgram:
    """The convex program of :func:`solve_consistent`, laid out once per structure and solved for any data and weight.

    The data enter through the Gram matrix of the column-scaled design (``root``, ``target_root``:
    ||A z - y||^2 / N = ||R z - c||^2 + const), so choosing the prior's weight on held-out blocks solves the same
    structure again instead of building it per block and weight. Clarabel solves its conic form
    (:class:`sim2real.identification.inertial.conic.ConicForm`), written directly: nothing is canonicalised; should
    Clarabel fail, the same program written in cvxpy (:class:`_CvxpyProgram`) is solved by SCS.
    """

    def __init__(self, size: int, lower: np.ndarray, inertial: InertialBlock | None) -> None:
        self.structure = (size, np.asarray(lower, dtype=float), inertial)
        self.scale = np.ones(size)
        self.form = ConicForm(size, lower, inertial)

    def solve(self, design: np.ndarray | DesignRows, target: np.ndarray, regularization: float,
              scale: np.ndarray | None = None) -> ConsistentSolution:
        """Solve on rows ``design`` (rows, p) ~ ``target`` (rows,) with the prior's weight ``regularization``;
        ``scale``: the columns' scale (default: their norms on these rows)."""
        return self.solve_prepared(self.prepare(design, target, scale), regularization)

    def prepare(self, design: np.ndarray | DesignRows, target: np.ndarray, scale: np.ndarray | None = None,
                rows: Sequence[slice] | None = None) -> _DataTerm:
        """The data term of rows ``design`` ~ ``target`` as the program takes it (the costly part of a solve:
        the cross-validation solves each training set at every prior weight, so it is computed once);
        ``rows``: only these rows of ``design`` and ``target`` (default: all)."""
        rows = [slice(0, design.shape[0])] if rows is None else list(rows)
        scale = _column_scale(design, rows) if scale is None else scale
        gram, rhs, count = _normal_equations(design, target, scale, rows)
        eigval, eigvec = np.linalg.eigh(gram)
        keep = eigval > 1e-12 * max(eigval.max(), 1e-300)
        root = np.sqrt(np.where(keep, eigval, 0.0))
        count = max(count, 1)
        return _DataTerm(scale, (root[:, None] * eigvec.T) / np.sqrt(count),
                         np.where(keep, (eigvec.T @ rhs) / np.where(keep, root, 1.0), 0.0) / np.sqrt(count))

    def solve_prepared(self, term: _DataTerm, regularization: float, precise: bool = True) -> ConsistentSolution:
        """Solve a prepared data term (:meth:`prepare`) with the prior's weight ``regularization``; ``precise``:
        :meth:`ConicForm.solve`'s."""
        import time

        self.scale = term.scale
        started = time.perf_counter()
        check = None
        try:
            solved = self.form.solve(term.root, term.target_root, float(regularization), 1.0 / self.scale, precise)
            z, status, objective, check = solved.z, solved.status, solved.objective, solved.check
        except SolverFailed:
            z, status, objective = _CvxpyProgram(*self.structure).solve_scs(
                term.root, term.target_root, float(regularization), 1.0 / self.scale)
        elapsed = time.perf_counter() - started
        if status not in ("optimal", "optimal_inaccurate") or z is None:
            raise InfeasibleFit(f"the consistent fit found no solution (solver status: {status})")
        return ConsistentSolution(np.asarray(z) / self.scale, status, elapsed, objective, check)


class _CvxpyProgram:
    """The same program written in cvxpy: SCS's where Clarabel fails, and the reference the conic form is tested
    against (``tests/test_consistent_fit.py``)."""

    def __init__(self, size: int, lower: np.ndarray, inertial: InertialBlock | None) -> None:
        import cvxpy as cp

        p = size
        self.root = cp.Parameter((p, p))
        self.target_root = cp.Parameter(p)
        self.weight = cp.Parameter(nonneg=True)
        self.inverse_scale = cp.Parameter(p, nonneg=True)
        self.z = cp.Variable(p)
        x = cp.multiply(self.inverse_scale, self.z)
        objective = cp.sum_squares(self.root @ self.z - self.target_root)
        constraints = []
        bounded = np.isfinite(lower)
        if bounded.any():
            constraints.append(x[np.flatnonzero(bounded)] >= lower[bounded])
        if inertial is not None:
            start = inertial.columns.start
            penalty = 0
            for b, anchor in enumerate(inertial.anchors):
                # Each body in the metric of its CAD pseudo-inertia J0: J~ = J0^-1/2 J J0^-1/2 is the identity
                # at CAD, so kg and kg*m^2 entries are equally well conditioned; J >= 0 iff J~ >= 0, and the
                # divergence is tr(J~) - log det(J~) - 4.
                w, v = np.linalg.eigh(pseudo_inertia(anchor))
                root_inv = v @ np.diag(w**-0.5) @ v.T
                root = v @ np.diag(w**0.5) @ v.T
                delta = x[start + PARAMS_PER_BODY * b : start + PARAMS_PER_BODY * (b + 1)]
                body = cp.Variable((4, 4), symmetric=True)
                # One affine map per body (16 x 10): far cheaper for cvxpy to canonicalise than a sum of terms.
                lift = np.stack([(root_inv @ PSEUDO_BASIS[k] @ root_inv).reshape(-1) for k in range(PARAMS_PER_BODY)], axis=1)
                expr = cp.reshape(lift @ delta + np.eye(4).reshape(-1), (4, 4), order="C")
                constraints += [body == expr, body >> PD_MARGIN * np.eye(4)]
                ellipsoid = inertial.ellipsoids[b] if b < len(inertial.ellipsoids) else None
                if ellipsoid is not None:
                    constraints.append(cp.trace(body @ (root @ ellipsoid @ root)) >= 0)
                divergence = cp.trace(body) - cp.log_det(body) - 4.0
                if b < len(inertial.bounds):
                    constraints += _band_constraints(inertial.bounds[b], anchor, delta, divergence)
                penalty = penalty + divergence
            objective = objective + self.weight * penalty
        self.problem = cp.Problem(cp.Minimize(objective), constraints)

    def set(self, root: np.ndarray, target_root: np.ndarray, weight: float, inverse_scale: np.ndarray) -> None:
        self.root.value, self.target_root.value = root, target_root
        self.weight.value, self.inverse_scale.value = float(weight), inverse_scale

    def solve_scs(self, root: np.ndarray, target_root: np.ndarray, weight: float,
                  inverse_scale: np.ndarray) -> tuple[np.ndarray | None, str, float]:
        """SCS, where Clarabel failed: (z or None, status, objective)."""
        import cvxpy as cp

        self.set(root, target_root, weight, inverse_scale)
        try:
            self.problem.solve(solver=cp.SCS, eps=1e-7, max_iters=20000)
        except cp.error.SolverError:
            return None, "solver_error", float("nan")
        value = self.problem.value
        return (None if self.z.value is None else np.asarray(self.z.value), str(self.problem.status),
                float(value) if value is not None else float("nan"))


def _band_constraints(bounds: BodyBounds, anchor: np.ndarray, delta, divergence) -> list:
    """A body's mass band, hull and divergence bound (:mod:`~.bands`) on its correction ``delta`` (cvxpy)."""
    lower, upper = bounds.mass
    out = [anchor[0] + delta[0] >= lower]
    if np.isfinite(upper):
        out.append(anchor[0] + delta[0] <= upper)
    if bounds.hull is not None:  # n . h + d m <= 0, h and m the corrected first moment and mass
        hull = np.asarray(bounds.hull, dtype=float)
        out.append(hull[:, :3] @ (anchor[1:4] + delta[1:4]) + hull[:, 3] * (anchor[0] + delta[0]) <= 0)
    if np.isfinite(bounds.divergence):
        out.append(divergence <= bounds.divergence)
    return out


@dataclass
class _DataTerm:
    """A least-squares data term reduced to its square root (p x p) in scaled coefficients."""

    scale: np.ndarray
    root: np.ndarray
    target_root: np.ndarray


def solve_consistent(
    design: np.ndarray | DesignRows,
    target: np.ndarray,
    lower: np.ndarray,
    inertial: InertialBlock | None,
    regularization: float,
) -> ConsistentSolution:
    """Least squares of ``design @ x ~ target`` with the constraints of the module docstring.

    ``design``: (N, n, p) columns in parameter units, already time-shifted; ``target``: (N, n);
    ``lower``: (p,) lower bounds on x (-inf where none); ``regularization``: weight of the entropic
    divergence in (N*m)^2 (the data term is the mean squared residual).
    """
    a, _, _ = _as_rows(design)
    return _program(a.shape[1], lower, inertial).solve(a, target.reshape(-1), regularization)


_PROGRAMS: dict[bytes, _ConsistentProgram] = {}


def _program(size: int, lower: np.ndarray, inertial: InertialBlock | None) -> _ConsistentProgram:
    """The program of this structure (coefficients, bounds, bodies, ellipsoids), laid out once per process: the
    held-out blocks and weights of the prior's choice solve the same structure again."""
    import hashlib

    key = hashlib.sha1(np.asarray([size], dtype=np.int64).tobytes() + np.asarray(lower, dtype=float).tobytes())
    if inertial is not None:
        key.update(repr((inertial.columns.start, inertial.columns.stop)).encode())
        key.update(np.asarray(inertial.anchors, dtype=float).tobytes())
        for ellipsoid in inertial.ellipsoids:
            key.update(b"-" if ellipsoid is None else np.asarray(ellipsoid, dtype=float).tobytes())
        for bound in inertial.bounds:
            key.update(np.asarray([*bound.mass, bound.divergence], dtype=float).tobytes())
            key.update(b"-" if bound.hull is None else np.asarray(bound.hull, dtype=float).tobytes())
    digest = key.digest()
    if digest not in _PROGRAMS:
        if len(_PROGRAMS) >= 32:
            _PROGRAMS.pop(next(iter(_PROGRAMS)))
        _PROGRAMS[digest] = _ConsistentProgram(size, lower, inertial)
    return _PROGRAMS[digest]


def import_solver() -> None:
    """Import what a solve needs (Clarabel, SciPy's sparse matrices, ~0.1 s): a process about to fork workers
    that solve programs imports it once for all of them, instead of once in each (:func:`sim2real.forked.map_forked`)."""
    import clarabel  # noqa: F401
    import scipy.sparse  # noqa: F401
