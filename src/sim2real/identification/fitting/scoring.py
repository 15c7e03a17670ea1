"""Judging a fit: each joint in units of its own noise floor (:func:`joint_weights`, :func:`floor_units`),
the prediction of a fitted model and its holdout metrics."""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.identification.effects import Signals, get_effect
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

    ``nominal`` may be None when ``signals`` are given (the actuator link, :mod:`sim2real.identification.links`)."""
    if signals is None:
        assert nominal is not None
        signals = make_signals(nominal, data)
    effects = [get_effect(name) for name in result.effects]
    problem = _Problem(effects, signals, result.states)
    return problem.predict(result.theta, result.nonlinear)


def holdout_metrics(result: FitResult, nominal: NominalModel | None, data: TorqueData, signals: Signals | None = None):
    """(metrics, residual) on the holdout data: ``{"torque_rmse": rmse shape}``."""
    residual = data.tau - predict(result, nominal, data, signals)
    return {"torque_rmse": rmse(residual, data.joint_names)}, residual

