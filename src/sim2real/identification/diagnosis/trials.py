"""Running the trials: which effects of the library a diagnosis fits on top of the model, each fitted as its rung
would be, and which of those fits failed to solve.

A candidate's trial fits the model with the candidate's line added and the lines it replaces removed
(:func:`trial_effects`), every way of holding or refining the current nonlinear parameters
(:func:`trial_fits`); a lag or a ripple is tried only where it could matter (:mod:`~sim2real.identification.diagnosis.lags`,
:mod:`~sim2real.identification.diagnosis.screens`). What a trial removes, and what the diagnosis concludes from all of
them, is :mod:`~sim2real.identification.diagnosis.candidates`'.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.forked import map_forked
from sim2real.identification import fitting
from sim2real.identification.diagnosis.caveats import NESTED_IN, SPANNED_BY
from sim2real.identification.diagnosis.current import CurrentResidual
from sim2real.identification.diagnosis.lags import after_other_shape, screen_lags
from sim2real.identification.diagnosis.screens import screen_ripples
from sim2real.identification.effects import EFFECTS
from sim2real.identification.inertial import import_solver
from sim2real.identification.records import Note, NoteKind


# A trial whose fit on the fit runs ends this many times further from them (x the floors) than the model it extends
# did not solve: the extended model holds the current one (its own coefficients zero), at the same prior weight.
FAILED_TRIAL_FACTOR = 2.0


def _fit_x_floor(result: fitting.FitResult, data: fitting.TorqueData) -> float:
    """A fit's RMS on its own runs, each joint in units of its floor, arm-wide."""
    floor = np.asarray(data.noise_floor, dtype=float)
    per_joint = np.array([result.fit_rmse["per_joint"][j] for j in data.joint_names], dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(floor > 0, per_joint / floor, per_joint)
    return float(np.sqrt(np.mean(ratio**2)))


def failed_trial(result: fitting.FitResult, current: fitting.FitResult | None,
                 data: fitting.TorqueData) -> dict[str, float] | None:
    """The fit-run figures of a trial that failed to solve (:data:`FAILED_TRIAL_FACTOR`), or None."""
    if current is None:
        return None
    trial, model = _fit_x_floor(result, data), _fit_x_floor(current, data)
    if not np.isfinite(trial) or trial > FAILED_TRIAL_FACTOR * max(model, 1e-12):
        return {"fit_x_floor": round(trial, 4) if np.isfinite(trial) else None, "model_fit_x_floor": round(model, 4)}
    return None


def replaced_by(name: str, model_effects: Sequence[str]) -> list[str]:
    """The effects of the model whose columns lie in the span of the candidate ``name``'s (:data:`SPANNED_BY`: a
    payload in the link inertias'). Its trial drops them and the verdict says to remove their lines: both in one model
    put the same torque in two sets of columns, a fit that only the inertial prior keeps from singular, and one that
    goes wrong where the prior is weak."""
    return [held for held in model_effects if held in SPANNED_BY.get(name, ())]


def trial_effects(model_effects: Sequence[str], name: str) -> list[str]:
    """The model a trial of ``name`` fits, as the user's model.yaml will list it: the candidate's line added at the end,
    the lines it holds removed (:func:`replaced_by`)."""
    replaced = replaced_by(name, model_effects)
    return [e for e in model_effects if e not in replaced] + [name]


def candidates_to_try(model_effects: Sequence[str], torque_source: str, forward: bool,
                      candidates: Sequence[str] | None = None) -> tuple[list[str], list[Note]]:
    """The effects of ``candidates`` (default: the library)
    :func:`~sim2real.identification.diagnosis.candidates.diagnose` fits on top of ``model_effects``, and those it does
    not, each a note of why; ``torque_source`` is the judged torque's, ``forward`` the signals' (the drive side
    predicts the measured torque from the command)."""
    tried: list[str] = []
    skipped: list[Note] = []
    for name in candidates if candidates is not None else EFFECTS:
        effect = EFFECTS[name]
        if name in model_effects:
            continue
        holder = next((held for held in model_effects if name in NESTED_IN.get(held, ())), None)
        if effect.per_run:
            skipped.append(Note(NoteKind.PER_RUN, effect=name))
        elif holder is not None:
            skipped.append(Note(NoteKind.NESTED, effect=name, figures={"holder": holder}))
        elif effect.needs_commands and torque_source != "tau_cmd" and not forward:
            skipped.append(Note(NoteKind.DRIVE_BEHIND_SENSOR, effect=name))
        elif effect.sensor_side and (torque_source == "tau_cmd" or forward):
            skipped.append(Note(NoteKind.SENSOR_ON_COMMANDS, effect=name))
        else:
            tried.append(name)
    return tried, skipped


def _trial_way(item: tuple[str, Mapping[str, Any]], model_effects: Sequence[str], **inputs: Any,
               ) -> tuple[fitting.FitResult, np.ndarray] | None:
    """One way (:func:`sim2real.identification.fitting.previous_ways`) of fitting the candidate ``item[0]`` on the current model,
    and its holdout residual (:func:`sim2real.identification.fitting.rung.fit_way`)."""
    name, way = item
    replaced = replaced_by(name, model_effects)
    # the held or starting nonlinear parameters of the lines the candidate replaces have no place in its model
    way = {key: ({e: v for e, v in value.items() if e not in replaced} if isinstance(value, Mapping) else value)
           for key, value in way.items()}
    return fitting.fit_way(way, effect_names=trial_effects(model_effects, name), **inputs)


def trial_fits(names: Sequence[str], model_effects: Sequence[str], context: fitting.FitContext,
               nonlinear_fixed: Mapping[str, np.ndarray] | None) -> dict[str, tuple[fitting.FitResult, np.ndarray]]:
    """Each candidate of ``names`` fitted as its rung will be: the current nonlinear parameters (``nonlinear_fixed``)
    refined again or held, whichever predicts better (:func:`sim2real.identification.fitting.fit_on_the_previous`);
    (fit, holdout residual).

    Every way of every candidate is one piece of work, on up to ``context.workers`` processes side by side
    (:func:`sim2real.forked.map_forked`: the same numbers as one after the other). The candidates' first ways
    go first (they refine, and take longest).
    """
    previous = fitting.previous_nonlinear(nonlinear_fixed)
    ways = fitting.previous_ways(previous, uncertainty=False)
    items = [(name, way) for way in ways for name in names]
    if context.workers > 1 and len(items) > 1:
        import_solver()
    inputs = {key: value for key, value in fitting.way_inputs([], context).items() if key != "effect_names"}
    fits = map_forked(_trial_way, items, context.workers, {"model_effects": list(model_effects), **inputs})
    out = {}
    for name in names:
        candidate = [fit for (item_name, _), fit in zip(items, fits, strict=True) if item_name == name]
        result, residual, _ = fitting.better_way(
            candidate, trial_effects(model_effects, name), context,
            {e: v for e, v in previous.items() if e not in replaced_by(name, model_effects)}, uncertainty=False)
        out[name] = (result, residual)
    return out


def _tried(model_effects: Sequence[str], context: fitting.FitContext, now: CurrentResidual,
           current: fitting.FitResult | None, limits: Mapping[str, float],
           candidates: Sequence[str] | None) -> tuple[dict[str, tuple[fitting.FitResult, np.ndarray]], list[str], list[Note]]:
    """The trials of the candidates worth one (screened: :mod:`~sim2real.identification.diagnosis.lags`,
    :mod:`~sim2real.identification.diagnosis.screens`), the names tried in order and the notes of those skipped."""
    tried, skipped = candidates_to_try(model_effects, context.holdout_data.torque_source,
                                       context.holdout_signals.forward, candidates)
    # A lag is fitted only where it could matter (diagnosis.lags): screened, or waiting for its other shape's trial.
    waiting = screen_lags(tried, skipped, current, context, now, limits)
    # A ripple is fitted only where some joint's residual repeats with its position (diagnosis.screens).
    screen_ripples(tried, skipped, current, context, now, limits)
    fixed = current.nonlinear if current is not None else None
    trials = trial_fits(tried, model_effects, context, fixed)
    second = after_other_shape(waiting, trials, skipped, now, limits)
    if second:
        trials.update(trial_fits(second, model_effects, context, fixed))
        tried += second
    return trials, tried, skipped
