"""The consistent fit's convex program (:func:`solve_consistent`): built once per structure, canonicalised by cvxpy,
kept between rounds of the loop (:func:`program_store`), solved by Clarabel for any data and prior weight."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim2real.identification.inertial.geometry import PARAMS_PER_BODY, PD_MARGIN, PSEUDO_BASIS, InertialBlock, pseudo_inertia
from sim2real.identification.inertial.rows import DesignRows, _as_rows, _column_scale, _normal_equations

@dataclass
class ConsistentSolution:
    coefficients: np.ndarray
    status: str  # cvxpy status ("optimal", "optimal_inaccurate", ...)
    solve_time_s: float
    objective: float


class InfeasibleFit(RuntimeError):
    """The convex program has no solution: the constraints contradict each other or the solver failed."""


class _ConsistentProgram:
    """The convex program of :func:`solve_consistent`, built once and solved for any data and weight.

    The data enter through the Gram matrix of the column-scaled design (cvxpy parameters ``root``,
    ``target_root``: ||A z - y||^2 / N = ||R z - c||^2 + const) and the prior's weight through a
    parameter too, so choosing the weight on held-out blocks re-solves the same canonicalised problem
    instead of building a new one per block and weight.
    """

    def __init__(self, size: int, lower: np.ndarray, inertial: InertialBlock | None) -> None:
        import cvxpy as cp

        p = size
        self.scale = np.ones(p)
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
                penalty = penalty + cp.trace(body) - cp.log_det(body) - 4.0
            objective = objective + self.weight * penalty
        self.problem = cp.Problem(cp.Minimize(objective), constraints)
        self.store_path: Path | None = None  # where to keep it once canonicalised (program_store)

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

    def canonicalise(self) -> None:
        """What the first solve does before it solves (cvxpy's canonicalisation), then kept in the program store:
        a program is the same whatever its parameters' values, so placeholders stand in for the data."""
        import cvxpy as cp

        if self.store_path is None:
            return  # read back from the store, or nowhere to keep it
        p = self.z.shape[0]
        self.inverse_scale.value = np.ones(p)
        self.root.value = np.eye(p)
        self.target_root.value = np.zeros(p)
        self.weight.value = 1.0
        self.problem.get_problem_data(cp.CLARABEL)
        self._store()

    def solve_prepared(self, term: _DataTerm, regularization: float) -> ConsistentSolution:
        """Solve a prepared data term (:meth:`prepare`) with the prior's weight ``regularization``."""
        import time

        import cvxpy as cp

        self.scale = term.scale
        self.inverse_scale.value = 1.0 / self.scale
        self.root.value = term.root
        self.target_root.value = term.target_root
        self.weight.value = float(regularization)
        # cvxpy keeps the last solve's Clarabel solver, and a solve after another differs from a first one in the
        # last bits, which the refinements downstream amplify: without it every solve is a first one, so the
        # numbers do not depend on which fit ran before (the diagnosis fits its candidates in parallel).
        getattr(self.problem, "_solver_cache", {}).clear()
        started = time.perf_counter()
        try:
            # One thread: Clarabel's factorisation (faer on rayon) would otherwise start a thread pool that a forked
            # worker (the diagnosis fits its candidates on forked processes) inherits without its threads and waits
            # on forever; and one thread gives the same bits on any number of cores.
            self.problem.solve(solver=cp.CLARABEL, max_threads=1)
        except cp.error.SolverError:
            self.problem.solve(solver=cp.SCS, eps=1e-7, max_iters=20000)
        elapsed = time.perf_counter() - started
        if self.store_path is not None:
            self._store()
        if self.problem.status not in ("optimal", "optimal_inaccurate") or self.z.value is None:
            raise InfeasibleFit(f"the consistent fit found no solution (solver status: {self.problem.status})")
        return ConsistentSolution(np.asarray(self.z.value) / self.scale, str(self.problem.status), elapsed,
                                  float(self.problem.value))

    def _store(self) -> None:
        """Keep the canonicalised program for the next process (the first solve canonicalised it)."""
        import os
        import pickle

        path, self.store_path = self.store_path, None
        assert path is not None
        getattr(self.problem, "_solver_cache", {}).clear()  # a solver is not kept (and cannot be pickled)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            aside = path.with_name(f".{path.name}.{os.getpid()}.tmp")
            aside.write_bytes(pickle.dumps(self, protocol=pickle.HIGHEST_PROTOCOL))
            os.replace(aside, path)
        except OSError:
            pass  # a full disk costs the next round the canonicalisation, nothing else


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


_STORE: list[Path | None] = []  # where programs are kept between processes, the innermost program_store last


@contextlib.contextmanager
def program_store(directory: str | Path | None) -> Iterator[None]:
    """Keep the canonicalised programs in ``directory`` (None: in this process only) while in the block.

    Canonicalising a program costs cvxpy about half a second, solving it tens of milliseconds, and each
    round of the loop is a new process: a program kept on disk is read back in milliseconds instead, and
    a program read back solves to the same bits (its canonical form is the one cvxpy built)."""
    _STORE.append(Path(directory) if directory is not None else None)
    try:
        yield
    finally:
        _STORE.pop()


def _program(size: int, lower: np.ndarray, inertial: InertialBlock | None) -> _ConsistentProgram:
    """The program of this structure (coefficients, bounds, bodies, ellipsoids), built once per process, or
    read back from the :func:`program_store` (canonicalising it takes cvxpy ~0.5 s, solving it tens of
    milliseconds: the rungs, the diagnosis's candidates and the held-out blocks of one round share a handful
    of structures)."""
    import hashlib
    import pickle

    key = hashlib.sha1(np.asarray([size], dtype=np.int64).tobytes() + np.asarray(lower, dtype=float).tobytes())
    if inertial is not None:
        key.update(repr((inertial.columns.start, inertial.columns.stop)).encode())
        key.update(np.asarray(inertial.anchors, dtype=float).tobytes())
        for ellipsoid in inertial.ellipsoids:
            key.update(b"-" if ellipsoid is None else np.asarray(ellipsoid, dtype=float).tobytes())
    digest = key.digest()
    if digest not in _PROGRAMS:
        if len(_PROGRAMS) >= 32:
            _PROGRAMS.pop(next(iter(_PROGRAMS)))
        store = _STORE[-1] if _STORE else None
        path = None
        if store is not None:
            from sim2real.cache import code_digest

            # other code or another cvxpy canonicalises differently: the file's name says which made it
            path = store / f"program-{hashlib.sha1(digest + code_digest().encode()).hexdigest()}.pkl"
        program = None
        if path is not None and path.exists():
            try:
                program = pickle.loads(path.read_bytes())
                path.touch()  # used by this round (sim2real.cache.FitCache.prune keeps it)
            except Exception:  # noqa: BLE001 - an unreadable file is built again
                program = None
        if program is None:
            program = _ConsistentProgram(size, lower, inertial)
            program.store_path = path
        _PROGRAMS[digest] = program
    return _PROGRAMS[digest]


def import_solver() -> None:
    """Import cvxpy now (~0.8 s): a process about to fork workers that solve programs imports it once for all of
    them, instead of once in each (:func:`sim2real.forked.map_forked`)."""
    import cvxpy  # noqa: F401


def build_program(size: int, lower: np.ndarray, inertial: InertialBlock | None) -> None:
    """Canonicalise the program of this structure (:func:`solve_consistent`'s) into the :func:`program_store`
    unless it is there already: another process that needs it reads it back (nothing without a store)."""
    _program(size, lower, inertial).canonicalise()
