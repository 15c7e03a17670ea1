"""One model on one data set: the design at given nonlinear parameters (``_Problem``), the linear solve
with the nonlinear parameters projected out, their refinement by bounded least squares, and the
fitted values (:class:`FitResult`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
# Imported with the module, not when first needed: it loads scipy's own BLAS, which run_sysid's one-thread
# limit (threadpoolctl) holds only if it is loaded by then, and the fit's last bits depend on it.
from scipy import optimize

from sim2real.identification.effects import Effect, Signals
from sim2real.identification.effects.actuation_delay import MAX_DELAY, shift_prediction
from sim2real.identification import inertial
from sim2real.identification.fitting.data import kept_segments


PREDICT_CHUNK_BYTES = 32 * 2**20  # the design's rows put together at once by _Problem.predict
# An effect's columns at its last nonlinear parameters are kept up to this size (the fit, its consistent variant,
# the predictions and the bootstrap ask for them in turn); a long log's larger blocks are computed again instead
# of staying alive beside the arrays of the next steps.
KEPT_BLOCK_BYTES = 16 * 2**20


@dataclass
class FitResult:
    effects: list[str]
    theta: dict[str, np.ndarray]  # linear coefficients per effect
    nonlinear: dict[str, np.ndarray]
    states: dict[str, dict[str, Any]]
    values: dict[str, Any]  # fitted values per effect (total, SI)
    intervals: dict[str, Any]
    fit_rmse: dict[str, Any]
    notes: list[str] = field(default_factory=list)
    consistency: dict[str, Any] = field(default_factory=dict)
    unconstrained: FitResult | None = None  # the same rung without the physical constraints
    after_sensor: bool = False  # the body link behind a link-side sensor: drive effects are the part after it


class _Problem:
    """Columns and targets of one model on one data set, for a given nonlinear parameter vector."""

    def __init__(self, effects: list[Effect], signals: Signals, states: dict[str, dict[str, Any]],
                 weights: np.ndarray | None = None, reuse_design: bool = False) -> None:
        self.effects = effects
        self.signals = signals
        self.states = states
        # Per-joint weights of the data term (joint_weights): the fit solves in units of each joint's floor.
        self.weights = np.ones(signals.n) if weights is None else np.asarray(weights, dtype=float)
        self.static_columns: dict[str, np.ndarray] = {}
        for effect in effects:
            if not effect.time_shift and not effect.nonlinear:
                self.static_columns[effect.name] = effect.columns(signals, states[effect.name], np.array([]))[0]
        self.nl_sizes = [len(e.nonlinear_init(signals)) for e in effects]
        # reuse_design: each design() writes the moving columns into the last one's array, the static ones stay
        # (the refinement asks for hundreds; a caller must be done with one design before it asks for the next)
        self._reused: tuple[np.ndarray, list[int], list[tuple[Effect, slice]]] | None = None
        self.reuse_design = reuse_design
        self._kept: dict[str, tuple[bytes, np.ndarray]] = {}  # effect -> (its nonlinear parameters, its columns)
        self._weighted: tuple[list[np.ndarray], inertial.DesignRows] | None = None

    def split_nonlinear(self, x: np.ndarray) -> dict[str, np.ndarray]:
        out, start = {}, 0
        for effect, size in zip(self.effects, self.nl_sizes, strict=True):
            out[effect.name] = np.asarray(x[start : start + size], dtype=float)
            start += size
        return out

    def delay(self, nonlinear: dict[str, np.ndarray]) -> float:
        """Time shift of the prediction: the command leads what it causes by the actuation delay."""
        for effect in self.effects:
            if effect.time_shift:
                delay = float(nonlinear[effect.name][0])
                return -delay if self.signals.forward else delay
        return 0.0

    def block(self, effect: Effect, nonlinear: dict[str, np.ndarray]) -> np.ndarray:
        """One effect's columns (N, n, k) at the given nonlinear parameters (before the time shift)."""
        cols = self.static_columns.get(effect.name)
        if cols is None:
            key = np.asarray(nonlinear[effect.name], dtype=float).tobytes()
            kept = self._kept.get(effect.name)
            if kept is not None and kept[0] == key:
                cols = kept[1]
            else:
                cols = effect.columns(self.signals, self.states[effect.name], nonlinear[effect.name])[0]
                if cols.nbytes <= KEPT_BLOCK_BYTES and not self.reuse_design:  # the refinement's move every step
                    self._kept[effect.name] = (key, cols)
        if self.signals.forward and effect.drive:
            cols = -cols  # forward, the drive's terms are taken from the command before the link-side sensor
        return cols

    def shift(self, columns: np.ndarray, effects: Sequence[Effect], sizes: Sequence[int],
              nonlinear: dict[str, np.ndarray]) -> np.ndarray:
        """Columns as they enter the prediction: shifted by the delay, except a drive's on the actuator link
        (the command is delayed; the rotor inertia and friction act on the motion as it is)."""
        delay = self.delay(nonlinear)
        shifted = shift_prediction(columns, self.signals.time, self.signals.segments, delay)
        if delay != 0.0 and self.signals.forward:
            held = np.concatenate([np.full(size, effect.drive) for effect, size in zip(effects, sizes, strict=True)]
                                  or [np.zeros(0, dtype=bool)])
            shifted[:, :, held] = columns[:, :, held]
        return shifted

    def shifted_design(self, nonlinear: dict[str, np.ndarray]) -> tuple[np.ndarray, list[int]]:
        design, sizes = self.design(nonlinear)
        return self.shift(design, self.effects, sizes, nonlinear), sizes

    def base(self, theta: dict[str, np.ndarray], nonlinear: dict[str, np.ndarray]) -> np.ndarray:
        """The prediction without the linear columns: nominal and offsets, shifted; plus the unshifted term."""
        out = shift_prediction(self.signals.tau_nominal + self.offsets(theta), self.signals.time,
                               self.signals.segments, self.delay(nonlinear))
        return out if self.signals.unshifted is None else out + self.signals.unshifted

    def design(self, nonlinear: dict[str, np.ndarray]) -> tuple[np.ndarray, list[int]]:
        """Columns (N, n, p) at the given nonlinear parameters (before the time shift) and sizes."""
        if self._reused is not None:
            design, sizes, moving = self._reused
            for effect, columns in moving:
                design[:, :, columns] = self.block(effect, nonlinear)
            return design, list(sizes)
        blocks, sizes = self._blocks(nonlinear)
        n_samples, n = self.signals.q.shape
        design = np.concatenate(blocks, axis=2) if blocks else np.zeros((n_samples, n, 0))
        if self.reuse_design:
            bounds = np.cumsum([0, *sizes])
            moving = [(effect, slice(int(bounds[k]), int(bounds[k + 1]))) for k, effect in enumerate(self.effects)
                      if sizes[k] and effect.name not in self.static_columns]
            self._reused = (design, list(sizes), moving)
        return design, sizes

    def weighted_rows(self, blocks: list[np.ndarray]) -> inertial.DesignRows:
        """The weighted design of these columns as rows (:class:`sim2real.identification.inertial.DesignRows`); the last one is
        kept when it fits in one chunk (the consistent fit and the bootstrap put the same one together)."""
        if self._weighted is not None and len(self._weighted[0]) == len(blocks) and all(
                a is b for a, b in zip(self._weighted[0], blocks, strict=True)):
            return self._weighted[1]
        rows = inertial.DesignRows(blocks, self.weights)
        self._weighted = (list(blocks), rows) if rows.shape[0] <= inertial.CHUNK_ROWS else None
        return rows

    def _blocks(self, nonlinear: dict[str, np.ndarray]) -> tuple[list[np.ndarray], list[int]]:
        """Each effect's columns (before the time shift; a time shift has none) and their sizes."""
        blocks, sizes = [], []
        for effect in self.effects:
            if effect.time_shift:
                sizes.append(0)
                continue
            cols = self.block(effect, nonlinear)
            blocks.append(cols)
            sizes.append(cols.shape[2])
        return blocks, sizes

    def offsets(self, theta: dict[str, np.ndarray]) -> np.ndarray:
        total = np.zeros_like(self.signals.tau_nominal)
        for effect in self.effects:
            if effect.name in theta:
                term = effect.offset(self.signals, self.states[effect.name], theta[effect.name])
                if term is not None:
                    total = total + term
        return total

    def predict(self, theta: dict[str, np.ndarray], nonlinear: dict[str, np.ndarray],
                shifted: tuple[np.ndarray, list[int]] | None = None, base: np.ndarray | None = None) -> np.ndarray:
        """The prediction; ``shifted``: :meth:`shifted_design` at ``nonlinear`` when the caller has it already;
        ``base``: :meth:`base` at ``theta`` and ``nonlinear``, likewise.

        Without a time shift the design is put together a few thousand samples at a time, never whole (on a
        long log the largest array of a fit): the same bits, as matmul multiplies sample by sample."""
        if shifted is None and self.delay(nonlinear) == 0.0:
            return self.predict_from_blocks(theta, nonlinear, *self._blocks(nonlinear), base=base)
        design, sizes = self.shifted_design(nonlinear) if shifted is None else shifted
        base = self.base(theta, nonlinear) if base is None else base
        if design.shape[2] == 0:  # a delay alone: what the product of no columns adds, without forming it
            return base + 0.0
        return base + design @ _flatten_theta(self.effects, theta, sizes)

    def predict_from_blocks(self, theta: dict[str, np.ndarray], nonlinear: dict[str, np.ndarray],
                            blocks: list[np.ndarray], sizes: list[int], base: np.ndarray | None = None) -> np.ndarray:
        """:meth:`predict` without a time shift from the effects' columns (:meth:`_blocks`), the design put
        together a few thousand samples at a time."""
        flat = _flatten_theta(self.effects, theta, sizes)
        base = self.base(theta, nonlinear) if base is None else base
        n_samples, n = self.signals.q.shape
        out = np.empty(base.shape, dtype=np.result_type(base, flat))
        step = max(1, PREDICT_CHUNK_BYTES // max(1, 8 * n * int(flat.size)))
        for start in range(0, n_samples, step):
            rows = slice(start, start + step)
            design = (np.concatenate([b[rows] for b in blocks], axis=2) if blocks
                      else np.zeros((len(base[rows]), n, 0)))
            out[rows] = base[rows] + design @ flat
        return out


def _flatten_theta(effects: list[Effect], theta: dict[str, np.ndarray], sizes: list[int]) -> np.ndarray:
    parts = [theta.get(e.name, np.zeros(s))[:s] for e, s in zip(effects, sizes, strict=True) if s]
    return np.concatenate(parts) if parts else np.zeros(0)


def _split_theta(effects: list[Effect], flat: np.ndarray, sizes: list[int]) -> dict[str, np.ndarray]:
    out, start = {}, 0
    for effect, size in zip(effects, sizes, strict=True):
        out[effect.name] = flat[start : start + size]
        start += size
    return out


def _column_blocks(design: np.ndarray, sizes: Sequence[int] | None) -> list[np.ndarray]:
    """``design`` (N, n, p) split into its effects' column blocks (views), empty ones left out."""
    if sizes is None:
        return [design] if design.shape[2] else []
    bounds = np.cumsum([0, *sizes])
    return [design[:, :, a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a]


@dataclass
class _ScaledBlock:
    """One block of columns, weighted per joint, on unit-norm columns: per joint the columns that act on
    it and their rows there (a friction column acts on its own joint only), and the columns' norms."""

    joints: list[tuple[np.ndarray, np.ndarray]]
    scale: np.ndarray


def _block_scale(block: np.ndarray, weights: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The weighted block's column norms (1 where a column is all zero) and which columns act on each joint (n, k)."""
    n_samples, n, k = block.shape
    if k < 2 or n_samples * n <= inertial.CHUNK_ROWS:  # one chunk (the demo's): numpy's own norm
        weighted = block if weights is None else block * weights[None, :, None]
        scale = np.linalg.norm(weighted.reshape(-1, k), axis=0)
        acting = np.any(weighted != 0.0, axis=0)  # (n, k)
        del weighted  # each joint's rows are weighted again later, so a long log never holds both copies
    else:
        # A long log's block, a chunk of samples at a time: numpy sums the squares of a column over the rows one
        # row after the other (two or more columns), so each chunk's sum continues the last (its first row):
        # the same bits as np.linalg.norm of the whole weighted block, which never exists.
        squares = np.zeros((0, k))
        acting = np.zeros((n, k), dtype=bool)
        step = max(1, inertial.CHUNK_ROWS // n)
        for start in range(0, n_samples, step):
            part = block[start : start + step] if weights is None else block[start : start + step] * weights[None, :, None]
            squares = np.add.reduce(np.concatenate([squares, (part * part).reshape(-1, k)]), axis=0, keepdims=True)
            acting |= np.any(part != 0.0, axis=0)
        scale = np.sqrt(squares[0])
    scale[scale == 0] = 1.0
    return scale, acting


def _joint_rows(block: np.ndarray, weights: np.ndarray | None, joint: int, cols: np.ndarray,
                scale: np.ndarray) -> np.ndarray:
    """Joint ``joint``'s rows of the block's columns ``cols``, weighted and on unit-norm columns (a new array)."""
    rows = block[:, joint, cols] if weights is None else block[:, joint, cols] * weights[joint]
    rows /= scale[cols]
    return rows


def _scaled_block(block: np.ndarray, weights: np.ndarray | None) -> _ScaledBlock:
    scale, acting = _block_scale(block, weights)
    joints = []
    for j in range(block.shape[1]):
        cols = np.flatnonzero(acting[j])
        joints.append((cols, _joint_rows(block, weights, j, cols, scale)))
    return _ScaledBlock(joints, scale)


def _normal_equations_by_joint(blocks: Sequence[np.ndarray], target: np.ndarray, weights: np.ndarray | None,
                               ) -> tuple[list[list[np.ndarray]], list[np.ndarray], list[np.ndarray]]:
    """Each pair of blocks' product and each block's right-hand side, as :func:`_block_product` and
    :func:`_block_rhs` sum them (joint by joint, in joint order: the same bits), with one joint's scaled rows
    held at a time instead of every joint's (a long log's copy of its blocks); and the blocks' scales."""
    heads = [_block_scale(block, weights) for block in blocks]
    products = [[np.zeros((heads[i][0].size, heads[k][0].size)) if k >= i else None for k in range(len(blocks))]
                for i in range(len(blocks))]  # the pairs k >= i: the Gram matrix is symmetric
    rhs = [np.zeros(scale.size) for scale, _ in heads]
    for j in range(target.shape[1]):
        rows = []
        for block, (scale, acting) in zip(blocks, heads, strict=True):
            cols = np.flatnonzero(acting[j])
            rows.append((cols, _joint_rows(block, weights, j, cols, scale)))
        for i, (left_cols, left_rows) in enumerate(rows):
            if left_cols.size:
                rhs[i][left_cols] += left_rows.T @ target[:, j]
            for k in range(i, len(rows)):
                right_cols, right_rows = rows[k]
                if left_cols.size and right_cols.size:
                    products[i][k][np.ix_(left_cols, right_cols)] += left_rows.T @ right_rows
    return products, rhs, [scale for scale, _ in heads]


def _block_product(left: _ScaledBlock, right: _ScaledBlock) -> np.ndarray:
    """``left``^T ``right`` summed joint by joint in joint order, over the columns acting on each joint."""
    out = np.zeros((left.scale.size, right.scale.size))
    for (left_cols, left_rows), (right_cols, right_rows) in zip(left.joints, right.joints, strict=True):
        if left_cols.size and right_cols.size:
            out[np.ix_(left_cols, right_cols)] += left_rows.T @ right_rows
    return out


def _block_rhs(left: _ScaledBlock, target: np.ndarray) -> np.ndarray:
    """``left``^T ``target`` (N, n) summed joint by joint, as :func:`_block_product`."""
    out = np.zeros(left.scale.size)
    for j, (cols, rows) in enumerate(left.joints):
        if cols.size:
            out[cols] += rows.T @ target[:, j]
    return out


class _GramCache:
    """The scaled blocks, their products and right-hand sides for the blocks that stay put while the
    refinement moves the nonlinear parameters (``static``: per non-empty block). Computed once, they are
    the same bits :func:`_solve_blocks` computes each time."""

    def __init__(self) -> None:
        self.static: list[bool] = []
        self._scaled: dict[int, _ScaledBlock] = {}
        self._products: dict[tuple[int, int], np.ndarray] = {}
        self._rhs: dict[int, np.ndarray] = {}
        self._target: np.ndarray | None = None

    def scaled(self, i: int, block: np.ndarray, weights: np.ndarray | None) -> _ScaledBlock:
        if not self.static[i]:
            return _scaled_block(block, weights)
        if i not in self._scaled:
            self._scaled[i] = _scaled_block(block, weights)
        return self._scaled[i]

    def product(self, i: int, j: int, left: _ScaledBlock, right: _ScaledBlock) -> np.ndarray:
        if not (self.static[i] and self.static[j]):
            return _block_product(left, right)
        if (i, j) not in self._products:
            self._products[i, j] = _block_product(left, right)
        return self._products[i, j]

    def rhs(self, i: int, left: _ScaledBlock, target: np.ndarray) -> np.ndarray:
        if not self.static[i]:
            return _block_rhs(left, target)
        if self._target is None or not np.array_equal(self._target, target):
            self._rhs.clear()
            self._target = target.copy()
        if i not in self._rhs:
            self._rhs[i] = _block_rhs(left, target)
        return self._rhs[i]


def _solve_blocks(blocks: Sequence[np.ndarray], target: np.ndarray, weights: np.ndarray | None,
                  cache: _GramCache | None) -> np.ndarray:
    """Minimum-norm least squares on unit-norm columns (collinear columns share, never blow up), each
    joint's rows multiplied by its weight (:func:`joint_weights`); ``blocks``: each effect's columns.

    Solved through the p x p Gram matrix (pseudo-inverse by SVD): the designs are tall (samples x joints
    rows, tens of columns), so this is many times faster than a QR of the design. The Gram matrix is summed
    block by block and joint by joint, over the columns that act on each joint, so a block's products come
    out the same to the last bit whichever blocks sit beside it. ``cache``: the scaled blocks and products
    of the blocks that stay put (the refinement's, :class:`_GramCache`); None computes every block.
    """
    if not blocks:
        return np.zeros(0)
    weighted_target = target if weights is None else target * weights[None, :]
    if cache is None:
        products, block_rhs, scales = _normal_equations_by_joint(blocks, weighted_target, weights)
    else:
        scaled = [cache.scaled(i, block, weights) for i, block in enumerate(blocks)]
        scales = [b.scale for b in scaled]
        block_rhs = [cache.rhs(i, left, weighted_target) for i, left in enumerate(scaled)]
        products = [[cache.product(i, k, left, scaled[k]) if k >= i else None for k in range(len(scaled))]
                    for i, left in enumerate(scaled)]
    bounds = np.cumsum([0] + [scale.size for scale in scales])
    gram = np.empty((bounds[-1], bounds[-1]))
    rhs = np.empty(bounds[-1])
    for i in range(len(scales)):
        rows = slice(bounds[i], bounds[i + 1])
        rhs[rows] = block_rhs[i]
        for k in range(i, len(scales)):
            cols = slice(bounds[k], bounds[k + 1])
            gram[rows, cols] = products[i][k]
            gram[cols, rows] = products[i][k].T
    coef = np.linalg.lstsq(gram, rhs, rcond=1e-12)[0]
    return coef / np.concatenate(scales)


def _linear_fit(problem: _Problem, tau: np.ndarray, nonlinear: dict[str, np.ndarray], iterations: int = 3,
                cache: _GramCache | None = None):
    """Linear parameters at fixed nonlinear ones; offsets (payload inertia) by fixed-point iteration.
    ``cache``: the blocks that stay put between calls (:func:`_refine_nonlinear`)."""
    # Without a time shift the effects' columns are solved as they are, never put together into one design (on a
    # long log the largest array of a fit); the same values, so the same bits. The refinement's small problem
    # keeps its one design, whose moving columns are rewritten in place at each step (reuse_design): faster.
    direct = problem.delay(nonlinear) == 0.0 and not problem.reuse_design
    if direct:
        columns, sizes = problem._blocks(nonlinear)
        blocks = [b for b in columns if b.shape[2]]
    else:
        shifted, sizes = problem.shifted_design(nonlinear)
        blocks = _column_blocks(shifted, sizes)
    has_offset = any(type(e).offset is not Effect.offset for e in problem.effects)
    theta: dict[str, np.ndarray] = {}
    for _ in range(iterations if has_offset else 1):
        if cache is not None:
            cache.static = [e.name in problem.static_columns for e, size in zip(problem.effects, sizes, strict=True) if size]
        base = problem.base(theta, nonlinear)
        flat = _solve_blocks(blocks, tau - base, problem.weights, cache)
        theta = _split_theta(problem.effects, flat, sizes)
    # Without offsets the base does not depend on the linear parameters: the prediction's is the one just used.
    known = None if has_offset else base
    predicted = (problem.predict_from_blocks(theta, nonlinear, columns, sizes, base=known) if direct
                 else problem.predict(theta, nonlinear, (shifted, sizes), base=known))
    return theta, tau - predicted, sizes


def _refine_nonlinear(
    problem: _Problem, tau: np.ndarray, settings: Mapping[str, Any], fixed: Mapping[str, np.ndarray] | None = None,
    start: Mapping[str, np.ndarray] | None = None,
) -> dict[str, np.ndarray]:
    """Nonlinear parameters by bounded least squares, the linear ones projected out.

    ``fixed``: nonlinear values of some effects to hold (e.g. the current model's, while the
    diagnosis tries a candidate on top of it); ``start``: values to start from but refine again (the
    previous rung's: a friction smoothing refined before the rotor inertia was in the model is refined
    again once it is); a delay given there starts from it instead of the grid.
    """
    signals = problem.signals
    fixed = dict(fixed or {})
    begin = {**dict(start or {}), **fixed}
    x0 = np.concatenate(
        [np.asarray(begin.get(e.name, e.nonlinear_init(signals)), dtype=float) for e in problem.effects] or [np.zeros(0)]
    )
    if x0.size == 0:
        return problem.split_nonlinear(x0)
    lower = np.concatenate([e.nonlinear_bounds(signals)[0] for e in problem.effects])
    upper = np.concatenate([e.nonlinear_bounds(signals)[1] for e in problem.effects])
    held = np.concatenate([np.full(s, e.name in fixed) for e, s in zip(problem.effects, problem.nl_sizes, strict=True)])
    # A previous value at its bound sits on a plateau (a sigmoid at its steepest is a sign function for every
    # sample: its slope no longer moves the residual), where the refinement cannot leave it: start that one
    # from its default instead.
    default = np.concatenate(
        [np.asarray(e.nonlinear_init(signals), dtype=float) for e in problem.effects] or [np.zeros(0)]
    )
    at_bound = ~held & ((x0 <= lower + 1e-9 * np.abs(lower)) | (x0 >= upper - 1e-9 * np.abs(upper)))
    x0 = np.where(at_bound & (lower < upper), default, x0)
    if held.all():
        return problem.split_nonlinear(x0)
    rows, windows = refinement_rows(signals, int(settings["refine_max_samples"]), settings.get("refine_windows_s"))
    sub_signals = subset_signals(signals, rows)
    if windows is not None:
        sub_signals.segments = windows
    sub = _Problem(problem.effects, sub_signals, problem.states, problem.weights, reuse_design=True)
    sub_tau = tau[rows]

    free = ~held
    # While the delay stays put, so do the columns of the effects without nonlinear parameters (the link
    # inertias, a rotor inertia): their part of the Gram matrix is computed once.
    delay_moves = any(e.time_shift and e.name not in fixed for e in problem.effects)
    cache = None if delay_moves else _GramCache()

    def residual_full(x: np.ndarray) -> np.ndarray:
        fitted = _linear_fit(sub, sub_tau, sub.split_nonlinear(x), iterations=1, cache=cache)
        return (fitted[1] * sub.weights).reshape(-1)

    def with_free(values: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[free] = values
        return x

    # A delay has local minima at multiples of the signal's periods, and between samples where the
    # interpolation averages white noise away: start from a grid no coarser than the sampling step.
    offset = 0
    for effect, size in zip(problem.effects, problem.nl_sizes, strict=True):
        if effect.time_shift and effect.name not in begin:
            dt = float(np.median(np.diff(sub_signals.time))) if len(sub_signals.time) > 1 else MAX_DELAY
            grid = np.linspace(0.0, MAX_DELAY, max(41, int(round(MAX_DELAY / dt)) + 1))
            costs = []
            for d in grid:
                x = x0.copy()
                x[offset] = d
                costs.append(float(np.sum(residual_full(x) ** 2)))
            x0[offset] = grid[int(np.argmin(costs))]
        offset += size
    # Smoothing velocities span decades: optimise their logarithm.
    log_mask = np.concatenate(
        [np.asarray(e.nonlinear_log_scale(signals), dtype=bool) for e in problem.effects]
    )

    def to_z(x: np.ndarray) -> np.ndarray:
        z = x.copy()
        z[log_mask] = np.log(x[log_mask])
        return z

    z_lower, z_upper = to_z(lower)[free], to_z(upper)[free]
    z0 = np.clip(to_z(x0)[free], z_lower, z_upper)
    log_free = log_mask[free]

    def to_x_free(z: np.ndarray) -> np.ndarray:
        values = z.copy()
        values[log_free] = np.exp(z[log_free])
        return with_free(values)

    result = optimize.least_squares(
        lambda z: residual_full(to_x_free(z)), z0, bounds=(z_lower, z_upper), method="trf", x_scale="jac",
        diff_step=1e-3, max_nfev=60, xtol=1e-4, ftol=1e-6,
    )
    return problem.split_nonlinear(to_x_free(result.x))


def subset_signals(signals: Signals, rows: np.ndarray) -> Signals:
    """The ``rows`` (sorted) of ``signals``, as :meth:`sim2real.identification.fitting.TorqueData.subset` takes them of the data:
    what :func:`sim2real.identification.fitting.make_signals` computes on the subset, without computing it again."""
    segments = kept_segments(signals.segments, rows)
    regressor = signals._regressor[rows] if signals._regressor is not None else None
    parent = signals
    return Signals(
        joint_names=signals.joint_names, time=signals.time[rows], q=signals.q[rows], qd=signals.qd[rows],
        qdd=signals.qdd[rows], tau_nominal=signals.tau_nominal[rows], segments=segments,
        tau=None if signals.tau is None else signals.tau[rows],
        regressor_fn=lambda: parent.regressor[rows], nominal=signals.nominal, forward=signals.forward,
        unshifted=None if signals.unshifted is None else signals.unshifted[rows], _regressor=regressor,
    )


def refinement_rows(signals: Signals, max_samples: int, window_s: float | None = None) -> tuple[np.ndarray, list[slice] | None]:
    """The samples the nonlinear refinement runs on, and their segments when they are not the runs'.

    Up to ``max_samples``, all of them. Beyond: every k-th sample of whole runs (the time grid stays uniform,
    k times coarser); or, with ``window_s``, windows of that length spread evenly over the runs, each its own
    segment (a time shift never crosses them), so the sampling step stays the log's: the actuator link
    refines a delay of a few samples. Its memory then stays put however long the log (the refinement's
    Jacobian is samples x joints x parameters)."""
    count = len(signals.time)
    if window_s is None or count <= max_samples:
        return np.arange(0, count, max(1, int(np.ceil(count / max_samples)))), None
    dt = float(np.median(np.diff(signals.time)))
    width = max(2, int(round(float(window_s) / dt)))
    candidates = []
    for seg in signals.segments:
        length = seg.stop - seg.start
        candidates.extend((start, start + width) for start in range(seg.start, seg.stop - width + 1, width))
        if 0 < length < width:
            candidates.append((seg.start, seg.stop))
    wanted = max(1, max_samples // width)
    picked = np.unique(np.linspace(0, len(candidates) - 1, min(wanted, len(candidates))).round().astype(int))
    rows = np.concatenate([np.arange(*candidates[k]) for k in picked])
    bounds = np.cumsum([0] + [candidates[k][1] - candidates[k][0] for k in picked])
    return rows, [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def _values(effects: list[Effect], theta, nonlinear, signals: Signals, states) -> dict[str, Any]:
    """Structured values (:meth:`Effect.values`) of the linear parameters ``theta``."""
    theta = _applied(effects, theta, signals)
    return {e.name: e.values(theta[e.name], nonlinear[e.name], signals, states[e.name]) for e in effects}


def _applied(effects: list[Effect], theta: Mapping[str, np.ndarray], signals: Signals) -> dict[str, np.ndarray]:
    """``theta`` as the values give it: with a gain (judged / applied torque), joint-local effects rescaled to
    applied torque, except a sensor's own bias, which is added after its gain. Each array may be stacked over
    bootstrap replicates (replicates, size): the same numbers, row by row."""
    theta = dict(theta)
    scaling = next((e for e in effects if e.scales_judged and np.shape(theta.get(e.name, ()))[-1]), None)
    if scaling is not None and not signals.forward:  # forward, every term is already applied torque
        gain = 1.0 + theta[scaling.name]
        for effect in effects:
            if (effect.joint_local and not effect.scales_judged and effect.name != "torque_bias"
                    and np.shape(theta[effect.name])[-1]):
                theta[effect.name] = theta[effect.name] / np.where(np.abs(gain) > 1e-6, gain, 1.0)
    return theta

