"""One rung's fit (:func:`fit`): the nonlinear refinement, the linear parameters, the physically
consistent fit (:mod:`sim2real.identification.inertial`) and the bootstrap; a model fitted on top of the previous one
(:func:`fit_on_the_previous`)."""

from __future__ import annotations

import copy
import functools
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.identification.effects import Effect, Signals, get_effect
from sim2real.identification.fitting.bootstrap import _block_bootstrap, _prune, replicate_intervals
from sim2real.identification.fitting.data import TorqueData, link_side
from sim2real.identification.fitting.scoring import holdout_metrics, joint_weights
from sim2real.identification.fitting.nominal import NominalModel, make_signals
from sim2real.identification.fitting.linear import _linear_fit
from sim2real.identification.fitting.problem import FitResult, _Problem, _values
from sim2real.identification.fitting.context import FitContext
from sim2real.identification.fitting.refine import Nonlinear, Refinements, _refine_nonlinear
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


# The prior's weight (x the floor's variance) where no link inertia is fitted or the held-out choice fails.
INERTIA_PRIOR_FALLBACK = 1e-3


# Where the held-out search of the prior's weight starts (a weight the ladder sets to the previous rung's choice:
# a rung that adds one effect rarely moves it by more than a decade); absent, the search starts on PRIOR_GRID.
PRIOR_START_SETTING = "inertia_prior_start"

# The joints that barely move in the fit runs (sim2real.measurements.motion.still_joints), absent when every joint
# moves: their drives' own parameters are held at the nominal model's (_Problem.without_still).
STILL_JOINTS_SETTING = "still_joints"


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
    problem = _Problem(effects, signals, states, weights, still_joints=settings.get(STILL_JOINTS_SETTING) or ())
    refine = functools.partial(_refine_nonlinear, problem, data.tau, settings, nonlinear.held, nonlinear.start)
    refined = refine() if nonlinear.refinements is None else nonlinear.refinements.get_or_compute(
        effect_names, settings, nonlinear.held, nonlinear.start, refine)
    return _rung_fit(effect_names, problem, data, settings, refined, notes, uncertainty, consistency)


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
    return FitResult(
        effects=list(effect_names), theta=theta, nonlinear=nonlinear, states=states, values=values,
        intervals=intervals, fit_rmse=rmse(residual, data.joint_names), notes=notes, consistency=record,
        unconstrained=unconstrained if consistency else None, after_sensor=link_side(data) and not signals.forward,
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



def _consistent_fit(
    problem: _Problem, data: TorqueData, nonlinear: dict[str, np.ndarray], theta_free: dict[str, np.ndarray],
    settings: Mapping[str, Any], free_residual: np.ndarray | None = None,
) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, Any]]:
    """The rung's linear coefficients under the physical constraints; (theta, fit residual, record);
    ``free_residual``: the residual of ``theta_free``, when the caller has it.

    Link inertias enter as full per-body corrections (the regressor's columns), every other effect
    with its own columns and lower bounds. Offsets that are not linear (a payload's own inertia) are
    held at the current estimate and updated by fixed-point iteration, as in the unconstrained fit.
    """
    from sim2real.identification.inertial import InfeasibleFit

    blocks, lower, inertial = _consistent_blocks(problem, nonlinear)
    if free_residual is None:
        free_residual = data.tau - problem.predict(theta_free, nonlinear)
    record: dict[str, Any] = {"notes": []}
    if not blocks:
        return theta_free, free_residual, record
    weighted = _consistent_design(problem, nonlinear, blocks)
    bounds = np.concatenate(lower)
    floor = float(np.mean(np.asarray(data.noise_floor, dtype=float) ** 2))
    relative, prior = _inertia_prior(problem, data, nonlinear, weighted, bounds, inertial, settings, floor)
    if prior is not None:
        record["inertia_prior"] = prior
    weight = float(relative) * max(floor, 1e-12)
    try:
        theta, solution, solve_time = _solve_physical(problem, data, nonlinear, weighted, bounds, inertial, weight, blocks)
    except InfeasibleFit as exc:
        record["status"] = "infeasible"
        record["notes"].append(Note(NoteKind.CONSISTENCY_INFEASIBLE, figures={"reason": str(exc)}).as_document())
        return theta_free, free_residual, record
    del weighted  # before the prediction (a long log's largest array, when it was put together)
    residual = data.tau - problem.predict(theta, nonlinear)
    record.update({"status": solution.status, "solve_time_s": solve_time})
    if solution.check is not None and not solution.check.plain:  # the solver's word judged by measured residuals
        record["solver"] = solution.check.as_document()
    _contradiction(problem, theta_free, free_residual, residual, floor, record)
    return theta, residual, record


def _consistent_design(problem: _Problem, nonlinear: Mapping[str, np.ndarray],
                       blocks: Sequence[tuple[Effect, slice, np.ndarray, np.ndarray | None]]) -> Any:
    """The consistent fit's columns in the data term's units (each joint by its floor). On a long log the largest
    array of the fit: without a time shift its rows are put together a chunk at a time (DesignRows), never whole; the
    same bits."""
    if not problem.retimed(nonlinear):
        return problem.weighted_rows([b[2] for b in blocks])
    weighted = problem.shift(np.concatenate([b[2] for b in blocks], axis=2), [b[0] for b in blocks],
                             [b[2].shape[2] for b in blocks], nonlinear)  # a new array: weighted in place
    weighted *= problem.weights[None, :, None]
    return weighted


def _inertia_prior(problem: _Problem, data: TorqueData, nonlinear: Mapping[str, np.ndarray], weighted: Any,
                   bounds: np.ndarray, inertial: Any, settings: Mapping[str, Any],
                   floor: float) -> tuple[Any, dict[str, Any] | None]:
    """The pull of the link inertias towards CAD (a fraction of the noise floor's variance: model.yaml's
    fit.inertia_regularization, or chosen by cross-validation when it says ``held_out``) and its record (None without
    link inertias, or when the cross-validation found no feasible fit)."""
    from sim2real.identification.inertial import PRIOR_GRID, InfeasibleFit, choose_prior_weight, grid_around

    relative = settings["inertia_regularization"]
    if relative != "held_out":
        if inertial is None:
            return relative, None
        return relative, {"weight": float(relative), "chosen_by": {"method": "setting"}}
    if inertial is None:
        return INERTIA_PRIOR_FALLBACK, None
    try:
        start = settings.get(PRIOR_START_SETTING)
        choice = choose_prior_weight(weighted, (data.tau - problem.base({}, nonlinear)) * problem.weights,
                                     bounds, inertial, max(floor, 1e-12),
                                     grid=PRIOR_GRID if start is None else grid_around(float(start)))
    except InfeasibleFit:
        return INERTIA_PRIOR_FALLBACK, None  # the rung's own solve says what failed
    # how it was chosen, as data (sim2real.report.verdicts.chosen_by_text words it)
    chosen_by = {"method": "cross_validation", "blocks": choice.blocks,
                 "first_grid": list(PRIOR_GRID) if start is None else "around_previous", "bound": choice.bound}
    return choice.weight, {"weight": choice.weight, "grid": choice.grid, "scores": choice.scores,
                           "inside_searched_range": choice.bound is None, "chosen_by": chosen_by}


def _solve_physical(problem: _Problem, data: TorqueData, nonlinear: Mapping[str, np.ndarray], weighted: Any,
                    bounds: np.ndarray, inertial: Any, weight: float,
                    blocks: Sequence[tuple[Effect, slice, np.ndarray, np.ndarray | None]],
                    ) -> tuple[dict[str, np.ndarray], Any, float]:
    """(theta, the last solve's :class:`~sim2real.identification.inertial.program.ConsistentSolution`, the solves'
    time) of the physically consistent solve; offsets that are not linear (a
    payload's own inertia) by fixed-point iteration. Raises InfeasibleFit when there is no consistent solution."""
    from sim2real.identification.inertial import InfeasibleFit, physically_consistent, solve_consistent

    has_offset = any(type(e).offset is not Effect.offset and e.name != "link_inertia" for e in problem.effects)
    theta: dict[str, np.ndarray] = {}
    solve_time = 0.0
    for _ in range(3 if has_offset else 1):
        # The solver returns the link inertias' whole correction each time: their remainder off the basis (the
        # null_offset the last iteration stored) is part of it, not a term of the data to fit around.
        others = {name: value for name, value in theta.items() if name != "link_inertia"}
        solution = solve_consistent(weighted, (data.tau - problem.base(others, nonlinear)) * problem.weights,
                                    bounds, inertial, weight)
        solve_time += solution.solve_time_s
        for effect, cols, _, kept in blocks:
            coefficients = solution.coefficients[cols]
            if effect.name == "link_inertia":
                coefficients = effect.set_correction(problem.states[effect.name], coefficients)
            if kept is not None:  # the columns left out (a still joint's) at zero: the nominal value
                placed = np.zeros(kept.size)
                placed[kept] = coefficients
                coefficients = placed
            theta[effect.name] = coefficients
    for effect in problem.effects:
        theta.setdefault(effect.name, np.zeros(0))  # a time shift has no linear coefficients
    if inertial is not None:
        # The solver's fallback tolerances (ConicForm.solve) can end a hair outside the physical set: a
        # solution that is not consistent is not one.
        state = problem.states["link_inertia"]
        if not physically_consistent(inertial.anchors.reshape(-1) + state["basis"] @ theta["link_inertia"]
                                     + state["null_offset"]):
            raise InfeasibleFit(f"the solver's solution ({solution.status}) leaves a body's pseudo-inertia "
                                "indefinite")
    return theta, solution, solve_time


def _contradiction(problem: _Problem, theta_free: dict[str, np.ndarray], free_residual: np.ndarray,
                   residual: np.ndarray, floor: float, record: dict[str, Any]) -> None:
    """Whether the unconstrained fit is physical, into ``record``; when it is not and fits clearly better than the
    physical one, the data contradict a physical model with these effects: a note says so."""
    signals = problem.signals
    free_physical = _physical(problem, theta_free, signals)
    record["unconstrained_physical"] = free_physical
    # Compared as fitted: in the weighted units of the data term, where white noise at the floors is the arm's floor.
    fit_now = float(np.sqrt(np.mean((residual * problem.weights) ** 2)))
    fit_free = float(np.sqrt(np.mean((free_residual * problem.weights) ** 2)))
    noise = float(np.sqrt(floor))
    if not free_physical and fit_now > 1.1 * fit_free and fit_now - fit_free > 0.1 * noise:
        # The data pull the model out of the physical set: say so, never hide it behind the nominal model.
        record["contradiction"] = True
        record["notes"].append(Note(NoteKind.CONSISTENCY_CONTRADICTED, figures={
            "violations": _violations(problem, theta_free, signals), "free_rmse": fit_free,
            "physical_rmse": fit_now}).as_document())


def _consistent_blocks(problem: _Problem, nonlinear: Mapping[str, np.ndarray]) -> tuple[
        list[tuple[Effect, slice, np.ndarray, np.ndarray | None]], list[np.ndarray], Any]:
    """The consistent fit's columns (effect, its coefficients, its columns, which of the effect's columns these are:
    None, all), each effect's lower bounds and the link inertias' block
    (:class:`sim2real.identification.inertial.InertialBlock`, None without link_inertia): what
    :func:`sim2real.identification.inertial.solve_consistent` builds its program of. A still joint's drive columns
    (:meth:`_Problem.without_still`) are left out: the program would leave a column it cannot see anywhere."""
    from sim2real.identification.effects.link_inertia import correction_anchors
    from sim2real.identification.inertial import InertialBlock, pseudo_inertia
    from sim2real.identification.inertial.bands import InertiaBands, body_bounds

    signals = problem.signals
    blocks, lower, inertial = [], [], None
    start = 0
    for effect in problem.effects:
        if effect.time_shift or effect.per_run:
            continue
        kept = None
        if effect.name == "link_inertia":
            cols = problem.per_run_removed(signals.regressor)
            anchors = correction_anchors(signals.nominal)
            # A body's mass must lie inside its meshes' ellipsoid where the CAD link itself does.
            bounds = signals.nominal.get("mesh_bounds")
            ellipsoids = [
                q if q is not None and float(np.trace(pseudo_inertia(a) @ q)) >= 0 else None
                for a, q in zip(anchors, (bounds.ellipsoids if bounds else None) or [None] * len(anchors), strict=True)
            ]
            inertial = InertialBlock(slice(start, start + cols.shape[2]), anchors, ellipsoids, body_bounds(
                anchors, bounds.hulls if bounds else None, signals.nominal.get("inertia_bands") or InertiaBands()))
            lower.append(np.full(cols.shape[2], -np.inf))
            problem.states[effect.name]["null_offset"] = np.zeros(cols.shape[2])
        else:
            cols = problem.block(effect, nonlinear)
            bounds_of = np.asarray(effect.theta_lower(signals, cols.shape[2]), dtype=float)
            if problem.still_rows.size and effect.drive:
                kept = np.any(cols != 0.0, axis=(0, 1))
                cols, bounds_of = cols[:, :, kept], bounds_of[kept]
            lower.append(bounds_of)
        blocks.append((effect, slice(start, start + cols.shape[2]), cols, kept))
        start += cols.shape[2]
    return blocks, lower, inertial


def _physical(problem: _Problem, theta: dict[str, np.ndarray], signals: Signals) -> bool:
    """Does a solution satisfy every constraint of the consistent fit?"""
    return not _violations(problem, theta, signals)


def _violations(problem: _Problem, theta: dict[str, np.ndarray], signals: Signals) -> list[dict[str, Any]]:
    """What is non-physical in a solution, effect by effect (empty when nothing): a link inertia's bodies whose
    pseudo-inertia is indefinite, or how many of an effect's values lie below their physical bound."""
    from sim2real.identification.effects.link_inertia import correction_anchors
    from sim2real.identification.inertial import min_eigenvalues

    found = []
    for effect in problem.effects:
        coefficients = np.asarray(theta.get(effect.name, []), dtype=float)
        if effect.time_shift or not coefficients.size:
            continue
        if effect.name == "link_inertia":
            state = problem.states[effect.name]
            anchors = correction_anchors(signals.nominal)
            eig = min_eigenvalues(anchors.reshape(-1) + state["basis"] @ coefficients + state["null_offset"])
            bad = [signals.nominal["body_links"][b] for b in np.flatnonzero(eig <= 0)]
            if bad:
                found.append({"effect": "link_inertia", "bodies": bad})
            continue
        low = effect.theta_lower(signals, coefficients.size)
        below = np.flatnonzero(coefficients < low - 1e-9)
        if below.size:
            found.append({"effect": effect.name, "below_bound": int(below.size)})
    return found

