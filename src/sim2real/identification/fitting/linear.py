"""The linear parameters at given nonlinear ones: each joint's rows weighted by its floor and its columns scaled,
the normal equations summed joint by joint (a long log's design never whole), the minimum-norm solve."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sim2real import blas
from sim2real.identification.effects import Effect
from sim2real.identification.fitting.problem import _Problem, _split_theta


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
    if k < 2 or n_samples * n <= blas.CHUNK_ROWS:  # one chunk (the demo's): numpy's own norm
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
        step = max(1, blas.CHUNK_ROWS // n)
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

    def __init__(self, time_moves: bool = False) -> None:
        # time_moves: the refinement moves a lag, so only the columns the lags leave where they are stay put
        self.time_moves = time_moves
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
                  cache: _GramCache | None, lower: np.ndarray | None = None) -> np.ndarray:
    """Minimum-norm least squares on unit-norm columns (collinear columns share, never blow up), each
    joint's rows multiplied by its weight (:func:`joint_weights`); ``blocks``: each effect's columns.

    Solved through the p x p Gram matrix (pseudo-inverse by SVD): the designs are tall (samples x joints
    rows, tens of columns), so this is many times faster than a QR of the design. The Gram matrix is summed
    block by block and joint by joint, over the columns that act on each joint, so a block's products come
    out the same to the last bit whichever blocks sit beside it. ``cache``: the scaled blocks and products
    of the blocks that stay put (the refinement's, :class:`_GramCache`); None computes every block. ``lower``:
    each coefficient's lower bound (-inf where none): a coefficient the solve puts below its bound is held at it and
    the others solved again (:func:`_held_at_bounds`).
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
    scale = np.concatenate(scales)
    if lower is not None:
        coef = _held_at_bounds(gram, rhs, coef, lower * scale)
    return coef / scale


def _held_at_bounds(gram: np.ndarray, rhs: np.ndarray, coef: np.ndarray, lower: np.ndarray) -> np.ndarray:
    """The normal equations' solution with every coefficient that falls below its bound held there and the rest
    solved again, until none falls below (an active set that only grows: at most one pass per coefficient). The
    refinement searches the nonlinear parameters of the model the consistent fit delivers, where a friction's
    amplitude is never negative: unbounded, it may settle where a sigmoid fits only with a negative amplitude,
    which the consistent fit then clips to nothing."""
    held = np.zeros(coef.size, dtype=bool)
    for _ in range(coef.size):
        below = ~held & (coef < lower)
        if not below.any():
            break
        held |= below
        coef = coef.copy()
        coef[held] = lower[held]
        free = ~held
        if free.any():
            coef[free] = np.linalg.lstsq(gram[np.ix_(free, free)], rhs[free] - gram[np.ix_(free, held)] @ lower[held],
                                         rcond=1e-12)[0]
    return coef


def lower_bounds(problem: _Problem, sizes: Sequence[int]) -> np.ndarray:
    """The lower bounds of the linear fit's coefficients, effect by effect in the fit's order (-inf where none)."""
    return np.concatenate([np.asarray(e.theta_lower(problem.signals, size), dtype=float)
                           for e, size in zip(problem.effects, sizes, strict=True) if size] or [np.zeros(0)])


def _linear_fit(problem: _Problem, tau: np.ndarray, nonlinear: dict[str, np.ndarray], iterations: int = 3,
                cache: _GramCache | None = None, bounded: bool = False):
    """Linear parameters at fixed nonlinear ones; offsets (payload inertia) by fixed-point iteration.
    ``cache``: the blocks that stay put between calls (:func:`_refine_nonlinear`); ``bounded``: each effect's
    coefficients held at or above their lower bounds (:meth:`Effect.theta_lower`, :func:`_held_at_bounds`)."""
    # Without a time shift the effects' columns are solved as they are, never put together into one design (on a
    # long log the largest array of a fit); the same values, so the same bits. The refinement's small problem
    # keeps its one design, whose moving columns are rewritten in place at each step (reuse_design): faster.
    direct = not problem.retimed(nonlinear) and not problem.reuse_design
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
            cache.static = [e.name in problem.static_columns and (not cache.time_moves or problem.held_in_time(e))
                            for e, size in zip(problem.effects, sizes, strict=True) if size]
        base = problem.base(theta, nonlinear)
        flat = _solve_blocks(blocks, tau - base, problem.weights, cache, lower_bounds(problem, sizes) if bounded else None)
        theta = _split_theta(problem.effects, flat, sizes)
    # Without offsets the base does not depend on the linear parameters: the prediction's is the one just used.
    known = None if has_offset else base
    predicted = (problem.predict_from_blocks(theta, nonlinear, columns, sizes, base=known) if direct
                 else problem.predict(theta, nonlinear, (shifted, sizes), base=known))
    return theta, tau - predicted, sizes
