"""Uncertainty of a fit: a block bootstrap of the fit samples (per-block Gram matrices, each replicate a
reweighting of them), its small-sample correction (:func:`small_sample_stretch`) and the percentile
intervals of every fitted value."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.identification.effects import Effect, Signals
from sim2real.identification.effects.timing import MAX_DELAY
from sim2real.identification.effects.base import Replicates
from sim2real.identification.fitting.problem import _Problem, _applied, _flatten_theta
from sim2real.identification.inertial import DesignRows, column_norms


DELAY_STEP_S = 2e-4  # half-step of the central difference of the prediction in the delay (bootstrap)
BOOTSTRAP_CHUNK_BYTES = 4 * 2**20  # the replicates' resampled Gram matrices held at once (kept within the CPU cache)


def stacked_lstsq(a: np.ndarray, b: np.ndarray, rcond: float = 1e-12) -> np.ndarray:
    """``np.linalg.lstsq(a[k], b[k], rcond)[0]`` for every k of a stack ``a`` (K, m, n), ``b`` (K, m): the same
    LAPACK solve to the bit, in one call of the gufunc that ``np.linalg.lstsq`` wraps one matrix at a time
    (the bootstrap's replicates: a Python call per replicate cost more than its solve)."""
    if a.shape[0] == 0 or a.shape[2] == 0:
        return np.zeros((a.shape[0], a.shape[2]))
    try:
        from numpy.linalg import _umath_linalg
    except ImportError:  # a numpy without it: one matrix at a time
        return np.array([np.linalg.lstsq(a_k, b_k, rcond=rcond)[0] for a_k, b_k in zip(a, b, strict=True)])
    def did_not_converge(*_: object) -> None:
        raise np.linalg.LinAlgError("SVD did not converge in Linear Least Squares")

    with np.errstate(call=did_not_converge, invalid="call", over="ignore", divide="ignore", under="ignore"):
        solution = _umath_linalg.lstsq(np.ascontiguousarray(a, dtype=float), np.asarray(b, dtype=float)[:, :, None],
                                       float(rcond), signature="ddd->ddid")[0]
    return solution[:, :, 0]


def _block_bootstrap(
    problem: _Problem,
    tau: np.ndarray,
    nonlinear: dict[str, np.ndarray],
    theta: dict[str, np.ndarray],
    sizes: list[int],
    settings: Mapping[str, Any],
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]] | None:
    """(linear, nonlinear) parameters of block-bootstrap replicates (blocks of time resampled, all joints
    together), each effect's stacked over the replicates: (replicates, size). The linear ones are solved again
    on each resample; the lags (a delay, a first-order lag's time constant) move by one Gauss-Newton step of the
    prediction linearised about the estimate, from the same resampled blocks, so they have intervals too (their
    nonlinear parameters (replicates, 1)). Other nonlinear parameters (friction smoothing) are held: the estimate's, as
    they are. None without replicates."""
    replicates = int(settings["bootstrap_replicates"])
    shifts = [e for e in problem.effects if e.time_shift]
    if replicates <= 0 or (sum(sizes) == 0 and not shifts):
        return None
    signals = problem.signals
    weights = problem.weights
    design = _weighted_design(problem, nonlinear)
    # Offsets (payload inertia) are held at the estimate: the replicates are linear solves.
    target = (tau - problem.base(theta, nonlinear)) * weights
    p = design.shape[1]
    scale = column_norms(design)
    scale[scale == 0] = 1.0
    lags = np.array([float(nonlinear[shift.name][0]) for shift in shifts])
    slopes = _lag_slopes(problem, theta, nonlinear, shifts, lags)
    left = weights * (tau - problem.predict(theta, nonlinear)) if shifts else None
    dt = float(np.median(np.diff(signals.time))) if len(signals.time) > 1 else 1.0
    block = max(2, int(round(float(settings["bootstrap_block_s"]) / dt)))
    grams_arr, rhs_arr, delay_grams_arr, delay_rhs_arr = _block_sums(signals, design, scale, target, slopes, left, block)
    # Replicates are unconstrained solves; their spread around the full-sample solve is centred on the
    # estimate (which may be the consistent one), so intervals describe the estimate the rung reports.
    full = np.linalg.lstsq(grams_arr.sum(axis=0), rhs_arr.sum(axis=0), rcond=1e-12)[0] / scale
    estimate = _flatten_theta(problem.effects, theta, sizes)
    block_weights = np.trace(grams_arr, axis1=1, axis2=2) if p else np.trace(delay_grams_arr, axis1=1, axis2=2)
    stretch = (small_sample_stretch(block_weights, float(settings["confidence"]))
               if settings.get("bootstrap_few_blocks_correction", True) else 1.0)
    # The lags' steps are centred like the linear solves: the refinement ran on a subset of the samples.
    full_step = (_lag_steps(*_summed(delay_grams_arr, delay_rhs_arr, np.arange(len(grams_arr))[None]))[0]
                 if shifts else None)
    # One draw for all replicates: the same stream as one draw per replicate, row after row (numpy's bit
    # generator keeps the unused half of a 64-bit word between calls; tests/test_sysid.py holds it to that).
    picks = np.random.default_rng(int(settings["seed"])).integers(0, len(grams_arr), size=(replicates, len(grams_arr)))
    thetas = estimate + stretch * (_replicate_solves(grams_arr, rhs_arr, picks, scale) - full)
    bounds = np.cumsum([0, *sizes])
    stacked = {e.name: thetas[:, bounds[k] : bounds[k + 1]] for k, e in enumerate(problem.effects)}
    replicate_nonlinear = dict(nonlinear)
    if shifts:
        steps = _lag_steps(*_summed(delay_grams_arr, delay_rhs_arr, picks))
        for k, shift in enumerate(shifts):
            moved = np.isfinite(steps[:, k])  # a resample without the lag's information keeps the estimate
            replicate_nonlinear[shift.name] = np.where(
                moved, np.clip(lags[k] + stretch * (steps[:, k] - full_step[k]), 0.0, MAX_DELAY), lags[k])[:, None]
    return stacked, replicate_nonlinear


def _weighted_design(problem: _Problem, nonlinear: dict[str, np.ndarray]) -> np.ndarray | DesignRows:
    """The weighted design the replicates solve, the fit's: without a time shift put together block by block
    (DesignRows; on a long log the whole would be the largest array here)."""
    signals = problem.signals
    if not problem.retimed(nonlinear):
        columns = [b for b in problem._blocks(nonlinear)[0] if b.shape[2]]
        return problem.weighted_rows(columns) if columns else np.zeros((len(signals.time) * signals.n, 0))
    shifted, _ = problem.shifted_design(nonlinear)  # a new array (the effects' columns put together)
    shifted *= problem.weights[None, :, None]
    return shifted.reshape(shifted.shape[0] * shifted.shape[1], shifted.shape[2])


def _lag_slopes(problem: _Problem, theta: dict[str, np.ndarray], nonlinear: dict[str, np.ndarray],
                shifts: Sequence[Effect], lags: np.ndarray) -> list[np.ndarray]:
    """Each lag's weighted d(prediction)/d(lag), central differences."""
    slopes = []
    for shift, lag in zip(shifts, lags, strict=True):
        low, high = max(lag - DELAY_STEP_S, 0.0), lag + DELAY_STEP_S
        slopes.append(problem.weights * (problem.predict(theta, {**nonlinear, shift.name: np.array([high])})
                                         - problem.predict(theta, {**nonlinear, shift.name: np.array([low])}))
                      / (high - low))
    return slopes


def _block_sums(
    signals: Signals,
    design: np.ndarray | DesignRows,
    scale: np.ndarray,
    target: np.ndarray,
    slopes: Sequence[np.ndarray],
    left: np.ndarray | None,
    block: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gram matrices per block of ``block`` samples (within each segment; a replicate is a sum of blocks, solved in
    p x p): the scaled design's (blocks, p, p) and its right-hand side (blocks, p), and the lags' sums of the
    ``slopes`` with each other (blocks, lags, lags) and with the weighted residual ``left`` (blocks, lags)."""
    joints = signals.n
    grams, rhs, delay_grams, delay_rhs = [], [], [], []
    for seg in signals.segments:
        for start in range(seg.start, seg.stop, block):
            stop = min(start + block, seg.stop)
            a = design[start * joints : stop * joints] / scale
            y = target[start:stop].reshape(-1)
            grams.append(a.T @ a)
            rhs.append(a.T @ y)
            if slopes:
                delay_grams.append([[float(np.sum(a_[start:stop] * b_[start:stop])) for b_ in slopes] for a_ in slopes])
                delay_rhs.append([float(np.sum(a_[start:stop] * left[start:stop])) for a_ in slopes])  # type: ignore[index]
    # (blocks, lags, lags) and (blocks, lags); one lag: the same sums as scalars
    delay_grams_arr = np.asarray(delay_grams, dtype=float).reshape(len(delay_grams), len(slopes), len(slopes))
    delay_rhs_arr = np.asarray(delay_rhs, dtype=float).reshape(len(delay_rhs), len(slopes))
    return np.asarray(grams), np.asarray(rhs), delay_grams_arr, delay_rhs_arr


def _replicate_solves(grams: np.ndarray, rhs: np.ndarray, picks: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Each replicate's (row of ``picks``) solve of its blocks' summed Gram matrices, (replicates, p): the same bits
    as its own sums and solve would be, a few replicates at a time (the stacked Gram matrices of a long log's hundreds
    of blocks are large)."""
    coefs = np.empty((len(picks), len(scale)))
    chunk = max(1, BOOTSTRAP_CHUNK_BYTES // max(1, grams[:1].nbytes * len(grams)))
    for start in range(0, len(picks), chunk):
        rows = picks[start : start + chunk]
        coefs[start : start + chunk] = stacked_lstsq(grams[rows].sum(axis=1), rhs[rows].sum(axis=1)) / scale
    return coefs


def _summed(grams: np.ndarray, rhs: np.ndarray, picks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row of ``picks``' sum of the blocks' lag sums (grams (blocks, lags, lags), rhs (blocks, lags)), each entry
    summed along its own contiguous row (the order, and so the bits, of one lag's scalar sums)."""
    k = rhs.shape[1]
    summed_grams = np.empty((len(picks), k, k))
    summed_rhs = np.empty((len(picks), k))
    for i in range(k):
        summed_rhs[:, i] = np.ascontiguousarray(rhs[:, i])[picks].sum(axis=1)
        for j in range(k):
            summed_grams[:, i, j] = np.ascontiguousarray(grams[:, i, j])[picks].sum(axis=1)
    return summed_grams, summed_rhs


def _lag_steps(grams: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Gauss-Newton steps of the lags, (replicates, lags) from (replicates, lags, lags) and (replicates, lags): one lag
    divided as a scalar; NaN where a resample holds none of the lags' information."""
    if grams.shape[1] == 1:
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(grams[:, :, 0] > 0, rhs / grams[:, :, 0], np.nan)
    out = np.full(rhs.shape, np.nan)
    for r in range(len(grams)):
        if np.linalg.matrix_rank(grams[r]) == grams.shape[1]:
            out[r] = np.linalg.solve(grams[r], rhs[r])
    return out


def replicate_intervals(
    effects: list[Effect], theta: dict[str, np.ndarray], nonlinear: dict[str, np.ndarray], signals: Signals,
    states: Mapping[str, Any], confidence: float,
) -> dict[str, Any]:
    """Percentile intervals of every fitted value over the replicates (:func:`_block_bootstrap`'s stacks): the
    values of each replicate as :func:`sim2real.identification.fitting.problem._values` gives them, each effect's in one call
    where it takes stacked parameters (:attr:`Effect.values_stacked`), else replicate by replicate."""
    theta = _applied(effects, theta, signals)
    count = len(next(iter(theta.values())))
    out = {}
    for effect in effects:
        values, shared = theta[effect.name], nonlinear[effect.name]
        state = states[effect.name]
        if effect.values_stacked and shared.ndim == 1:
            out[effect.name] = _tree_intervals(effect.values(values, shared, signals, state), count, confidence)
        else:
            samples = [effect.values(values[k], shared[k] if shared.ndim == 2 else shared, signals, state)
                       for k in range(count)]
            out[effect.name] = _intervals(samples, confidence)
    return out


def _tree_intervals(tree: Any, count: int, confidence: float) -> Any:
    """:func:`_intervals` of a value tree from stacked parameters: a :class:`Replicates` holds each replicate's
    number, a plain number is every replicate's. The percentiles of all of them in one call (column by column:
    the same numbers as one call each)."""
    columns: list[Sequence[float]] = []

    def gather(node: Any) -> None:
        if isinstance(node, Replicates):
            columns.append(node)
        elif isinstance(node, dict):
            for value in node.values():
                gather(value)
        elif isinstance(node, list):
            for value in node:
                gather(value)
        elif not isinstance(node, bool) and isinstance(node, (int, float)):
            columns.append([node] * count)

    gather(tree)
    if not columns:
        return _intervals([tree], confidence)  # no number in it: what the replicates' own walk gives
    lows, highs = np.percentile(np.asarray(columns, dtype=float).T, [50 * (1 - confidence), 50 * (1 + confidence)],
                                axis=0)
    bounds = iter(zip(lows.tolist(), highs.tolist(), strict=True))

    def build(node: Any) -> Any:
        if isinstance(node, Replicates) or (not isinstance(node, bool) and isinstance(node, (int, float))):
            low, high = next(bounds)
            return [round(low, 6), round(high, 6)]
        if isinstance(node, dict):
            return {k: build(v) for k, v in node.items()}
        if isinstance(node, list):
            return [build(v) for v in node]
        return None

    return build(tree)


def small_sample_stretch(block_weights: np.ndarray, confidence: float) -> float:
    """Factor on the replicates' deviations that makes percentile intervals from few blocks honest.

    A block bootstrap of B blocks sees the estimate's spread through B draws: its variance is short by
    (B - 1) / B, and the spread is itself estimated, so the interval needs Student's t quantile with
    B - 1 degrees of freedom instead of the normal one. Both matter at the usual 20-40 blocks:
    ``benchmarks/bench_sysid.py --case calibration`` counts how often the 95 % intervals of the
    per-joint friction hold the truth over independent lab draws, with and without the correction. Blocks of unequal information (segments cut
    short, partial last blocks) count by Kish's effective number (sum w)^2 / sum w^2 of their weights.
    """
    weights = np.asarray(block_weights, dtype=float)
    weights = weights[weights > 0]
    if weights.size < 2:
        return 1.0
    effective = float(weights.sum() ** 2 / np.sum(weights**2))
    if effective <= 1.0:
        return 1.0
    # The quantiles scipy.stats' t.ppf and norm.ppf return, from the special functions they call, without their
    # argument handling (a tenth of a millisecond a fit, which the friction benchmark's seven fits feel)
    from scipy import special

    level = 0.5 + 0.5 * confidence
    return float(np.sqrt(effective / (effective - 1.0)) * special.stdtrit(effective - 1.0, level) / special.ndtri(level))


def _intervals(samples: list[Any], confidence: float) -> Any:
    """Percentile intervals of every number in a list of like-shaped structures."""
    first = samples[0]
    if isinstance(first, dict):
        return {k: _intervals([s[k] for s in samples], confidence) for k in first}
    if isinstance(first, list):
        return [_intervals([s[i] for s in samples], confidence) for i in range(len(first))]
    if isinstance(first, bool) or not isinstance(first, (int, float)):
        return None
    return _percentile_interval(samples, confidence)


def _percentile_interval(samples: Sequence[float], confidence: float) -> list[float]:
    lo, hi = np.percentile(np.asarray(samples, dtype=float), [50 * (1 - confidence), 50 * (1 + confidence)])
    return [round(float(lo), 6), round(float(hi), 6)]


def _prune(tree: Any) -> Any:
    if isinstance(tree, dict):
        out = {k: _prune(v) for k, v in tree.items()}
        return {k: v for k, v in out.items() if v not in (None, {}, [])}
    return tree

