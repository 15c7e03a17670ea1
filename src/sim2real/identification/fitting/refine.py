"""The nonlinear parameters (a delay, friction slopes and offsets) refined by bounded least squares with the linear
ones projected out (variable projection), on every sample or, on a long log, on windows spread over it."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
# Imported with the module, not when first needed: it loads scipy's own BLAS, which run_sysid's one-thread
# limit (threadpoolctl) holds only if it is loaded by then, and the fit's last bits depend on it.
from scipy import optimize

from sim2real.identification.effects import Signals
from sim2real.identification.effects.actuation_delay import MAX_DELAY
from sim2real.identification.fitting.linear import _GramCache, _linear_fit
from sim2real.identification.fitting.problem import _Problem, subset_signals


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
