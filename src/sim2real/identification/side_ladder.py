"""One side's ladder (:func:`fit_ladder`): every rung (nominal, then each effect added in turn, refining only the new
effect's nonlinear parameters) fitted on the ``role: fit`` runs and judged on the ``role: holdout`` runs, its
``ladder.json`` content, and the diagnosis of the last rung (:mod:`sim2real.identification.diagnosis`) with, on a side
judged against the motion, its model-free ceiling. Rungs and diagnoses of an earlier round with the same inputs are
read back from the fit cache (:class:`sim2real.cache.FitCache`)."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.cache import FitCache
from sim2real.identification.diagnosis import DEFAULT_DIAGNOSIS, Diagnosis, diagnose, model_free_ceiling
from sim2real.identification.diagnosis.current import CurrentResidual
from sim2real.identification.diagnosis.promise import kept_promise, promised_effect
from sim2real.identification.diagnosis.raises import add_line, rung_raises
from sim2real.identification.diagnosis.trials import trial_effects
from sim2real.identification.documents import round_floats
from sim2real.identification.fitting import (
    EFFECT_JOINTS_SETTING, PRIOR_START_SETTING, STILL_JOINTS_SETTING, FitContext, FitResult, Refinements, TorqueData,
    effect_joints_of, fit_on_the_previous, floor_units, holdout_metrics, predict,
)
from sim2real.identification.ladder_rows import Figures, Rung, RungMetrics
from sim2real.identification.records import Note, NoteKind, Side, Status
from sim2real.stats import joint_figures, rmse


@dataclasses.dataclass(frozen=True)
class SideLadder:
    """One side's ladder: its ``ladder.json`` content (``ladder``, ``noise_floor``, ...), the last rung's fit, the
    diagnosis of that rung (None when not asked for), and its residuals (judged minus predicted torque) on the
    holdout and the fit data (the fit data's: None on the drive side, whose diagnosis has no model-free ceiling)."""

    document: dict[str, Any]
    result: FitResult
    diagnosis: Diagnosis | None
    holdout_residual: np.ndarray
    fit_residual: np.ndarray | None

    def as_document(self) -> dict[str, Any]:
        """The side's ``ladder.json`` content with its diagnosis's document (a side judged alone)."""
        if self.diagnosis is None:
            return dict(self.document)
        return {**self.document, "diagnosis": round_floats(self.diagnosis.as_document())}


def state_domain_status(data: TorqueData) -> dict[str, str]:
    """The state-domain refinement replays commands in MuJoCo: skipped here, and why (``no_commands``: the runs have
    no commanded torque to replay; ``replayed_in_gap_report``: the gap report replays each rung)."""
    return {"status": "skipped", "reason": "replayed_in_gap_report" if data.has_commands else "no_commands"}


def fit_ladder(effect_names: Sequence[str], context: FitContext, *, side: Side = Side.BODY,
               candidates: Sequence[str] | None = None, limits: Mapping[str, float] | None = None,
               diagnosed: bool = True, cache: FitCache | None = None) -> SideLadder:
    """Every rung (nominal, then each effect added in turn) fitted and judged on one side of the model
    (:mod:`sim2real.identification.sides`); the diagnosis of the last (``diagnosed``).

    ``context``: the side's data, signals and fit settings; ``candidates``: the effects the diagnosis tries;
    ``limits``: the diagnosis's (model.yaml ``diagnosis``); ``cache``: rungs and diagnoses of earlier rounds with the
    same inputs are read back from it (:class:`sim2real.cache.FitCache`), the same to the last bit. Off the drive
    side, the last rung's residual on the fit data is returned too: what the model-free ceiling learns from and,
    with the holdout's, what the gap report judges the current model by.
    """
    cache = cache or FitCache(None)
    # Everything a rung depends on but its effects: a rung of an earlier round with the same is the same fit.
    inputs = cache.key(str(side), context.nominal, context.fit_data, context.holdout_data, context.fit_signals,
                       context.holdout_signals)
    # The diagnosis's trials keep their refinements: the rung of the candidate the user adds reads its back.
    if cache.directory is not None:
        context = dataclasses.replace(context, refinements=Refinements(cache, inputs))
    limits = {**DEFAULT_DIAGNOSIS, **(limits or {})}
    rungs, result, residual = _rungs(effect_names, context, cache, inputs, limits)
    document = _ladder_document(rungs, context)
    # the model-free ceiling learns from the fit runs' residual (a side judged against the motion only)
    fit_residual = (context.fit_data.tau - predict(result, context.nominal, context.fit_data, context.fit_signals)
                    if side != Side.DRIVE else None)
    if not diagnosed:
        return SideLadder(round_floats(document), result, None, residual, fit_residual)
    prior = (result.consistency or {}).get("inertia_prior")
    # Every candidate is fitted with the prior weight the current rung chose: a candidate that merely let the
    # inertias move more would otherwise be credited with their fall, on joints where it does nothing. Its
    # rung chooses again on held-out blocks, which the holdout can find worse: the recommended candidate promises
    # what that rung delivers (_promised_by_its_rung).
    trials = context.with_settings({**context.settings, "inertia_regularization": prior["weight"]} if prior
                                   else context.settings)
    key = cache.key(inputs, list(effect_names), residual, result.nonlinear, dict(trials.settings), limits, candidates)
    diagnosis = cache.get_or_compute("diagnosis", key, functools.partial(
        _diagnose_side, effect_names, trials, residual, fit_residual, side=side, current=result, limits=limits,
        candidates=candidates))
    diagnosis = _promised_by_its_rung(diagnosis, effect_names, context, cache, inputs, result, residual, limits)
    diagnosis = _declared_within_the_rule(diagnosis, effect_names, context, cache, inputs, result, residual, limits)
    return SideLadder(round_floats(document), result, diagnosis, residual, fit_residual)


def _declared_within_the_rule(diagnosis: Diagnosis, effect_names: Sequence[str], context: FitContext, cache: FitCache,
                              inputs: str, result: FitResult, residual: np.ndarray,
                              limits: Mapping[str, float]) -> Diagnosis:
    """``diagnosis`` whose model-free ceiling declares a drift only where its rung raises no joint beyond the noise
    (:mod:`sim2real.identification.diagnosis.raises`), as a recommended candidate's: the line for every joint, else
    kept on the joints it helps, else withheld. Each rung tried is the one the next round fits (read back from
    ``cache``)."""
    ceiling = diagnosis.model_free
    if ceiling is None or ceiling.declare is None:
        return diagnosis
    advice = ceiling.declare
    joints = list(context.holdout_data.joint_names)
    now = CurrentResidual.of(residual, context.holdout_data.noise_floor)

    def line_raises(kept: Sequence[str] | None) -> tuple[dict[str, tuple[float, float]], list[str]]:
        settings = dict(context.settings)
        if kept is not None:
            settings[EFFECT_JOINTS_SETTING] = {**(settings.get(EFFECT_JOINTS_SETTING) or {}), advice.effect: list(kept)}
        _, after, _, _ = _next_rung(trial_effects(effect_names, advice.effect), context.with_settings(settings),
                                    cache, inputs, result, residual, limits)
        return rung_raises(after, now, joints, limits)

    raised, helped = line_raises(None)
    if not raised:
        return diagnosis
    if helped and not line_raises(helped)[0]:
        kept = dataclasses.replace(advice, line=add_line(advice.effect, helped), kept_to=tuple(helped), raised=raised)
        return dataclasses.replace(diagnosis, model_free=dataclasses.replace(ceiling, declare=kept))
    withheld = dataclasses.replace(advice, raised=raised)
    return dataclasses.replace(diagnosis, model_free=dataclasses.replace(ceiling, declare=None, withheld=withheld))


def _promised_by_its_rung(diagnosis: Diagnosis, effect_names: Sequence[str], context: FitContext, cache: FitCache,
                          inputs: str, result: FitResult, residual: np.ndarray,
                          limits: Mapping[str, float]) -> Diagnosis:
    """``diagnosis`` whose recommended candidate promises what its rung delivers (:mod:`sim2real.identification.
    diagnosis.promise`): where the current rung chose the inertial prior's weight on held-out blocks, the rung of
    the added line chooses it again, as :func:`_rungs` fits it (the next round reads it back from ``cache``)."""
    effect = promised_effect(diagnosis)
    chosen = (result.consistency or {}).get("inertia_prior") or {}
    if effect is None or "grid" not in chosen:
        return diagnosis  # no weight chosen again: the trial is the rung's fit
    kept_to = diagnosis.candidates[0].kept_to  # a line kept on the joints it helps (diagnosis.raises)
    if kept_to:
        context = context.with_settings({**context.settings, EFFECT_JOINTS_SETTING: {
            **(context.settings.get(EFFECT_JOINTS_SETTING) or {}), effect: list(kept_to)}})
    rung, after, _, _ = _next_rung(trial_effects(effect_names, effect), context, cache, inputs, result, residual,
                                   limits)
    prior = (rung.consistency or {}).get("inertia_prior") or {}
    return kept_promise(diagnosis, after, context.holdout_data.noise_floor, prior.get("weight"))


def _next_rung(effects: Sequence[str], context: FitContext, cache: FitCache, inputs: str, result: FitResult | None,
               before: np.ndarray | None = None, limits: Mapping[str, float] | None = None,
               ) -> tuple[FitResult, np.ndarray, str, Figures | None]:
    """The rung of ``effects`` fitted on the one before it (``result``; None: the nominal model; ``before``: its
    holdout residual), read back from ``cache`` when fitted before (:func:`_rung`). The prior's weight is searched
    from the previous rung's choice (fitting.PRIOR_START_SETTING); where the weight chosen again raises a joint beyond
    the noise (:func:`~sim2real.identification.diagnosis.raises.rung_raises`, ``limits`` the diagnosis's) and the
    previous rung's weight raises none, the rung holds that weight instead (:func:`_held_prior`)."""
    previous = result.nonlinear if result is not None else None
    chosen = ((result.consistency or {}).get("inertia_prior") or {}) if result is not None else {}
    rung_context = (context.with_settings({**context.settings, PRIOR_START_SETTING: chosen["weight"]})
                    if "grid" in chosen else context)
    rung_context = rung_context.with_settings(narrowed(rung_context.settings, effects))
    rung = cache.get_or_compute("rung", cache.key(inputs, list(effects), previous, dict(rung_context.settings)),
                                functools.partial(_rung, list(effects), rung_context, previous))
    again = (rung[0].consistency or {}).get("inertia_prior") or {}
    if before is None or "grid" not in chosen or "grid" not in again or again["weight"] == chosen["weight"]:
        return rung
    joints = list(context.holdout_data.joint_names)
    now = CurrentResidual.of(before, context.holdout_data.noise_floor)
    limits = {**DEFAULT_DIAGNOSIS, **(limits or {})}
    raised, _ = rung_raises(rung[1], now, joints, limits)
    if not raised:
        return rung
    held_context = rung_context.with_settings({**rung_context.settings, "inertia_regularization": chosen["weight"]})
    held = cache.get_or_compute("rung", cache.key(inputs, list(effects), previous, dict(held_context.settings)),
                                functools.partial(_rung, list(effects), held_context, previous))
    if rung_raises(held[1], now, joints, limits)[0]:
        return rung  # the line raises a joint at either weight: the weight is not what raises it
    return _held_prior(held, again, raised)


def _held_prior(rung: tuple[FitResult, np.ndarray, str, Figures | None], again: Mapping[str, Any],
                raised: Mapping[str, tuple[float, float]]) -> tuple[FitResult, np.ndarray, str, Figures | None]:
    """``rung`` (fitted at the previous rung's prior weight) whose prior record says why: the weight chosen again by
    cross-validation (``again``, its grid and scores kept) raised ``raised`` on the holdout, which judges a rung's
    weight as it judges a line (the loop's rule: no rung raises a joint beyond the noise)."""
    result, residual, carried, free = rung
    held = (result.consistency or {}).get("inertia_prior") or {}
    record = {**{k: v for k, v in again.items() if k != "chosen_by"}, "weight": held.get("weight"),
              "chosen_by": {"method": "held_from_previous_rung", "cross_validated": again["weight"],
                            "raised": {j: list(v) for j, v in raised.items()},
                            "cross_validation": again.get("chosen_by")}}
    consistency = {**(result.consistency or {}), "inertia_prior": record}
    return dataclasses.replace(result, consistency=consistency), residual, carried, free


def narrowed(settings: Mapping[str, Any], effects: Sequence[str]) -> dict[str, Any]:
    """The fit ``settings`` of a rung of ``effects``: the lines kept on some joints
    (:data:`~sim2real.identification.fitting.EFFECT_JOINTS_SETTING`) narrowed to those it holds, absent when none is
    (a rung without such a line is the fit of an earlier round, read back from the cache)."""
    out = {key: value for key, value in settings.items() if key != EFFECT_JOINTS_SETTING}
    kept = effect_joints_of(settings, effects)
    return {**out, EFFECT_JOINTS_SETTING: kept} if kept else out


def _rungs(effect_names: Sequence[str], context: FitContext, cache: FitCache, inputs: str,
           limits: Mapping[str, float]) -> tuple[list[dict[str, Any]], FitResult, np.ndarray]:
    """Each rung's ``ladder.json`` entry, and the last rung's fit and holdout residual."""
    rungs: list[dict[str, Any]] = []
    result: FitResult | None = None
    residual: np.ndarray | None = None
    for k in range(len(effect_names) + 1):
        effects = list(effect_names[:k])
        result, residual, carried, free = _next_rung(effects, context, cache, inputs, result, residual, limits)
        rungs.append(_rung_document(effects, result, residual, carried, free, context.holdout_data))
    assert result is not None and residual is not None
    return rungs, result, residual


def _rung_document(effects: Sequence[str], result: FitResult, residual: np.ndarray, carried: str,
                   free: Figures | None, holdout_data: TorqueData) -> dict[str, Any]:
    """One rung's entry of ``ladder.json`` (:class:`~sim2real.identification.ladder_rows.Rung`): its effects,
    parameters and intervals, its holdout metrics (each joint in units of its own floor as its headline), and what it
    says of its fit."""
    x_floor = floor_units(residual, holdout_data.noise_floor)
    notes = list(result.notes)
    if carried == "held":
        # refined again, the previous rung's nonlinear parameters predicted the holdout runs worse
        notes.append(Note(NoteKind.NONLINEAR_HELD).as_document())
    metrics = RungMetrics(
        torque_rmse=rmse(residual, holdout_data.joint_names), fit_torque_rmse=result.fit_rmse,
        # the rung's headline: each joint in units of its own noise floor
        torque_x_floor=joint_figures(x_floor["overall"], holdout_data.joint_names, x_floor["per_joint"]),
        # the same rung without the physical constraints: what consistency costs (or gains) on holdout
        unconstrained_torque_rmse=free)
    # Wall time stays out of the document (outputs are byte-identical on rebuild).
    consistency = ({k: v for k, v in result.consistency.items() if k != "solve_time_s"} if free is not None
                   else None)
    return Rung(tuple(effects), metrics, result.values, result.intervals, consistency, tuple(notes)).as_document()


def _ladder_document(rungs: list[dict[str, Any]], context: FitContext) -> dict[str, Any]:
    """One side's ``ladder.json`` content around its rungs: the runs, the noise floor, the settings."""
    holdout = context.holdout_data
    joints = holdout.joint_names
    floor = np.asarray(holdout.noise_floor)
    return {
        "joints": joints,
        "torque_source": holdout.torque_source,
        "fit_runs": context.fit_data.run_names,
        "holdout_runs": holdout.run_names,
        "ladder": rungs,
        "noise_floor": {"torque_rmse": joint_figures(float(np.sqrt(np.mean(floor**2))), joints, floor)},
        "state_domain": state_domain_status(holdout),
        "settings": {"fit": dict(context.settings)},
    }


def _diagnose_side(effect_names: Sequence[str], context: FitContext, holdout_residual: np.ndarray,
                   fit_residual: np.ndarray | None, *, side: Side, **options: Any) -> Diagnosis:
    """The diagnosis of one side (:func:`sim2real.identification.diagnosis.diagnose`) and, on a side judged against
    the motion, its model-free ceiling (:func:`sim2real.identification.diagnosis.model_free_ceiling`): when no effect
    is named, what kind of thing is left."""
    diagnosis = _still_rows_marked(diagnose(effect_names, context, holdout_residual, side=side, **options),
                                   context.settings.get(STILL_JOINTS_SETTING) or ())
    if side == Side.DRIVE:
        return diagnosis  # predicted forward from the command: the motion is not what it is a function of
    ceiling = model_free_ceiling(context.fit_data, fit_residual, context.holdout_data, holdout_residual,
                                 float(options["limits"]["noise_floor_factor"]), workers=context.workers,
                                 model_effects=effect_names,
                                 nominal_dynamics=context.nominal.dynamics if context.nominal else None)
    if diagnosis.status == Status.ADD_EFFECT and ceiling.declare is not None:
        # A candidate a held-out run judged comes first: a drift estimated on every run, holdout included, could
        # stand in for it; the next round's ceiling declares the drift if it is still there.
        ceiling = dataclasses.replace(ceiling, declare=None)
    return dataclasses.replace(diagnosis, model_free=ceiling)


def _rung(effects: Sequence[str], context: FitContext, previous: Mapping[str, np.ndarray] | None,
          ) -> tuple[FitResult, np.ndarray, str, Figures | None]:
    """One rung of :func:`fit_ladder` (:func:`fit_on_the_previous`) and, where it is constrained, the holdout
    torque RMSE of the same rung without the constraints: (fit, holdout residual, how its nonlinear parameters were
    carried, unconstrained RMSE or None), kept whole by the fit cache."""
    result, residual, carried = fit_on_the_previous(effects, context, previous)
    free = None
    if result.unconstrained is not None and result.consistency:
        free, _ = holdout_metrics(result.unconstrained, context.nominal, context.holdout_data, context.holdout_signals)
    return result, residual, carried, free


def _still_rows_marked(diagnosis: Diagnosis, still: Sequence[str]) -> Diagnosis:
    """``diagnosis`` with the per-joint rows of the joints the fit runs barely move marked ``judged: false``: their
    drives were held at the nominal model's (:func:`_still_setting`), and the report names them as not judged."""
    if not still:
        return diagnosis
    return dataclasses.replace(diagnosis, per_joint={
        joint: dataclasses.replace(row, judged=False) if joint in still else row
        for joint, row in diagnosis.per_joint.items()})
