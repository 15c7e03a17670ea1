"""A rung's physically consistent fit (:func:`_consistent_fit`): the linear coefficients under the physical
constraints (:mod:`sim2real.identification.inertial`: the pseudo-inertia LMIs and each effect's sign bounds), the
pull of the link inertias towards CAD, and whether the data contradict the constraints (:func:`_violations`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.identification.effects import Effect, Signals
from sim2real.identification.fitting.data import TorqueData
from sim2real.identification.fitting.problem import _Problem
from sim2real.identification.records import Note, NoteKind

# The prior's weight (x the floor's variance) where no link inertia is fitted or the held-out choice fails.
INERTIA_PRIOR_FALLBACK = 1e-3


# Where the held-out search of the prior's weight starts (a weight the ladder sets to the previous rung's choice:
# a rung that adds one effect rarely moves it by more than a decade); absent, the search starts on PRIOR_GRID.
PRIOR_START_SETTING = "inertia_prior_start"


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
            if kept is not None:  # the columns left out (a still joint's, a line's off its joints) at zero: the nominal value
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
    and a line's on the joints it is not kept on (:meth:`_Problem.without_still`) are left out: the program would leave a
    column it cannot see anywhere."""
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
            if problem.held_rows(effect).size:
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

