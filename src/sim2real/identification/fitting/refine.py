"""The nonlinear parameters (a delay, friction slopes and offsets) refined by bounded least squares with the linear
ones projected out (variable projection), on every sample or, on a long log, on windows spread over it."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
# Imported with the module, not when first needed: it loads scipy's own BLAS, which run_sysid's one-thread
# limit (threadpoolctl) holds only if it is loaded by then, and the fit's last bits depend on it.
from scipy import optimize

from sim2real.identification.effects import Signals
from sim2real.identification.effects.timing import MAX_DELAY
from sim2real.identification.fitting.linear import _GramCache, _linear_fit, lower_bounds
from sim2real.identification.fitting.problem import _Problem, subset_signals


# The settings a refinement reads (joint_weighting through the problem's weights).
REFINE_SETTINGS = ("refine_max_samples", "refine_windows_s", "joint_weighting")


@dataclass
class Refinements:
    """The nonlinear refinements of one side's data, kept between rounds of the loop (:class:`sim2real.cache.FitCache`).

    A diagnosis's trial of a candidate refines exactly what that candidate's rung refines in the next round, once
    the user adds it: the same data, effects, start and held parameters (the prior's weight, the one difference
    between a trial and its rung, does not enter the refinement). The rung reads it back, the same bits.
    ``inputs``: the digest of the side's data and nominal model (:func:`sim2real.identification.sysid.fit_ladder`'s)."""

    cache: Any
    inputs: str

    def get_or_compute(self, effect_names: Sequence[str], settings: Mapping[str, Any],
                       fixed: Mapping[str, np.ndarray] | None, start: Mapping[str, np.ndarray] | None,
                       compute: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
        key = self.cache.key(self.inputs, list(effect_names), {k: settings.get(k) for k in REFINE_SETTINGS},
                             dict(fixed or {}), dict(start or {}))
        return self.cache.get_or_compute("refinement", key, compute)


@dataclass(frozen=True)
class Nonlinear:
    """How a fit reaches its nonlinear parameters: those ``held`` as they are (the diagnosis holds the current model's
    while it tries a candidate), where the refinement of the others ``starts`` (the ladder passes the previous rung's
    and refines every nonlinear parameter again, so a rung delivers at least the fall its candidate promised), and
    where refinements are read back from or kept for the next round (``refinements``)."""

    held: Mapping[str, np.ndarray] | None = None
    start: Mapping[str, np.ndarray] | None = None
    refinements: Refinements | None = None


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
    x0 = _off_the_bounds(problem, x0, lower, upper, held)
    if held.all():
        return problem.split_nonlinear(x0)
    rows, windows = refinement_rows(signals, int(settings["refine_max_samples"]), settings.get("refine_windows_s"))
    sub_signals = subset_signals(signals, rows)
    if windows is not None:
        sub_signals.segments = windows
    sub = _Problem(problem.effects, sub_signals, problem.states, problem.weights, reuse_design=True,
                   still_joints=problem.still_joints,
                   effect_joints=problem.effect_joints)
    sub_tau = tau[rows]
    cache = _refinement_cache(problem, fixed)
    _start_delays(problem, sub, sub_tau, cache, begin, x0)
    _start_periods(problem, sub, sub_tau, begin, x0, lower, upper)
    return problem.split_nonlinear(_least_squares(problem, sub, sub_tau, cache, x0, lower, upper, ~held))


def _off_the_bounds(problem: _Problem, x0: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                    held: np.ndarray) -> np.ndarray:
    """``x0``, each free value at its bound replaced by its default: a previous value at its bound sits on a plateau
    (a sigmoid at its steepest is a sign function for every sample: its slope no longer moves the residual), where
    the refinement cannot leave it."""
    default = np.concatenate(
        [np.asarray(e.nonlinear_init(problem.signals), dtype=float) for e in problem.effects] or [np.zeros(0)]
    )
    at_bound = ~held & ((x0 <= lower + 1e-9 * np.abs(lower)) | (x0 >= upper - 1e-9 * np.abs(upper)))
    return np.where(at_bound & (lower < upper), default, x0)


def _refinement_cache(problem: _Problem, fixed: Mapping[str, np.ndarray]) -> _GramCache | None:
    """While the delay stays put, so do the columns of the effects without nonlinear parameters (the link
    inertias, a rotor inertia): their part of the Gram matrix is computed once. While it moves, only those the
    lags leave where they are (a drive's on the drive side) stay put."""
    delay_moves = any(e.time_shift and e.name not in fixed for e in problem.effects)
    stays_put = any(e.name in problem.static_columns and problem.held_in_time(e) for e in problem.effects)
    return (_GramCache(time_moves=True) if stays_put else None) if delay_moves else _GramCache()


def _start_delays(problem: _Problem, sub: _Problem, sub_tau: np.ndarray, cache: _GramCache | None,
                  begin: Mapping[str, np.ndarray], x0: np.ndarray) -> None:
    """A delay has local minima at multiples of the signal's periods, and between samples where the
    interpolation averages white noise away: each one not in ``begin`` starts (in ``x0``, in place) from the best of
    a grid no coarser than the sampling step."""
    def residual_full(x: np.ndarray) -> np.ndarray:
        fitted = _linear_fit(sub, sub_tau, sub.split_nonlinear(x), iterations=1, cache=cache, bounded=True)
        return (fitted[1] * sub.weights).reshape(-1)

    sub_signals = sub.signals
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


def _start_periods(problem: _Problem, sub: _Problem, sub_tau: np.ndarray, begin: Mapping[str, np.ndarray],
                   x0: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
    """A period has a local minimum at every other one: each one not in ``begin`` starts (in ``x0``, in place) where
    the residual of the model without the effect repeats most (Effect.search_start), that model's linear
    coefficients fitted at the start's other values."""
    sub_signals = sub.signals
    offset = 0
    for effect, size in zip(problem.effects, problem.nl_sizes, strict=True):
        if effect.searched and effect.name not in begin:
            others = [e for e in problem.effects if e is not effect]
            start_values = sub.split_nonlinear(x0)
            without = _Problem(others, sub_signals, problem.states, problem.weights, still_joints=problem.still_joints,
                               effect_joints=problem.effect_joints)
            _, rest, _ = _linear_fit(without, sub_tau, {e.name: start_values[e.name] for e in others}, iterations=1)
            x0[offset:offset + size] = np.clip(effect.search_start(sub_signals, rest), lower[offset:offset + size],
                                               upper[offset:offset + size])
        offset += size


def _least_squares(problem: _Problem, sub: _Problem, sub_tau: np.ndarray, cache: _GramCache | None, x0: np.ndarray,
                   lower: np.ndarray, upper: np.ndarray, free: np.ndarray) -> np.ndarray:
    """The free values refined from ``x0`` by bounded least squares (trust region reflective, the Jacobian by
    variable projection), smoothing velocities through their logarithm; the held ones as in ``x0``."""
    # Smoothing velocities span decades: optimise their logarithm.
    log_mask = np.concatenate(
        [np.asarray(e.nonlinear_log_scale(problem.signals), dtype=bool) for e in problem.effects]
    )

    def to_z(x: np.ndarray) -> np.ndarray:
        z = x.copy()
        z[log_mask] = np.log(x[log_mask])
        return z

    def with_free(values: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[free] = values
        return x

    z_lower, z_upper = to_z(lower)[free], to_z(upper)[free]
    z0 = np.clip(to_z(x0)[free], z_lower, z_upper)
    log_free = log_mask[free]

    def to_x_free(z: np.ndarray) -> np.ndarray:
        values = z.copy()
        values[log_free] = np.exp(z[log_free])
        return with_free(values)

    jacobian = _ProjectedJacobian(sub, sub_tau, cache, to_x_free, np.flatnonzero(free))
    result = optimize.least_squares(
        jacobian.residual, z0, jac=jacobian, bounds=(z_lower, z_upper), method="trf", x_scale="jac",
        max_nfev=60, xtol=1e-4, ftol=1e-6,
    )
    return to_x_free(result.x)


class _ProjectedJacobian:
    """The refinement's residual and its Jacobian by variable projection (Kaufman's form).

    The residual is the weighted torque error with the linear parameters solved for at each nonlinear point. Its
    derivative along a nonlinear parameter is the change of that effect's columns times the linear parameters,
    less what the design's columns take up of it (projected out, as the linear solve would): one small solve for
    every parameter together, where differencing the whole solve costs one solve per parameter. The columns'
    change is differenced on the columns alone (cheap: one effect's). A delay shifts every column and the nominal
    prediction, and its cost is rough between samples: it is differenced through the whole solve, at the step the
    refinement always used for it."""

    COLUMN_STEP = 1e-6  # relative step of the columns' difference (smooth functions of their parameters)
    DELAY_STEP = 1e-3  # relative step of the delay's difference through the solve

    def __init__(self, problem: _Problem, tau: np.ndarray, cache: _GramCache | None, to_x: Any,
                 free_index: np.ndarray) -> None:
        self.problem, self.tau, self.cache, self.to_x = problem, tau, cache, to_x
        owners = [(effect, k) for effect, size in zip(problem.effects, problem.nl_sizes, strict=True)
                  for k in range(size)]
        self.owners = [owners[i] for i in free_index]  # (effect, index in its vector) of each free parameter
        self._point: tuple[bytes, dict[str, np.ndarray], dict[str, np.ndarray], np.ndarray] | None = None

    def _at(self, z: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], np.ndarray]:
        key = np.asarray(z, dtype=float).tobytes()
        if self._point is None or self._point[0] != key:
            nonlinear = self.problem.split_nonlinear(self.to_x(z))
            theta, residual, _ = _linear_fit(self.problem, self.tau, nonlinear, iterations=1, cache=self.cache,
                                             bounded=True)
            self._point = (key, nonlinear, theta, (residual * self.problem.weights).reshape(-1))
        return self._point[1], self._point[2], self._point[3]

    def residual(self, z: np.ndarray) -> np.ndarray:
        return self._at(z)[2]

    def _columns(self, effect: Any, nonlinear: dict[str, np.ndarray], delay_of: dict[str, np.ndarray]) -> np.ndarray:
        """One effect's columns as they enter the prediction (shifted by the delay ``delay_of`` holds)."""
        block = self.problem.block(effect, nonlinear)
        return self.problem.shift(block, [effect], [block.shape[2]], delay_of)

    def __call__(self, z: np.ndarray) -> np.ndarray:
        problem, weights = self.problem, self.problem.weights
        z = np.asarray(z, dtype=float)
        nonlinear, theta, residual = self._at(z)
        design, sizes = problem.shifted_design(nonlinear)  # the one the residual at z was solved on, not made again
        weighted = (design * weights[None, :, None]).reshape(residual.size, -1)  # a copy: the design is reused
        out = np.empty((residual.size, z.size))
        moved, where = [], []
        point = self._point
        joints = len(weights)
        # A joint-local effect's parameter moves its own joint's columns only: the same parameter of every joint
        # (its k-th, k // joints) is differenced in one evaluation of the effect's columns, each joint's change
        # read on its own rows; any other parameter alone.
        groups: dict[tuple[str, int], list[int]] = {}
        for i, (effect, k) in enumerate(self.owners):
            if effect.time_shift:
                step = np.zeros_like(z)
                step[i] = self.DELAY_STEP * max(1.0, abs(z[i])) * (1.0 if z[i] >= 0 else -1.0)
                out[:, i] = (self._at(z + step)[2] - residual) / step[i]
                self._point = point
                continue
            local = effect.joint_local and nonlinear[effect.name].size % joints == 0
            groups.setdefault((effect.name, k // joints if local else joints + k), []).append(i)
        base_columns: dict[str, np.ndarray] = {}
        for (name, _), members in groups.items():
            effect = self.owners[members[0]][0]
            step = np.zeros_like(z)
            for i in members:
                step[i] = self.COLUMN_STEP * max(1.0, abs(z[i]))
            if name not in base_columns:  # the effect's columns at z, as they enter the prediction: the design's
                base_columns[name] = problem.columns_of(effect, design, sizes)
            shifted = problem.split_nonlinear(self.to_x(z + step))
            # the prediction's change (samples x joints), each joint's from its own parameter in the group
            change = (self._columns(effect, shifted, nonlinear) - base_columns[name]) @ theta[name] * weights[None, :]
            for i in members:
                if len(members) > 1:  # this parameter's joint alone: the others' rows moved by their own
                    own = np.zeros_like(change)
                    joint = self.owners[i][1] % joints
                    own[:, joint] = change[:, joint] / step[i]
                    moved.append(own.reshape(-1))
                else:
                    moved.append((change / step[i]).reshape(-1))
                where.append(i)
        if moved:
            changes = np.column_stack(moved)
            # a coefficient held at its bound (fitting.linear._held_at_bounds) takes up no change: only the free
            # columns' span is projected out, as the bounded solve does
            flat = np.concatenate([theta[e.name] for e, size in zip(problem.effects, sizes, strict=True) if size]
                                  or [np.zeros(0)])
            lower = lower_bounds(problem, sizes)
            at_bound = np.isfinite(lower) & (flat <= lower + 1e-12 * np.maximum(1.0, np.abs(np.where(np.isfinite(lower),
                                                                                                       lower, 0.0))))
            if at_bound.any():
                weighted = weighted[:, ~at_bound]
            if weighted.shape[1]:
                scale = np.linalg.norm(weighted, axis=0)
                scale[scale == 0] = 1.0
                unit = weighted
                unit /= scale  # in place: the weighted copy is not needed again
                # The columns' share of each change: its projection on their span, dropping directions below 1e-6 of
                # the largest singular value (the Gram matrix's 1e-12, as the linear fit drops them). From the p x p
                # Gram matrix's eigenpairs rather than an SVD of the tall design: a third of the work, and a
                # Jacobian's precision is all it needs (the refinement's minimum is the residual's).
                eigval, eigvec = np.linalg.eigh(unit.T @ unit)
                keep = eigval > 1e-12 * eigval[-1]
                inverse = (eigvec[:, keep] / eigval[keep]) @ eigvec[:, keep].T
                taken = unit @ (inverse @ (unit.T @ changes))
                changes -= taken
            np.negative(changes, out=changes)
            out[:, where] = changes
        return out


def refinement_rows(signals: Signals, max_samples: int, window_s: float | None = None) -> tuple[np.ndarray, list[slice] | None]:
    """The samples the nonlinear refinement runs on, and their segments when they are not the runs'.

    Up to ``max_samples``, all of them. Beyond: every k-th sample of whole runs (the time grid stays uniform,
    k times coarser); or, with ``window_s``, windows of that length spread evenly over the runs, each its own
    segment (a time shift never crosses them), so the sampling step stays the log's: the drive side
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
