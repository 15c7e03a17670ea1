"""Which candidates are worth a trial: a candidate costs a rung's fit to try, and a log without its effect needs none.

A screen estimates, cheaply and generously, what a candidate could remove at most,
and the candidate is tried where that is at least half of what names one (:func:`worth_a_trial`). The lags' screen
(a lag linearised about none) is :mod:`sim2real.identification.diagnosis.lags`'; a position ripple's is here
(:func:`screen_ripples`): one sinusoid of each joint's own position, at the period that removes most on the fit
runs, judged on the holdout runs.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from sim2real.identification.diagnosis.current import CurrentResidual
from sim2real.identification.effects import EFFECTS
from sim2real.identification.effects.position_ripple import best_periods
from sim2real.identification.records import Note, NoteKind

# The share of what names a candidate that a screened one must be able to remove to be tried.
SCREEN_SHARE = 0.5


def worth_a_trial(gain: np.ndarray, excess: np.ndarray, x_now: np.ndarray, limits: Mapping[str, float]) -> bool:
    """Whether removing ``gain`` (per joint, of the squared residual in floor units) is worth fitting a candidate: half
    of what names one, arm-wide or on a joint above its floor (:data:`SCREEN_SHARE`)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        per_joint = np.where(excess > 0, gain / excess, 0.0)
    arm = float(gain.sum() / excess.sum()) if excess.sum() > 0 else 0.0
    above = x_now > limits["noise_floor_factor"]
    return bool(arm >= SCREEN_SHARE * limits["min_explained"] or np.any(
        above & (per_joint >= SCREEN_SHARE * min(limits["joint_decisive"], limits["joint_min_explained"]))))


def ripple_gain(fit_q: np.ndarray, fit_residual: np.ndarray, holdout_q: np.ndarray,
                holdout_residual: np.ndarray) -> np.ndarray:
    """Per joint (columns), the squared holdout residual one sinusoid of the joint's own position removes: its period
    and coefficients fitted on the fit runs' residual (the period that removes most there,
    :func:`sim2real.identification.effects.position_ripple.best_periods`), judged on the holdout runs, as a trial is."""
    periods, _ = best_periods(fit_q, fit_residual)
    gain = np.zeros(fit_q.shape[1])
    for j, period in enumerate(periods):
        def design(q: np.ndarray) -> np.ndarray:
            angle = 2 * np.pi * q / period
            return np.column_stack([np.sin(angle), np.cos(angle), np.ones_like(q)])

        coefficients = np.linalg.lstsq(design(fit_q[:, j]), fit_residual[:, j], rcond=None)[0]
        ripple = design(holdout_q[:, j])[:, :2] @ coefficients[:2]  # an offset is not the ripple's
        gain[j] = float(np.sum(holdout_residual[:, j] ** 2) - np.sum((holdout_residual[:, j] - ripple) ** 2))
    return np.clip(gain, 0.0, None)


def screen_ripples(tried: list[str], skipped: list[Note], current: Any, context: Any, now: CurrentResidual,
                   limits: Mapping[str, float]) -> None:
    """Take a position ripple out of ``tried`` (into ``skipped``, with why) where no joint's residual repeats with its
    own position: one sinusoid of each joint's position, fitted on the current model's residual on the fit runs and
    judged on the holdout runs (:func:`ripple_gain`), would not remove what :func:`worth_a_trial` asks. The joints at
    their floor are not searched: they have nothing to give. Without the current model's fit, it is tried.
    ``context``: the side's :class:`sim2real.identification.fitting.FitContext`."""
    ripples = [name for name in tried if EFFECTS[name].searched]
    if not ripples or current is None:
        return
    above = now.x_floor > limits["noise_floor_factor"]
    gain = np.zeros(len(now.x_floor))
    if above.any():
        from sim2real.identification.fitting import predict

        fit_data = context.fit_data
        fit_residual = (fit_data.tau - predict(current, context.nominal, fit_data, context.fit_signals)) / now.unit
        gain[above] = ripple_gain(np.asarray(fit_data.q)[:, above], fit_residual[:, above],
                                  np.asarray(context.holdout_data.q)[:, above], now.scaled[:, above])
    if worth_a_trial(gain, now.excess, now.x_floor, limits):
        return
    if not above.any():
        reason = Note(NoteKind.RIPPLE_AT_FLOOR)
    else:
        with np.errstate(invalid="ignore", divide="ignore"):
            per_joint = np.where(now.excess > 0, gain / now.excess, 0.0)
        arm = float(gain.sum() / now.excess.sum()) if now.excess.sum() > 0 else 0.0
        best = int(np.argmax(np.where(above, per_joint, -1.0)))
        reason = Note(NoteKind.RIPPLE_SCREENED, joints=(context.holdout_data.joint_names[best],),
                      figures={"share": max(arm, 0.0), "joint_share": min(float(per_joint[best]), 1.0)})
    for name in ripples:
        tried.remove(name)
        skipped.append(Note(reason.kind, effect=name, joints=reason.joints, figures=reason.figures))
