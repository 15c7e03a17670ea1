"""A weighted design's rows, a chunk at a time (:class:`DesignRows`): a long log's design never exists whole, and
its sums (column norms, normal equations, squared residuals) are taken chunk by chunk in numpy's own order."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sim2real import blas



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
        if self.shape[0] <= blas.CHUNK_ROWS:  # a design of one chunk (the demo's) is put together once, then viewed
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
    """``rows`` (slices) cut into groups of at most blas.CHUNK_ROWS rows; one group when they fit in one."""
    groups: list[list[slice]] = [[]]
    size = 0
    for part in rows:
        start = part.start
        while start < part.stop:
            stop = min(part.stop, start + blas.CHUNK_ROWS - size)
            groups[-1].append(slice(start, stop))
            size += stop - start
            start = stop
            if size == blas.CHUNK_ROWS:
                groups.append([])
                size = 0
    return [g for g in groups if g]


def _rows_of(a: np.ndarray | DesignRows, group: Sequence[slice]) -> np.ndarray:
    """The rows of ``group`` (a view when it is one slice)."""
    return a[group[0]] if len(group) == 1 else np.concatenate([a[part] for part in group])


def column_norms(a: np.ndarray | DesignRows, rows: Sequence[slice] | None = None) -> np.ndarray:
    """The Euclidean norm of each column of ``a`` (rows x columns) over ``rows`` (default: all), summed chunk
    by chunk (blas.CHUNK_ROWS); numpy's own norm when the rows fit in one chunk."""
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


def _squared_residual(design: np.ndarray | DesignRows, target: np.ndarray, rows: slice, x: np.ndarray) -> float:
    """Sum of squares of ``design[rows] @ x - target[rows]``, chunk by chunk (blas.CHUNK_ROWS; one sum when they fit)."""
    groups = _chunks([rows])
    if len(groups) == 1:
        return float(np.sum((_rows_of(design, groups[0]) @ x - _rows_of(target, groups[0])) ** 2))
    return float(sum(np.sum((_rows_of(design, g) @ x - _rows_of(target, g)) ** 2) for g in groups))
