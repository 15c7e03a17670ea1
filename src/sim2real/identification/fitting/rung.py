"""One rung's fit (:func:`fit`): the nonlinear refinement, the linear parameters, the physically
consistent fit (:mod:`sim2real.identification.fitting.consistent`) and the bootstrap; a model fitted on top of the
previous one (:func:`fit_on_the_previous`), the ways it is fitted and the better of them."""

from __future__ import annotations

import copy
import functools
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.identification.effects import Signals, get_effect
from sim2real.identification.fitting.bootstrap import _block_bootstrap, _prune, replicate_intervals
from sim2real.identification.fitting.data import TorqueData, link_side
from sim2real.identification.fitting.scoring import holdout_metrics, joint_weights
from sim2real.identification.fitting.nominal import NominalModel, make_signals
from sim2real.identification.fitting.linear import _linear_fit
from sim2real.identification.fitting.problem import FitResult, _Problem, _values
from sim2real.identification.fitting.consistent import (  # noqa: F401  (the rung's settings that set the prior)
    INERTIA_PRIOR_FALLBACK, PRIOR_START_SETTING, _consistent_fit,
)
from sim2real.identification.fitting.context import FitContext
from sim2real.identification.fitting.refine import Nonlinear, Refinements, _refine_nonlinear
from sim2real.identification.model_config import EFFECT_JOINTS_KEY
from sim2real.identification.records import Note, NoteKind
from sim2real.forked import map_forked
from sim2real.identification.inertial import import_solver
from sim2real.stats import rmse


DEFAULT_SETTINGS: dict[str, Any] = {
    "fit_rate_hz": 200.0,  # fit and judge on a decimated grid: the filtered signals are smooth
    "refine_max_samples": 2000,  # samples used by the nonlinear refinement
    "refine_windows_s": None,  # beyond refine_max_samples: windows of this length instead of every k-th sample
    "bootstrap_replicates": 200,
    "bootstrap_block_s": 1.0,
    "confidence": 0.95,
    "bootstrap_few_blocks_correction": True,  # small_sample_stretch; off only to measure what it corrects
    "seed": 0,
    # Weight of the entropic pull of link inertias towards CAD, x the noise floor's variance (sim2real.identification.inertial):
    # "held_out" chooses it on held-out blocks of the fit runs (inertial.choose_prior_weight); a number fixes it.
    "inertia_regularization": "held_out",
    # Each joint's residual in units of its own noise floor (joint_weights); "none": plain N*m, to measure it.
    "joint_weighting": "noise_floor",
}


# The joints that barely move in the fit runs (sim2real.measurements.motion.still_joints), absent when every joint
# moves: their drives' own parameters are held at the nominal model's (_Problem.without_still).
STILL_JOINTS_SETTING = "still_joints"
# The lines model.yaml keeps on some joints ({effect: [joints]}), absent when none is: each such effect is fitted on
# its joints only and absent on the others (_Problem.held_rows), its values only on its joints (restricted_values).
EFFECT_JOINTS_SETTING = EFFECT_JOINTS_KEY


def fit(
    effect_names: Sequence[str],
    nominal: NominalModel | None,
    data: TorqueData,
    settings: Mapping[str, Any] | None = None,
    signals: Signals | None = None,
    uncertainty: bool = True,
    consistency: bool = True,
    nonlinear: Nonlinear = Nonlinear(),
) -> FitResult:
    """Fit the model ``nominal + effect_names`` on ``data`` (the fit runs).

    ``consistency``: solve the rung as one convex program (:mod:`sim2real.identification.inertial`: link inertias
    physically consistent, friction/armature/payload mass >= 0) and keep the unconstrained fit beside
    it (``result.unconstrained``); ``uncertainty``: bootstrap intervals; ``nonlinear``: the nonlinear parameters
    held, where the refinement of the others starts, and where refinements are kept
    (:class:`sim2real.identification.fitting.refine.Nonlinear`); ``signals``: what the judged torque is predicted
    from (default: the nominal model on ``data``; the drive side passes its own and no nominal model).
    """
    settings = {**DEFAULT_SETTINGS, **(settings or {})}
    if signals is None:
        assert nominal is not None, "give the nominal model or the signals (the drive side has no nominal model)"
        signals = make_signals(nominal, data)
    effects = [get_effect(name) for name in effect_names]
    notes = []
    for effect in effects:
        if effect.needs_commands and data.torque_source != "tau_cmd" and not signals.forward:
            notes.append(Note(NoteKind.DELAY_NOT_SEEN, effect=effect.name,
                              figures={"torque_source": data.torque_source}).as_document())
    states = {e.name: e.prepare(signals) for e in effects}
    weights = joint_weights(data.noise_floor, str(settings.get("joint_weighting", "noise_floor")))
    problem = _Problem(effects, signals, states, weights, still_joints=settings.get(STILL_JOINTS_SETTING) or (),
                       effect_joints=effect_joints_of(settings, effect_names))
    refine = functools.partial(_refine_nonlinear, problem, data.tau, settings, nonlinear.held, nonlinear.start)
    refined = refine() if nonlinear.refinements is None else nonlinear.refinements.get_or_compute(
        effect_names, settings, nonlinear.held, nonlinear.start, refine)
    return _rung_fit(effect_names, problem, data, settings, refined, notes, uncertainty, consistency)


def effect_joints_of(settings: Mapping[str, Any], effect_names: Sequence[str]) -> dict[str, list[str]]:
    """The lines of ``effect_names`` the fit ``settings`` keep on some joints (:data:`EFFECT_JOINTS_SETTING`)."""
    kept = settings.get(EFFECT_JOINTS_SETTING) or {}
    return {name: list(kept[name]) for name in effect_names if name in kept}


def restricted_values(values: Any, joints: Sequence[str], joint_names: Sequence[str]) -> Any:
    """An effect's values (or intervals) with every per-joint mapping (keyed by ``joint_names``) narrowed to
    ``joints``: a line kept on those joints holds the effect there alone."""
    if isinstance(values, Mapping):
        if values and set(values) <= set(joint_names):
            return {j: v for j, v in values.items() if j in joints}
        return {k: restricted_values(v, joints, joint_names) for k, v in values.items()}
    return values


def _rung_fit(effect_names: Sequence[str], problem: _Problem, data: TorqueData, settings: Mapping[str, Any],
              nonlinear: dict[str, np.ndarray], notes: list[Any], uncertainty: bool, consistency: bool) -> FitResult:
    """:func:`fit` at its refined nonlinear parameters: the linear fit, its consistent form and its intervals."""
    effects, signals, states = problem.effects, problem.signals, problem.states
    theta, residual, sizes = _linear_fit(problem, data.tau, nonlinear)
    unconstrained = FitResult(
        effects=list(effect_names), theta=theta, nonlinear=nonlinear, states=copy.deepcopy(states),
        values=_values(effects, theta, nonlinear, signals, states), intervals={},
        fit_rmse=rmse(residual, data.joint_names), notes=list(notes),
    )
    record: dict[str, Any] = {}
    if consistency:
        theta, residual, record = _consistent_fit(problem, data, nonlinear, theta, settings, residual)
        notes.extend(record.pop("notes"))
    values = _values(effects, theta, nonlinear, signals, states)
    intervals: dict[str, Any] = {}
    if uncertainty:
        replicates = _block_bootstrap(problem, data.tau, nonlinear, theta, sizes, settings)
        if replicates is not None:
            intervals = _prune(replicate_intervals(effects, *replicates, signals, states, float(settings["confidence"])))
    kept = problem.effect_joints
    if kept:
        values = {k: restricted_values(v, kept[k], signals.joint_names) if k in kept else v for k, v in values.items()}
        intervals = {k: restricted_values(v, kept[k], signals.joint_names) if k in kept else v
                     for k, v in intervals.items()}
    return FitResult(
        effects=list(effect_names), theta=theta, nonlinear=nonlinear, states=states, values=values,
        intervals=intervals, fit_rmse=rmse(residual, data.joint_names), notes=notes, consistency=record,
        unconstrained=unconstrained if consistency else None, after_sensor=link_side(data) and not signals.forward,
        effect_joints={k: list(v) for k, v in kept.items()},
    )


def fit_on_the_previous(effect_names: Sequence[str], context: FitContext, previous: Mapping[str, np.ndarray] | None,
                        uncertainty: bool = True) -> tuple[FitResult, np.ndarray, str]:
    """A model fitted on top of the previous one, on ``context``'s fit runs and judged on its holdout runs: (fit,
    holdout residual, how its nonlinear parameters were set).

    Two ways to carry the previous model's nonlinear parameters (friction slopes and offsets, a delay):
    refine them all again from there, so that a smoothing refined before the rotor inertia was in the
    model can move once it is, or hold them, so that a sharp sigmoid cannot wander off to absorb what
    the new effect should explain. The fit runs alone cannot tell which generalises (the refinement
    always lowers the fit residual); the one whose holdout residual is smaller, each joint in units of
    its own floor, is kept. The diagnosis and the ladder use this same rule, so a rung delivers what
    its diagnosis promised. ``"refined"`` also when there is nothing to hold. With two ``context.workers``, both
    ways are fitted side by side (:func:`sim2real.forked.map_forked`).
    """
    previous = previous_nonlinear(previous)
    ways = previous_ways(previous, uncertainty)
    if context.workers > 1 and len(ways) > 1:
        import_solver()
    fits = map_forked(fit_way, ways, context.workers, way_inputs(effect_names, context))
    return better_way(fits, effect_names, context, previous, uncertainty)


def way_inputs(effect_names: Sequence[str], context: FitContext) -> dict[str, Any]:
    """The keyword arguments of :func:`fit_way` for ``effect_names`` on ``context``."""
    return {"effect_names": effect_names, "nominal": context.nominal, "data": context.fit_data,
            "settings": context.settings, "signals": context.fit_signals, "holdout_data": context.holdout_data,
            "holdout_signals": context.holdout_signals, "refinements": context.refinements}


def previous_nonlinear(previous: Mapping[str, np.ndarray] | None) -> dict[str, np.ndarray]:
    """The previous model's nonlinear parameters that exist (an effect without any has an empty array)."""
    return {k: v for k, v in (previous or {}).items() if np.size(v)}


def previous_ways(previous: Mapping[str, np.ndarray], uncertainty: bool) -> list[dict[str, Any]]:
    """The ways of :func:`fit_on_the_previous` (:func:`fit_way`'s ``way``): refined from ``previous``
    (:func:`previous_nonlinear`), and held at it when there is anything to hold."""
    ways: list[dict[str, Any]] = [{"uncertainty": uncertainty, "start": previous}]
    if previous:
        ways.append({"uncertainty": False, "held": previous})
    return ways


def better_way(fits: Sequence[tuple[FitResult, np.ndarray]], effect_names: Sequence[str], context: FitContext,
               previous: Mapping[str, np.ndarray], uncertainty: bool) -> tuple[FitResult, np.ndarray, str]:
    """Of the fits of :func:`previous_ways`, each with its holdout residual (:func:`fit_way`), the one whose
    residual is smaller, each joint in units of its own floor (:func:`fit_on_the_previous`); held and asked for
    ``uncertainty``, it is fitted again with it."""
    holdout = context.holdout_data
    weights = joint_weights(holdout.noise_floor, str({**DEFAULT_SETTINGS, **(context.settings or {})}["joint_weighting"]))

    def score(residual: np.ndarray) -> float:
        return float(np.sum((residual * weights) ** 2))

    refined, residual = fits[0]
    if not previous:
        return refined, residual, "refined"
    held, held_residual = fits[1]
    if score(held_residual) >= score(residual):
        return refined, residual, "refined"
    if uncertainty:
        held = fit(effect_names, context.nominal, context.fit_data, context.settings, signals=context.fit_signals,
                   uncertainty=True, nonlinear=Nonlinear(held=previous))
        # the fit returned's, to the bit
        _, held_residual = holdout_metrics(held, context.nominal, holdout, context.holdout_signals)
    return held, held_residual, "held"


def fit_way(way: Mapping[str, Any], holdout_data: TorqueData, holdout_signals: Signals | None,
            refinements: Refinements | None = None, **inputs: Any) -> tuple[FitResult, np.ndarray]:
    """:func:`fit` with one way of carrying the previous nonlinear parameters (:func:`fit_on_the_previous`; ``way``:
    ``uncertainty`` and the parameters ``held`` or refined from their ``start``), and its holdout residual."""
    nonlinear = Nonlinear(held=way.get("held"), start=way.get("start"), refinements=refinements)
    result = fit(**inputs, uncertainty=way["uncertainty"], nonlinear=nonlinear)
    return result, holdout_metrics(result, inputs["nominal"], holdout_data, holdout_signals)[1]
