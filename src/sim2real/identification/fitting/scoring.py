"""Judging a fit: each joint in units of its own noise floor (:func:`joint_weights`, :func:`floor_units`),
the prediction of a fitted model and its holdout metrics."""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.identification.effects import Signals, get_effect
from sim2real.identification.effects.timing import time_derivative
from sim2real.identification.fitting.data import TorqueData
from sim2real.identification.fitting.nominal import NominalModel, make_signals
from sim2real.identification.fitting.problem import FitResult, _Problem
from sim2real.stats import rmse


# A joint whose floor reads below this fraction of the arm's RMS floor is weighted as if it were there:
# an underestimated floor (a quiet sensor, a saturated log) must not let one joint take the whole fit.
MIN_FLOOR_FRACTION = 0.2


def joint_weights(noise_floor: np.ndarray, weighting: str = "noise_floor") -> np.ndarray:
    """Per-joint weights of the fit: each joint's residual in units of its own noise floor.

    Weighted least squares as Gautier and Poignet identify robots (each joint weighted by its error's
    standard deviation): a wrist whose torques are ten times smaller than the shoulder's then counts as
    much, in its own units, as the shoulder. Rescaled so that white noise at the floors gives the
    arm's RMS floor on every joint: the weighted data term stays in (N*m)^2, the scale of the
    inertial prior's weight. ``weighting="none"``: all ones (plain N*m).
    """
    floor = np.asarray(noise_floor, dtype=float).reshape(-1)
    if weighting == "none" or floor.size == 0 or not np.all(np.isfinite(floor)) or floor.max() <= 0:
        return np.ones(floor.size)
    rms = float(np.sqrt(np.mean(floor**2)))
    return rms / np.maximum(floor, MIN_FLOOR_FRACTION * rms)


def judged_floors(noise_floor: np.ndarray) -> np.ndarray:
    """Each joint's floor as the loop judges by it (:func:`joint_weights`): at least :data:`MIN_FLOOR_FRACTION` of
    the arm's RMS floor, so a joint whose torque shows no white noise (logged in coarse quanta) is judged in the
    arm's units, not divided by zero; ones where no joint has a floor."""
    floor = np.asarray(noise_floor, dtype=float)
    rms = float(np.sqrt(np.mean(floor**2))) if floor.size else 0.0
    return np.maximum(floor, MIN_FLOOR_FRACTION * rms) if rms > 0 else np.ones_like(floor)


def floor_units(residual: np.ndarray, noise_floor: np.ndarray) -> dict[str, Any]:
    """A residual's RMS in units of each joint's noise floor (:func:`judged_floors`): per joint and over the arm
    (RMS of the ratios).

    1.0 is what white noise at the floor gives; the loop's decisions are taken in these units."""
    floor = judged_floors(noise_floor)
    ratio = np.sqrt(np.mean(np.asarray(residual, dtype=float) ** 2, axis=0)) / floor
    return {"overall": float(np.sqrt(np.mean(ratio**2))), "per_joint": [float(v) for v in ratio]}


def predict(
    result: FitResult, nominal: NominalModel | None, data: TorqueData, signals: Signals | None = None
) -> np.ndarray:
    """Judged torque the fitted model predicts on ``data`` (e.g. the holdout runs).

    ``nominal`` may be None when ``signals`` are given (the drive side, :mod:`sim2real.identification.sides`)."""
    if signals is None:
        assert nominal is not None
        signals = make_signals(nominal, data)
    effects = [get_effect(name) for name in result.effects]
    problem = _Problem(effects, signals, result.states, effect_joints=result.effect_joints)
    return problem.predict(result.theta, result.nonlinear)


def holdout_metrics(result: FitResult, nominal: NominalModel | None, data: TorqueData, signals: Signals | None = None):
    """(torque RMSE, residual) on the holdout data (the RMSE in :func:`sim2real.stats.rmse`'s shape)."""
    residual = data.tau - predict(result, nominal, data, signals)
    return rmse(residual, data.joint_names), residual


LAG_CHUNK_ROWS = 1 << 14  # samples whose design rows a lag's score sums at a time (never the whole design)


def lag_score(result: FitResult, nominal: NominalModel | None, data: TorqueData, residual: np.ndarray,
              unit: np.ndarray, signals: Signals | None = None, lead: bool = False) -> tuple[float, np.ndarray]:
    """What a lag of the judged torque behind the fitted model would remove of ``residual`` (``data``'s, the model's
    holdout residual), linearised about no lag, with every linear coefficient of the model refitted beside it on
    these very samples (optimistic: an upper bound of what a fit on other runs delivers here, to first order).

    Returns the lag (s; 0 where only a lead would help: a reading cannot come before the torque) and, per joint, the
    fall of the sum of squares of ``residual / unit``. The model's reading at t is its torque at t - d, so
    d(prediction)/dd = -d(prediction)/dt; with ``lead``, the judged torque leads the model (a command against the
    motion it causes: t + d). For a model without a time shift of its own; its design is summed
    :data:`LAG_CHUNK_ROWS` samples at a time."""
    if signals is None:
        assert nominal is not None
        signals = make_signals(nominal, data)
    effects = [get_effect(name) for name in result.effects]
    problem = _Problem(effects, signals, result.states, effect_joints=result.effect_joints)
    slope = (1.0 if lead else -1.0) * time_derivative(data.tau - residual, signals.time, signals.segments)
    r, g = residual / unit, slope / unit
    blocks, _ = problem._blocks(result.nonlinear)
    p = int(sum(block.shape[2] for block in blocks))
    r_rest, g_rest = r.copy(), g.copy()  # each less its projection on the model's columns
    if p:
        gram, right = np.zeros((p, p)), np.zeros((p, 2))
        for start in range(0, len(r), LAG_CHUNK_ROWS):
            rows = slice(start, start + LAG_CHUNK_ROWS)
            flat = (np.concatenate([block[rows] for block in blocks], axis=2) / unit[None, :, None]).reshape(-1, p)
            gram += flat.T @ flat
            right += flat.T @ np.stack([r[rows].reshape(-1), g[rows].reshape(-1)], axis=1)
        coefficients = np.linalg.lstsq(gram, right, rcond=1e-12)[0]
        for start in range(0, len(r), LAG_CHUNK_ROWS):
            rows = slice(start, start + LAG_CHUNK_ROWS)
            design = np.concatenate([block[rows] for block in blocks], axis=2) / unit[None, :, None]
            r_rest[rows] -= design @ coefficients[:, 0]
            g_rest[rows] -= design @ coefficients[:, 1]
    energy = float(np.sum(g_rest**2))
    delay = float(np.sum(r_rest * g_rest)) / energy if energy > 0 else 0.0
    if delay <= 0:
        return 0.0, np.zeros(r.shape[1])
    return delay, np.sum(r_rest**2, axis=0) - np.sum((r_rest - delay * g_rest) ** 2, axis=0)
