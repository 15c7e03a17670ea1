"""A lag's place in the diagnosis: when one is worth a trial, and what a verdict says of its two shapes.

A lag (:mod:`sim2real.identification.effects.timing`: a delay, or a first-order lag) costs a rung's fit to try, and a
log without one needs none. A lag is tried where, linearised about no lag with every linear coefficient refitted
beside it on the holdout runs themselves (more than a fit on the fit runs can deliver there), it could remove half
of what a candidate must remove to be named (:func:`screen_lags`,
:func:`~sim2real.identification.diagnosis.screens.worth_a_trial`); a shape of a lag beside another shape the side tries
anyway (the drive side's delay) waits for that trial instead, and is fitted where it removes as much
(:func:`after_other_shape`). Two shapes of one lag part only where the judged torque changes within it: where the
data cannot tell them apart the verdict says so (:func:`other_shapes`, a :data:`~sim2real.identification.records.NoteKind.LAG_SHAPES` note), and no designed run is
promised (:func:`same_lag`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.identification import fitting
from sim2real.identification.diagnosis.current import CurrentResidual
from sim2real.identification.diagnosis.screens import worth_a_trial
from sim2real.identification.effects import EFFECTS
from sim2real.identification.records import Note, NoteKind


def same_lag(a: str, b: str) -> bool:
    """Whether two effects are two shapes of one lag (a delay and a first-order lag of the same place): they part
    only where the judged torque changes within the lag, which no motion within the arm's limits makes, so no designed
    run separates them; the ranking decides (within what the data can tell, the delay:
    :func:`sim2real.identification.diagnosis.candidates._rank`)."""
    first, second = EFFECTS[a], EFFECTS[b]
    return (a != b and first.time_shift and second.time_shift and first.side == second.side
            and first.sensor_side == second.sensor_side)


def leads(name: str, forward: bool) -> bool:
    """Whether a lag effect moves the prediction ahead in time (a command judged against the motion it causes)."""
    effect = EFFECTS[name]
    return (effect.prediction_lag(1.0, forward) < 0) if effect.lowpass else (effect.prediction_shift(1.0, forward) > 0)


def _screen_reason(current: fitting.FitResult, context: fitting.FitContext, now: CurrentResidual,
                   limits: Mapping[str, float], lead: bool = False) -> Note | None:
    """Why a lag of the judged torque (with ``lead``: a lead) is not fitted on these runs (None: it is;
    :func:`fitting.lag_score`)."""
    delay, gain = fitting.lag_score(current, context.nominal, context.holdout_data, now.residual, now.unit,
                                    context.holdout_signals, lead=lead)
    if worth_a_trial(gain, now.excess, now.x_floor, limits):
        return None
    arm = float(gain.sum() / now.excess.sum()) if now.excess.sum() > 0 else 0.0
    return Note(NoteKind.LAG_SCREENED, figures={"lead": lead, "delay_s": delay, "share": arm})


def screen_lags(tried: list[str], skipped: list[Note], current: fitting.FitResult | None,
                context: fitting.FitContext, now: CurrentResidual, limits: Mapping[str, float]) -> dict[str, str]:
    """Take out of ``tried`` the lags not worth a trial on these runs (into ``skipped``, each with why) and those
    that wait for their other shape's trial; returns the waiting ones, each with the shape it waits for. Only a model
    without a lag of its own is screened (with one, the other shape is the question). One score for every shape:
    linearised about none they are the same (a command judged against the motion leads it instead)."""
    if current is None or any(EFFECTS[e].time_shift for e in current.effects):
        return {}
    forward = context.holdout_signals.forward
    lags = [n for n in tried if EFFECTS[n].lag_screened]
    waiting = {n: next(s for s in tried if same_lag(n, s) and not EFFECTS[s].lag_screened) for n in lags
               if any(same_lag(n, s) and not EFFECTS[s].lag_screened for s in tried)}
    screened = [n for n in lags if n not in waiting]
    reasons = {lead: _screen_reason(current, context, now, limits, lead)
               for lead in sorted({leads(name, forward) for name in screened})}
    for name in lags:
        if name in waiting:
            tried.remove(name)
        elif (reason := reasons[leads(name, forward)]) is not None:
            tried.remove(name)
            skipped.append(Note(reason.kind, effect=name, figures=reason.figures))
    return waiting


def after_other_shape(waiting: Mapping[str, str], trials: Mapping[str, tuple[Any, np.ndarray]],
                      skipped: list[Note], now: CurrentResidual, limits: Mapping[str, float]) -> list[str]:
    """The waiting lags (:func:`screen_lags`) to fit after all: those whose other shape's trial removes what the screen
    asks of a lag (the data, not the order of the library, choose the shape); the rest into ``skipped``, with what
    that trial removed."""
    second = []
    for name, other in waiting.items():
        gain = now.sse - np.sum((trials[other][1] / now.unit) ** 2, axis=0)
        if worth_a_trial(gain, now.excess, now.x_floor, limits):
            second.append(name)
        else:
            share = float(gain.sum() / now.excess.sum()) if now.excess.sum() > 0 else 0.0
            skipped.append(Note(NoteKind.OTHER_SHAPE, effect=name, figures={"other": other, "share": max(share, 0.0)}))
    return second


def other_shapes(best: Mapping[str, Any], candidates: Sequence[Mapping[str, Any]],
                 residuals: Mapping[str, np.ndarray], limits: Mapping[str, Any], same_prediction: float) -> list[str]:
    """The other shapes of the named lag that do as well as the data can tell (the ranking's tolerance) or predict
    the same torque (within ``same_prediction`` RMS): a tie, said as one (:func:`shapes_note`). ``residuals``: in
    floor units, by candidate."""
    return [c["effect"] for c in candidates if same_lag(best["effect"], c["effect"]) and c["effect"] in residuals
            and c["explained"] >= float(limits["min_gain"]) and (
                abs(c["evidence"].x_floor_after - best["evidence"].x_floor_after)
                <= float(limits["parsimony_noise_fraction"])
                or float(np.sqrt(np.mean((residuals[best["effect"]] - residuals[c["effect"]]) ** 2))) <= same_prediction)]


def shapes_note(best: Mapping[str, Any], shapes: Sequence[str]) -> Note | None:
    """The note on a lag named where another shape of it does as well (None without one)."""
    if not shapes:
        return None
    return Note(NoteKind.LAG_SHAPES, effect=best["effect"],
                figures={"shapes": list(shapes), "lowpass": bool(EFFECTS[best["effect"]].lowpass)})
