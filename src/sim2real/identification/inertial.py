"""Physically consistent inertial identification: one convex program for a whole model rung.

The rung's prediction is linear in its coefficients ``x`` (link inertial corrections, friction,
armature, bias, ...), so the fit is a least-squares problem. Physical consistency enters as convex
constraints (Wensing, Kim and Slotine 2017, "Linear Matrix Inequalities for Physically Consistent
Inertial Parameter Identification"):

* every corrected body's 4x4 pseudo-inertia ``J(pi) = [[Sigma, h], [h^T, m]]`` is positive definite,
  which implies m > 0, the triangle inequalities and a density that exists;
* where the body's bounding ellipsoid is known from its meshes, ``tr(J Q) >= 0``: the mass lies
  inside the ellipsoid (centre of mass inside the body), a strictly stronger condition;
* per-coefficient lower bounds (friction, damping and armature totals >= 0, payload mass >= 0).

A regulariser keeps what the data cannot see at the CAD values: the entropic (Bregman) divergence
of Lee and Park 2018, ``d(J, J0) = tr(J0^-1 J) - log det(J J0^-1) - 4``, summed over bodies. It is
geometric (invariant to the body's frame and units), zero at the CAD body and a barrier at the
boundary of the consistent set, so the solution is strictly consistent. Its weight is a fraction of
the noise floor's variance: a correction the data see costs far more in the data term than in the
divergence, a direction they do not see is pulled to CAD. The fraction is chosen on held-out blocks
of the fit runs (:func:`choose_prior_weight`): the strongest pull whose held-out error is within 1%
of the best, not a number set by hand.

Why a semidefinite program (cvxpy, Clarabel) rather than the log-Cholesky parametrisation with
scipy's least squares (Rucker and Wensing 2022, ``pin.LogCholeskyParameters``): the problem is
convex, so the SDP returns the global optimum with a certificate and no start point, with the
friction/armature bounds and the ellipsoid LMIs as plain constraints. It works on the p x p Gram
matrix of the design (p ~ 90 coefficients on a 7-joint arm), so its size does not grow with the
number of samples. Measured on the Panda (``benchmarks/bench_sysid.py``): the solve takes tens of
milliseconds, beside the ~1 s that computing the regressor and the nonlinear refinement take, so the
consistent rung costs about the same as the unconstrained one. Log-Cholesky is unconstrained but
non-convex in the data term, needs a start inside the set and handles bounds only by clipping.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim2real import blas

PARAMS_PER_BODY = 10  # Pinocchio order: m, m*c (3), I about the body frame (xx, xy, yy, xz, yz, zz)
PD_MARGIN = 1e-4  # smallest eigenvalue kept, relative to the CAD body's pseudo-inertia (J >= 1e-4 J0)


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


# d(pseudo-inertia)/d(parameter k): the pseudo-inertia is linear in the parameters.
PSEUDO_BASIS = np.array([pseudo_inertia(np.eye(PARAMS_PER_BODY)[k]) for k in range(PARAMS_PER_BODY)])


def min_eigenvalues(params: np.ndarray) -> np.ndarray:
    """Smallest pseudo-inertia eigenvalue of every body of a stacked parameter vector."""
    bodies = np.asarray(params, dtype=float).reshape(-1, PARAMS_PER_BODY)
    return np.array([np.linalg.eigvalsh(pseudo_inertia(b)).min() for b in bodies])


def physically_consistent(params: np.ndarray) -> bool:
    return bool(np.all(min_eigenvalues(params) > 0))


def entropic_divergence(params: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Lee-Park divergence of every body from its reference (inf where a body is not consistent)."""
    out = []
    for p, r in zip(np.reshape(params, (-1, 10)), np.reshape(reference, (-1, 10)), strict=True):
        j, j0 = pseudo_inertia(p), pseudo_inertia(r)
        sign, logdet = np.linalg.slogdet(np.linalg.solve(j0, j))
        out.append(float(np.trace(np.linalg.solve(j0, j)) - logdet - 4.0) if sign > 0 else np.inf)
    return np.asarray(out)


def ellipsoid_matrix(center: np.ndarray, axes: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Q of the ellipsoid {x : [x; 1]^T Q [x; 1] >= 0} with semi-axes ``axes`` along ``rotation``'s columns."""
    shape = rotation @ np.diag(1.0 / np.asarray(axes, dtype=float) ** 2) @ rotation.T
    center = np.asarray(center, dtype=float)
    q = np.zeros((4, 4))
    q[:3, :3] = -shape
    q[:3, 3] = shape @ center
    q[3, :3] = shape @ center
    q[3, 3] = 1.0 - center @ shape @ center
    return q


def bounding_ellipsoid(points: np.ndarray) -> np.ndarray:
    """Q of an ellipsoid holding every point: the one through the corners of their oriented bounding box."""
    import trimesh

    to_box, extents = trimesh.bounds.oriented_bounds(np.asarray(points, dtype=float))
    frame = np.linalg.inv(to_box)
    axes = np.sqrt(3.0) / 2.0 * np.maximum(np.asarray(extents, dtype=float), 1e-3)
    return ellipsoid_matrix(frame[:3, 3], axes, frame[:3, :3])


def inside_ellipsoids(params: np.ndarray, ellipsoids: Sequence[np.ndarray | None]) -> list[bool]:
    """tr(J Q) >= 0 per body (True where no ellipsoid is known)."""
    bodies = np.asarray(params, dtype=float).reshape(-1, PARAMS_PER_BODY)
    return [q is None or float(np.trace(pseudo_inertia(b) @ q)) >= -1e-12 for b, q in zip(bodies, ellipsoids)]


@dataclass
class InertialBlock:
    """Where the link corrections sit among the coefficients, and what they correct.

    ``columns``: slice of the design's coefficients that are per-body corrections (10 per body,
    parameter units); ``anchors``: the parameters the corrections are added to, body by body (the
    URDF link that receives them: consistency of it implies consistency of the whole body, which
    also holds the fixed links merged into it); ``ellipsoids``: bounding ellipsoid Q per body or None.
    """

    columns: slice
    anchors: np.ndarray  # (n_bodies, 10)
    ellipsoids: list[np.ndarray | None] = field(default_factory=list)

    @property
    def n_bodies(self) -> int:
        return len(self.anchors)


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
            self.problem.solve(solver=cp.CLARABEL)
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


CHUNK_ROWS = blas.CHUNK_ROWS  # the long sums' chunk (sim2real.blas), a name of this module the tests can vary


class DesignRows:
    """The rows (samples x joints, p) of a design whose columns are kept as blocks (N, n, k_i), each joint's
    rows multiplied by its weight: rows are put together when asked for (``design[a:b]``), a chunk at a time,
    so the whole weighted design (on a long log the largest array of a fit) never exists. The rows are the
    bits ``(np.concatenate(blocks, axis=2) * weights[None, :, None]).reshape(-1, p)[a:b]`` would hold."""

    def __init__(self, blocks: Sequence[np.ndarray], weights: np.ndarray) -> None:
        self.blocks = list(blocks)
        self.weights = np.asarray(weights, dtype=float)
        self.samples, self.joints = self.blocks[0].shape[:2]
        self.shape = (self.samples * self.joints, sum(b.shape[2] for b in self.blocks))
        self._whole: np.ndarray | None = None
        self._norms: np.ndarray | None = None  # column_norms over all rows, once

    def __getitem__(self, rows: slice) -> np.ndarray:
        start, stop, step = rows.indices(self.shape[0])
        assert step == 1, "rows are taken as one contiguous range"
        if self.shape[0] <= CHUNK_ROWS:  # a design of one chunk (the demo's) is put together once, then viewed
            if self._whole is None:
                self._whole = self._rows(0, self.shape[0])
            return self._whole[start:stop]
        return self._rows(start, stop)

    def _rows(self, start: int, stop: int) -> np.ndarray:
        first, last = start // self.joints, -(-stop // self.joints)
        part = np.concatenate([b[first:last] for b in self.blocks], axis=2)
        part *= self.weights[None, :, None]
        offset = first * self.joints
        return part.reshape(-1, self.shape[1])[start - offset : stop - offset]


def _as_rows(design: np.ndarray | DesignRows) -> tuple[np.ndarray | DesignRows, int, int]:
    """A design (N, n, p) as its rows (N * n, p) (a view, or the :class:`DesignRows` themselves), N and n."""
    if isinstance(design, DesignRows):
        return design, design.samples, design.joints
    return design.reshape(-1, design.shape[2]), design.shape[0], design.shape[1]


def _chunks(rows: Sequence[slice]) -> list[list[slice]]:
    """``rows`` (slices) cut into groups of at most CHUNK_ROWS rows; one group when they fit in one."""
    groups: list[list[slice]] = [[]]
    size = 0
    for part in rows:
        start = part.start
        while start < part.stop:
            stop = min(part.stop, start + CHUNK_ROWS - size)
            groups[-1].append(slice(start, stop))
            size += stop - start
            start = stop
            if size == CHUNK_ROWS:
                groups.append([])
                size = 0
    return [g for g in groups if g]


def _rows_of(a: np.ndarray | DesignRows, group: Sequence[slice]) -> np.ndarray:
    """The rows of ``group`` (a view when it is one slice)."""
    return a[group[0]] if len(group) == 1 else np.concatenate([a[part] for part in group])


def column_norms(a: np.ndarray | DesignRows, rows: Sequence[slice] | None = None) -> np.ndarray:
    """The Euclidean norm of each column of ``a`` (rows x columns) over ``rows`` (default: all), summed chunk
    by chunk (CHUNK_ROWS); numpy's own norm when the rows fit in one chunk."""
    every_row = [slice(0, a.shape[0])]
    if isinstance(a, DesignRows) and (rows is None or list(rows) == every_row):
        if a._norms is None:  # the consistent fit and the bootstrap both scale the same rows
            a._norms = _column_norms(a, every_row)
        return a._norms.copy()
    return _column_norms(a, every_row if rows is None else rows)


def _column_norms(a: np.ndarray | DesignRows, rows: Sequence[slice]) -> np.ndarray:
    groups = _chunks(rows)
    if len(groups) == 1:
        return np.linalg.norm(_rows_of(a, groups[0]), axis=0)
    return np.sqrt(sum(np.sum(_rows_of(a, group) ** 2, axis=0) for group in groups))


def _column_scale(a: np.ndarray | DesignRows, rows: Sequence[slice] | None = None) -> np.ndarray:
    # Scaled coefficients z = x * norm (unit-norm columns): a well-conditioned data term.
    norms = column_norms(a, rows)
    return np.where(norms > 1e-12 * max(norms.max(), 1e-300), norms, 1.0)


def _normal_equations(design: np.ndarray | DesignRows, target: np.ndarray, scale: np.ndarray,
                      rows: Sequence[slice]) -> tuple[np.ndarray, np.ndarray, int]:
    """Gram matrix and right-hand side of the column-scaled rows, summed chunk by chunk; the row count."""
    gram = np.zeros((design.shape[1], design.shape[1]))
    rhs = np.zeros(design.shape[1])
    count = 0
    for k, group in enumerate(_chunks(rows)):
        an = _rows_of(design, group) / scale
        y = _rows_of(target, group)
        if k == 0:
            gram, rhs = an.T @ an, an.T @ y
        else:
            gram += an.T @ an
            rhs += an.T @ y
        count += y.size
    return gram, rhs, count


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


# The prior's weights first tried on held-out blocks, as fractions of the noise floor's variance: from a pull the
# data always outweigh (1e-4) to one that moves the prediction by about a tenth of the floor (0.1). The search
# goes on past either edge while the held-out score says it should (choose_prior_weight), a decade at a time,
# within PRIOR_BOUNDS. A stiffer prior cannot hand a candidate a fall it did not earn: the diagnosis fits every
# candidate with the current rung's weight (sim2real.identification.sysid).
PRIOR_GRID = (1e-4, 1e-3, 1e-2, 1e-1)
PRIOR_BOUNDS = (1e-8, 1e2)
PRIOR_BLOCKS = 4
# Among weights whose held-out error is within this fraction of the best, the strongest pull to CAD wins:
# what the held-out data cannot tell apart, the CAD decides (plausible inertias at no cost in fit).
PRIOR_TOLERANCE = 0.01


def _squared_residual(design: np.ndarray | DesignRows, target: np.ndarray, rows: slice, x: np.ndarray) -> float:
    """Sum of squares of ``design[rows] @ x - target[rows]``, chunk by chunk (CHUNK_ROWS; one sum when they fit)."""
    groups = _chunks([rows])
    if len(groups) == 1:
        return float(np.sum((_rows_of(design, groups[0]) @ x - _rows_of(target, groups[0])) ** 2))
    return float(sum(np.sum((_rows_of(design, g) @ x - _rows_of(target, g)) ** 2) for g in groups))


@dataclass
class PriorChoice:
    """The inertial prior's weight chosen on held-out blocks: ``weight`` and each ``grid`` weight's
    held-out RMS ``scores`` (fractions of the floor's variance; RMS in the data term's units), the grid in
    increasing order as searched; ``bound``: ``"weakest"`` or ``"strongest"`` when the choice sits at the
    search's bound (:data:`PRIOR_BOUNDS`: the held-out data would have gone on), else None."""

    weight: float
    grid: list[float]
    scores: list[float]
    blocks: int
    bound: str | None = None


def choose_prior_weight(
    design: np.ndarray | DesignRows,
    target: np.ndarray,
    lower: np.ndarray,
    inertial: InertialBlock,
    floor_variance: float,
    grid: Sequence[float] = PRIOR_GRID,
    blocks: int = PRIOR_BLOCKS,
    bounds: tuple[float, float] = PRIOR_BOUNDS,
) -> PriorChoice:
    """The prior's weight by cross-validation on ``blocks`` contiguous blocks of the fit rows.

    Each weight (x ``floor_variance``) is fitted on all blocks but one and scored on the one left out; the
    score is the held-out RMS over every block. Contiguous blocks in time, not random rows: neighbouring
    samples share their noise and motion, so a random split would reward fitting it. The strongest pull
    whose score is within :data:`PRIOR_TOLERANCE` of the best is chosen. The search starts on ``grid`` and
    goes past its edges a decade at a time, never beyond ``bounds``: weaker while the weakest weight scores
    best (the data still ask for freer inertias), stronger while the strongest is still within tolerance
    (the held-out data do not yet pay for the pull). So the choice is inside the searched range unless a
    bound stopped it, which :attr:`PriorChoice.bound` says.
    """
    flat, samples, joints = _as_rows(design)  # samples x joints rows
    p = flat.shape[1]
    flat_target = target.reshape(-1)
    limits = [(int(b[0]), int(b[-1]) + 1) for b in np.array_split(np.arange(samples), blocks)]
    scale = _column_scale(flat)
    program = _program(p, lower, inertial)
    terms = []
    for start, stop in limits:
        # the training rows are the blocks before and after the held one, in time order
        train = [part for part in (slice(0, start * joints), slice(stop * joints, flat.shape[0])) if part.stop > part.start]
        terms.append((program.prepare(flat, flat_target, scale, train), slice(start * joints, stop * joints)))

    def score(relative: float) -> float:
        squared = 0.0
        for term, held in terms:
            solution = program.solve_prepared(term, relative * floor_variance)
            squared += _squared_residual(flat, flat_target, held, solution.coefficients)
        return float(np.sqrt(squared / max(target.size, 1)))

    weights = sorted(float(g) for g in grid)
    scores = [score(g) for g in weights]
    bound = None
    while True:
        best = min(scores)
        if scores[0] == best and weights[0] > bounds[0] * (1 + 1e-9):
            weights.insert(0, max(weights[0] / 10.0, bounds[0]))
            scores.insert(0, score(weights[0]))
        elif scores[-1] <= best * (1.0 + PRIOR_TOLERANCE) and weights[-1] < bounds[1] * (1 - 1e-9):
            weights.append(min(weights[-1] * 10.0, bounds[1]))
            scores.append(score(weights[-1]))
        else:
            break
    best = min(scores)
    chosen_index = max(i for i, s in enumerate(scores) if s <= best * (1.0 + PRIOR_TOLERANCE))
    if scores[0] == best and chosen_index == 0 and len(weights) > 1 and weights[0] <= bounds[0] * (1 + 1e-9):
        bound = "weakest"
    elif chosen_index == len(weights) - 1 and weights[-1] >= bounds[1] * (1 - 1e-9):
        bound = "strongest"
    return PriorChoice(weights[chosen_index], weights, scores, len(limits), bound)
