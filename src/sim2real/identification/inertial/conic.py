"""The consistent fit's program in Clarabel's standard form, written directly (:class:`ConicForm`).

The program of :mod:`sim2real.identification.inertial.program` has one fixed shape: a least-squares data term,
lower bounds, and per body a PSD margin, an ellipsoid, the bands of :mod:`~.bands` (mass, hull: linear rows;
divergence: a linear row on the log-det's ``t``) and the entropic divergence's log-det. Its conic form is
written here in a few array operations per solve, so a fit never canonicalises (cvxpy takes 0.3-0.7 s per program
structure and about a second to import, and every new rung and candidate is a new structure):

    minimise  1/2 x'Px + q'x   subject to  Ax + s = b,  s in K

with ``x = [z | per body: Z (its 10 lower-triangular entries), t (4)]``, ``z`` the scaled coefficients. The data
term ||R z - c||^2 is ``P = 2 R'R``, ``q = -2 R'c``; a body's ``J~ = I + L diag(s) z_b`` (``L`` the lift of its
10 coefficients, ``s`` the inverse column scale) enters ``J~ - margin I`` in a 4x4 PSD cone, ``tr(J~ M) >= 0``
(the ellipsoid) in the nonnegative cone, and ``-log det J~`` as ``-sum t`` with ``[[J~, Z], [Z', diag Z]]`` in an
8x8 PSD cone and ``(t_i, 1, Z_ii)`` in exponential cones (the standard log-det cone, as cvxpy writes it). PSD
cones are Clarabel's upper triangles, column by column, off-diagonal entries times sqrt(2).
``tests/test_consistent_fit.py`` checks the solutions against the same program written in cvxpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sim2real.identification.inertial.geometry import PARAMS_PER_BODY, PD_MARGIN, PSEUDO_BASIS, InertialBlock, pseudo_inertia
from sim2real.identification.inertial.judged import SolveCheck

# Clarabel's statuses, named as cvxpy names them.
SOLVED = {"Solved": "optimal", "AlmostSolved": "optimal_inaccurate"}
NO_SOLUTION = {"PrimalInfeasible": "infeasible", "DualInfeasible": "unbounded",
               "AlmostPrimalInfeasible": "infeasible_inaccurate", "AlmostDualInfeasible": "unbounded_inaccurate",
               "MaxIterations": "user_limit", "MaxTime": "user_limit"}

_SQRT2 = np.sqrt(2.0)


# The precise solve's tolerances (Clarabel's tol_feas and tol_gap_*; its defaults are 1e-8).
PRECISE_TOLERANCE = 1e-11

# Clarabel's step towards the cone's boundary, as a fraction of the longest feasible one (its default 0.99), on a
# solve that stopped with InsufficientProgress: on the UR5's and the Panda's held-out blocks the default step stalls
# within 5-30 iterations on some prior weights, a step of 0.9 solves every one of them in about 30 (SCS, the
# fallback after, takes ~100x as long).
SHORT_STEP_FRACTION = 0.9


@dataclass(frozen=True)
class ConicSolution:
    """A solve's scaled coefficients (None without a solution), its status as cvxpy names it, its objective, and how
    a precise solve's status was judged (:class:`~sim2real.identification.inertial.judged.SolveCheck`; None for a
    solve that is not precise or found no solution)."""

    z: np.ndarray | None
    status: str
    objective: float
    check: SolveCheck | None


class SolverFailed(RuntimeError):
    """Clarabel stopped on a numerical error: another solver may do."""


def _triangle(n: int) -> list[tuple[int, int, float]]:
    """(row, column, scale) of an n x n PSD cone's entries in Clarabel's order: upper triangle, by column."""
    return [(r, c, 1.0 if r == c else _SQRT2) for c in range(n) for r in range(c + 1)]


_LOWER4 = [(a, b) for a in range(4) for b in range(a + 1)]  # Z's lower-triangular entries, as laid out in x


@dataclass
class _Rows:
    """A block of constraint rows: A's entries ``value * inverse_scale[scaled_by]`` (1 where ``scaled_by`` < 0) at
    ``(row, column)``, and the rows' b."""

    rows: list[int] = field(default_factory=list)
    cols: list[int] = field(default_factory=list)
    vals: list[float] = field(default_factory=list)
    scaled_by: list[int] = field(default_factory=list)
    b: list[float] = field(default_factory=list)

    def entry(self, row: int, col: int, value: float, scaled_by: int = -1) -> None:
        self.rows.append(row)
        self.cols.append(col)
        self.vals.append(value)
        self.scaled_by.append(scaled_by)


class ConicForm:
    """The program of one structure (``size`` coefficients, their ``lower`` bounds, the bodies of ``inertial``),
    with everything that does not depend on the data laid out once; :meth:`solve` takes the data term, the prior's
    weight and the column scale."""

    def __init__(self, size: int, lower: np.ndarray, inertial: InertialBlock | None) -> None:
        self.p = int(size)
        lower = np.asarray(lower, dtype=float)
        self.bounded = np.flatnonzero(np.isfinite(lower))
        self.lower = lower[self.bounded]
        bodies = [] if inertial is None else list(enumerate(inertial.anchors))
        self.bodies = len(bodies)
        self.anchors = [np.asarray(anchor, dtype=float) for _, anchor in bodies]
        self.bounds = [] if inertial is None else list(inertial.bounds)
        self.n = self.p + 14 * self.bodies
        # Per body: its columns, the lift of its coefficients into J~ (16 x 10), tr(lift_k) (the divergence's
        # linear part) and, with an ellipsoid, tr(lift_k M) and tr(M).
        self.columns: list[np.ndarray] = []
        self.lifts: list[np.ndarray] = []
        self.traces: list[np.ndarray] = []
        self.ellipsoids: list[tuple[np.ndarray, float] | None] = []
        for b, anchor in bodies:
            assert inertial is not None
            w, v = np.linalg.eigh(pseudo_inertia(anchor))
            root_inv = v @ np.diag(w**-0.5) @ v.T
            root = v @ np.diag(w**0.5) @ v.T
            lift = np.stack([root_inv @ PSEUDO_BASIS[k] @ root_inv for k in range(PARAMS_PER_BODY)], axis=2)  # 4x4x10
            start = inertial.columns.start + PARAMS_PER_BODY * b
            self.columns.append(np.arange(start, start + PARAMS_PER_BODY))
            self.lifts.append(lift)
            self.traces.append(np.trace(lift, axis1=0, axis2=1))
            ellipsoid = inertial.ellipsoids[b] if b < len(inertial.ellipsoids) else None
            if ellipsoid is None:
                self.ellipsoids.append(None)
            else:
                m = root @ np.asarray(ellipsoid, dtype=float) @ root
                self.ellipsoids.append((np.einsum("ijk,ji->k", lift, m), float(np.trace(m))))
        self._layout()

    def _z_var(self, b: int, entry: int) -> int:
        return self.p + 14 * b + entry  # Z's entries first, then t's four

    def _layout(self) -> None:
        """A's entries (a coefficient's column scale multiplies its own), b and the cones: the same at every solve."""
        nonneg, cones_psd, exp = _Rows(), _Rows(), _Rows()
        for i, low in zip(self.bounded, self.lower, strict=True):  # s = x_i - lower_i >= 0, x = z / scale
            nonneg.entry(len(nonneg.b), int(i), -1.0, int(i))
            nonneg.b.append(-low)
        psd_sizes: list[int] = []
        for b in range(self.bodies):
            cols, lift = self.columns[b], self.lifts[b]  # J~ = I + lift . (z_b / scale_b)
            if self.ellipsoids[b] is not None:
                ell, trace = self.ellipsoids[b]
                row = len(nonneg.b)
                for k, col in enumerate(cols):
                    nonneg.entry(row, int(col), -ell[k], int(col))
                nonneg.b.append(trace)
            if b < len(self.bounds):
                self._band_rows(nonneg, b)
            # J~ - margin I in a 4x4 cone
            for r, c, sigma in _triangle(4):
                row = len(cones_psd.b)
                for k, col in enumerate(cols):
                    if lift[r, c, k] != 0.0:
                        cones_psd.entry(row, int(col), -sigma * lift[r, c, k], int(col))
                cones_psd.b.append(sigma * (1.0 - PD_MARGIN) if r == c else 0.0)
            psd_sizes.append(4)
            # [[J~, Z], [Z', diag Z]] in an 8x8 cone
            for r, c, sigma in _triangle(8):
                row = len(cones_psd.b)
                value = 0.0
                if c < 4:  # J~'s block
                    for k, col in enumerate(cols):
                        if lift[r, c, k] != 0.0:
                            cones_psd.entry(row, int(col), -sigma * lift[r, c, k], int(col))
                    value = sigma if r == c else 0.0
                elif r < 4:  # Z's block: Z[r, c-4], lower-triangular
                    if r >= c - 4:
                        cones_psd.entry(row, self._z_var(b, _LOWER4.index((r, c - 4))), -sigma)
                elif r == c:  # diag Z
                    cones_psd.entry(row, self._z_var(b, _LOWER4.index((r - 4, r - 4))), -1.0)
                cones_psd.b.append(value)
            psd_sizes.append(8)
            for a in range(4):  # (t_a, 1, Z_aa) in the exponential cone: exp(t_a) <= Z_aa
                row = len(exp.b)
                exp.entry(row, self._z_var(b, 10 + a), -1.0)
                exp.entry(row + 2, self._z_var(b, _LOWER4.index((a, a))), -1.0)
                exp.b.extend([0.0, 1.0, 0.0])
        blocks = [nonneg, cones_psd, exp]
        offsets = np.cumsum([0] + [len(block.b) for block in blocks])
        self.a_rows = np.concatenate([np.asarray(block.rows, dtype=np.int64) + off
                                      for block, off in zip(blocks, offsets, strict=False)])
        self.a_cols = np.concatenate([np.asarray(block.cols, dtype=np.int64) for block in blocks])
        self.a_vals = np.concatenate([np.asarray(block.vals, dtype=float) for block in blocks])
        self.a_scaled_by = np.concatenate([np.asarray(block.scaled_by, dtype=np.int64) for block in blocks])
        self.m = int(offsets[-1])
        self.b = np.concatenate([np.asarray(block.b, dtype=float) for block in blocks])
        self.cone_sizes = (len(nonneg.b), psd_sizes, 4 * self.bodies)

    def _band_rows(self, nonneg: _Rows, b: int) -> None:
        """Body ``b``'s mass band, hull and divergence bound (:mod:`~.bands`) as nonnegative slacks ``b - A x``, with
        ``x`` its correction (the mass its first column, the first moment the next three) added to its anchor."""
        bounds, anchor, cols = self.bounds[b], self.anchors[b], self.columns[b]
        lower, upper = bounds.mass
        mass = int(cols[0])
        nonneg.entry(len(nonneg.b), mass, -1.0, mass)  # m0 + dm - lower >= 0
        nonneg.b.append(float(anchor[0] - lower))
        if np.isfinite(upper):  # upper - m0 - dm >= 0
            nonneg.entry(len(nonneg.b), mass, 1.0, mass)
            nonneg.b.append(float(upper - anchor[0]))
        if bounds.hull is not None:  # -(n . (h0 + dh) + d (m0 + dm)) >= 0, facet by facet
            for facet in np.asarray(bounds.hull, dtype=float):
                row = len(nonneg.b)
                nonneg.entry(row, mass, float(facet[3]), mass)
                for k in range(3):
                    if facet[k] != 0.0:
                        nonneg.entry(row, int(cols[1 + k]), float(facet[k]), int(cols[1 + k]))
                nonneg.b.append(-float(facet[:3] @ anchor[1:4] + facet[3] * anchor[0]))
        if np.isfinite(bounds.divergence):  # D - (tr J~ - 4 - sum t) >= 0, tr J~ = 4 + tr(lift_k) x_k
            row = len(nonneg.b)
            for k, col in enumerate(cols):
                if self.traces[b][k] != 0.0:
                    nonneg.entry(row, int(col), float(self.traces[b][k]), int(col))
            for a in range(4):
                nonneg.entry(row, self._z_var(b, 10 + a), -1.0)
            nonneg.b.append(float(bounds.divergence))

    def _constraints(self, inverse_scale: np.ndarray) -> tuple[object, np.ndarray, list]:
        """A (CSC), b and Clarabel's cones at the column scale ``inverse_scale``."""
        import clarabel
        import scipy.sparse as sp

        factor = np.where(self.a_scaled_by >= 0, np.asarray(inverse_scale, dtype=float)[np.maximum(self.a_scaled_by, 0)], 1.0)
        a = sp.csc_matrix((self.a_vals * factor, (self.a_rows, self.a_cols)), shape=(self.m, self.n))
        nonneg, psd_sizes, exp = self.cone_sizes
        cones = ([clarabel.NonnegativeConeT(nonneg)] if nonneg else []) + [
            clarabel.PSDTriangleConeT(n) for n in psd_sizes] + [clarabel.ExponentialConeT() for _ in range(exp)]
        return a, self.b, cones

    def _problem(self, root: np.ndarray, target_root: np.ndarray, weight: float,
                 inverse_scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The data term's Gram block of P and q of the program at this data, weight and column scale."""
        p = self.p
        gram = 2.0 * (root.T @ root)
        q = np.zeros(self.n)
        q[:p] = -2.0 * (root.T @ target_root)
        for b in range(self.bodies):  # weight * (tr J~ - sum t - 4): tr J~ = 4 + tr(lift_k) s_k z_k
            cols_b = self.columns[b]
            q[cols_b] += weight * self.traces[b] * inverse_scale[cols_b]
            q[self._z_var(b, 10) : self._z_var(b, 14)] = -weight
        return gram, q

    def solve(self, root: np.ndarray, target_root: np.ndarray, weight: float,
              inverse_scale: np.ndarray, precise: bool = True, tolerance: float | None = None) -> ConicSolution:
        """min ||root z - target_root||^2 + weight * (the bodies' divergence) under the constraints (:class:`ConicSolution`).
        Clarabel on one thread: a forked worker inherits no thread
        pool, and any number of cores gives the same bits. Its tolerances are ``tolerance`` (:data:`PRECISE_TOLERANCE`, 1e-11), a thousandth of its
        defaults: a few more iterations of a 30 ms solve, and the solution then moves by ~1e-6 of itself between two
        equivalent forms of the program (cvxpy's and this one), rather than 1e-4, in the flat directions the prior holds.
        Should that stall, it solves again at its default tolerances, then with a shorter step (:data:`SHORT_STEP_FRACTION`);
        raises :class:`SolverFailed` if that fails too.
        A solution Clarabel calls almost solved is judged by its measured residuals, and polished when they fall short
        (:func:`sim2real.identification.inertial.judged.judge`).
        ``precise=False``: 1e-6 from the start (the prior's held-out scores, compared within 1 %: a score then moves by
        up to 2e-4 of itself, a fiftieth of that, and a fold's solve takes a fifth fewer iterations), taken as it comes."""
        import clarabel
        import scipy.sparse as sp

        from sim2real.identification.inertial.judged import judge, measure

        gram, q = self._problem(root, target_root, weight, inverse_scale)
        rows, cols = np.triu_indices(self.p)
        big_p = sp.csc_matrix((gram[rows, cols], (rows, cols)), shape=(self.n, self.n))
        a, b_vec, cones = self._constraints(inverse_scale)

        def attempt(tight: bool, short_step: bool = False) -> object:
            settings = clarabel.DefaultSettings()
            settings.verbose = False
            settings.max_threads = 1
            if tight:
                settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = tolerance or PRECISE_TOLERANCE
                settings.tol_ktratio = 1e-9
            elif not precise:
                settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = 1e-6
            if short_step:
                settings.max_step_fraction = SHORT_STEP_FRACTION
            return clarabel.DefaultSolver(big_p, q, a, b_vec, cones, settings).solve()

        # (tight tolerances, short step) of each attempt, until one ends
        attempts = ((True, False), (False, False), (False, True)) if precise else ((False, False), (False, True))
        for tight, short_step in attempts:
            solution = attempt(tight, short_step)
            status = str(solution.status)
            if status in SOLVED or status in NO_SOLUTION:
                break
        if status in NO_SOLUTION:
            return ConicSolution(None, NO_SOLUTION[status], float("nan"), None)
        if status not in SOLVED:
            raise SolverFailed(f"Clarabel stopped: {status}")
        check = None
        if precise:
            solution, check = judge(solution, lambda: attempt(False) if tight else solution,
                                    lambda s: measure(gram, q, a, b_vec, s))
            status = "Solved" if check.status == "optimal" else "AlmostSolved"
        return ConicSolution(np.asarray(solution.x, dtype=float)[: self.p], SOLVED[status],
                             float(solution.obj_val) + float(target_root @ target_root), check)
