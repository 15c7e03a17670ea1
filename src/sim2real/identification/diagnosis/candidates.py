"""Diagnosis: which physical effect is the model missing?

On the holdout residual of the last rung, every effect of the library not yet in the model is tried: it is added to the
model, the model is refitted on the fit runs, and its holdout residual is compared with the current one (the trials run
in :mod:`~sim2real.identification.diagnosis.trials`; this module scores them, ranks them and concludes). Every residual
is taken in units of each joint's own noise floor (:func:`sim2real.identification.fitting.joint_weights`, the weights
of the fit too): a wrist residual 8x its floor weighs what a shoulder residual 8x its floor weighs, although its N*m
are ten times smaller. ``explained`` is the fraction of the current holdout residual energy (in those units) the
candidate removes (1 - SSE_after / SSE_now, clipped to 0..1); because it is measured on runs the fit never saw, an
effect that only soaks up noise explains nothing. ``explained_beyond_noise`` is the same removal as a share of the
residual energy above the noise floor, the part any model could remove: near the floor a real effect removes most of
that excess but only a small share of the whole residual, so the decision is taken on it.

Each candidate also carries its residual signature (:meth:`sim2real.identification.effects.base.Effect.evidence` on the
current holdout residual), the joints it acts on (those where it removes a good share of that joint's residual), its
fitted values and ``add``, the line to add to the model's model.yaml.

The diagnosis runs per side of the model (:mod:`sim2real.identification.sides`): ``candidates`` are the effects of that
side. It returns a :class:`~sim2real.identification.diagnosis.result.Diagnosis`, data the report words
(:mod:`sim2real.report.verdicts`). Candidates whose holdout predictions agree to within a tenth of the noise floor are
listed as ``confounded``: these data cannot tell them apart.

A verdict the user can trust says when it is not a clean decision:

* **ties** (``tied``): a decisive candidate named on the same joints as the best whose holdout residual is the best
  one's within the spread of their paired difference over blocks of the holdout
  (:func:`~sim2real.identification.diagnosis.caveats.tied`) is not told apart from it on these runs; the verdict says
  so, recommends the physically plausible, simpler one (or none: status ``not_told_apart``) and names the separating
  run the experiment design builds;
* **inertias**: each candidate is fitted with the link inertias it needs; the bodies it leaves beyond plausible are in
  its evidence, the ranking prefers, among those that do as well, one that keeps them plausible, and the verdict says
  when the named one does not;
* **trades with the model**: a candidate whose own term the fit gives back through the effects already in the model (a
  torque gain against the link inertias' scale) is said to trade places with them;
* **relabellings** (:func:`_relabellings`): a candidate whose own term the fit gives back through an effect already
  held, correlation near -1, is the model's term under another name: never decisive, and the verdict says so;
* **margins** (:mod:`~sim2real.identification.diagnosis.margins`): every threshold a decision reads is read with the
  arithmetic's margin against the decision; a figure within it names nothing, and the verdict says so;
* **failed trials** (``failed``): a candidate extends the current model, so its fit matches the fit runs at least as
  well; one that ends far worse there (:data:`~sim2real.identification.diagnosis.trials.FAILED_TRIAL_FACTOR`) is a
  solve that failed, not an effect that explains nothing: it is left out of the ranking and the verdict says so.

A candidate is decisive arm-wide (it removes ``min_explained`` of the excess above the floors), or on joints: a joint
above ``noise_floor_factor`` x its floor whose excess it mostly removes (``joint_decisive``) names it on that joint,
however small that joint's share of the arm. When no candidate is decisive, the verdict says so instead of forcing a
label: ``at_noise_floor`` when every joint is within ``noise_floor_factor`` of its own floor, ``unexplained``
otherwise, with each joint still above its floor and the candidate that comes closest there (``per_joint``). The
diagnosis never looks at the lab's truth.yaml: it sees only runs.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from sim2real.identification import fitting
from sim2real.identification.diagnosis.caveats import (bound_changes, caveat_notes, effect_term, implausible_bodies,
                                                       recommend, relabelling, ties, trades_with_model)
from sim2real.identification.diagnosis.current import CurrentResidual
from sim2real.identification.diagnosis.lags import other_shapes, shapes_note
from sim2real.identification.diagnosis.raises import (add_line, keep_off_raised, near_raises, raised_joints,
                                                      raises_note, withhold)
from sim2real.identification.diagnosis.ranking import _confounded, _rank  # noqa: F401  (the ranking's, used here)
from sim2real.identification.diagnosis.margins import (CONSERVATIVE, PERMISSIVE, above_floor, decide, joints_near_floor,
                                                       near_threshold_notes, near_thresholds)
from sim2real.identification.diagnosis.result import Candidate, CandidateEvidence, Diagnosis, JointStanding
from sim2real.identification.diagnosis.trials import _tried, failed_trial, replaced_by
from sim2real.identification.effects import EFFECTS
from sim2real.identification.effects.base import Signals, per_joint_dict
from sim2real.identification.records import Note, NoteKind, Side, Status

DEFAULT_DIAGNOSIS: dict[str, float] = {
    "min_explained": 0.3,  # a candidate must remove this share of the holdout residual beyond the noise floor
    "min_gain": 0.05,  # ... and this share of the whole holdout residual energy (a fall worth a rung)
    "joint_min_explained": 0.2,  # ... and this share of a joint's residual beyond noise to name that joint
    # A joint above noise_floor_factor x its floor: a candidate removing this share of its excess is named on it,
    # however small that joint's share of the arm-wide residual.
    "joint_decisive": 0.5,
    "noise_floor_factor": 1.5,  # every joint's residual RMS within this factor of its floor: nothing to add
    # Nested effects (a payload is a change of the last link's inertia): a candidate with fewer parameters
    # ranks first when its holdout residual is within this fraction of the noise floor of the best one's.
    "parsimony_noise_fraction": 0.1,
}


CONFOUNDED_NOISE_FRACTION = 0.1  # two candidates whose predictions differ by less: not told apart


# A per-joint fix may not push another joint further above its floor by more than this (x its floor).
HARM_TOLERANCE = 0.1


# A joint is named for an effect when the effect's own fitted term there is at least this (RMS, x its floor).
OWN_TERM_MIN = 0.5


def _own_term_x_floor(result: fitting.FitResult, name: str, nominal: Any, data: fitting.TorqueData,
                      signals: Signals, unit: np.ndarray) -> np.ndarray | None:
    """RMS per joint of what the effect ``name`` itself adds to the prediction, x each joint's floor
    (None for an effect without linear coefficients: a delay acts through the whole prediction)."""
    term = effect_term(result, name, nominal, data, signals)
    return None if term is None else np.sqrt(np.mean((term / unit) ** 2, axis=0))


def _sse(residual: np.ndarray) -> np.ndarray:
    return np.sum(residual**2, axis=0)


def _scores(residual: np.ndarray, now: CurrentResidual, broken: bool,
            limits: Mapping[str, float]) -> dict[str, Any]:
    """What a trial's holdout residual removes of the current one: arm-wide (``explained``, ``beyond``: of the excess
    above the floors) and per joint, and the joints it pushes further above their floor (``harmed``)."""
    scaled = residual / now.unit
    sse_after = _sse(scaled)
    gain = now.total - float(sse_after.sum()) if not broken else 0.0
    excess = now.excess
    with np.errstate(invalid="ignore", divide="ignore"):
        per_joint = np.clip(np.where(now.sse > 0, 1.0 - sse_after / now.sse, 0.0), 0.0, 1.0)
        per_joint_beyond = np.clip(np.where(excess > 0, (now.sse - sse_after) / excess, 0.0), 0.0, 1.0)
    if broken:  # a failed solve removes nothing and is named nowhere
        per_joint, per_joint_beyond = np.zeros_like(per_joint), np.zeros_like(per_joint_beyond)
    x_after = np.sqrt(sse_after / max(now.rows, 1))
    harmed = [bool(b > max(a, limits["noise_floor_factor"]) + HARM_TOLERANCE)
              for a, b in zip(now.x_floor, x_after, strict=True)]
    return {"scaled": scaled, "gain": gain,
            "explained": float(np.clip(gain / now.total, 0.0, 1.0)) if now.total > 0 else 0.0,
            "beyond": float(np.clip(gain / excess.sum(), 0.0, 1.0)) if excess.sum() > 0 else 0.0,
            "per_joint": per_joint, "per_joint_beyond": per_joint_beyond, "x_after": x_after, "harmed": harmed}


def _evidence(name: str, trial: tuple[fitting.FitResult, np.ndarray], scores: Mapping[str, Any],
              context: fitting.FitContext, now: CurrentResidual, current: fitting.FitResult | None,
              own: np.ndarray | None) -> CandidateEvidence:
    """A trial's evidence: the effect's residual signature, then what its fit removes and does."""
    result, residual = trial
    joints = list(context.holdout_data.joint_names)
    signature = EFFECTS[name].evidence(now.residual, context.holdout_signals)
    bounds = bound_changes(result, current)
    return CandidateEvidence(
        signature=signature.description, statistic=signature.statistic, per_joint=signature.per_joint,
        lag_s=signature.lag_s,
        per_joint_explained=per_joint_dict(joints, scores["per_joint"], 3),
        per_joint_explained_beyond_noise=per_joint_dict(joints, scores["per_joint_beyond"], 3),
        rmse_after=round(float(np.sqrt(np.mean(residual**2))), 6),
        x_floor_after=round(float(np.sqrt(np.mean(scores["x_after"] ** 2))), 4),
        per_joint_x_floor_after=per_joint_dict(joints, scores["x_after"], 3),
        harmed_joints=tuple(j for j, h in zip(joints, scores["harmed"], strict=True) if h),
        per_joint_own_term_x_floor=per_joint_dict(joints, own, 3) if own is not None else None,
        fitted=result.values[name],
        # Its own coefficients (the linear ones added to the nominal model, and the nonlinear ones): what a
        # design that separates two confounded candidates predicts each of them adds (sim2real.excitation).
        linear_coefficients=tuple(float(v) for v in result.theta.get(name, [])),
        nonlinear_coefficients=tuple(float(v) for v in result.nonlinear.get(name, [])),
        parameters=int(len(result.theta.get(name, [])) + len(result.nonlinear.get(name, []))),
        implausible_bodies=tuple(implausible_bodies(result, current)),
        bounds_pushed={k: tuple(v) for k, v in bounds["pushes"].items()},
        bounds_released={k: tuple(v) for k, v in bounds["releases"].items()})


def _candidate(name: str, trial: tuple[fitting.FitResult, np.ndarray], context: fitting.FitContext,
               now: CurrentResidual, current: fitting.FitResult | None, limits: Mapping[str, float],
               side: Side, model_effects: Sequence[str]) -> tuple[dict[str, Any], np.ndarray, dict[str, float] | None]:
    """One tried candidate (the ranking's dict), its holdout residual in floor units, and its fit-run figures when
    its trial failed to solve (:func:`failed_trial`)."""
    result, _ = trial
    joints = list(context.holdout_data.joint_names)
    broken = failed_trial(result, current, context.fit_data)
    scores = _scores(trial[1], now, broken is not None, limits)
    # Named on the joints where its own term shows, not where the residual fell because the rest of the
    # model no longer bends to soak it up (joint 7's friction frees the link inertias of joints 2 to 6).
    own = _own_term_x_floor(result, name, context.nominal, context.holdout_data, context.holdout_signals, now.unit)
    seen = [True] * len(joints) if own is None else [bool(o >= OWN_TERM_MIN) for o in own]
    # A joint above its floor whose excess the candidate mostly removes names it on that joint, however small that
    # joint's share of the arm; never at the price of the arm as a whole, nor of another joint (diagnosis.margins).
    # Each threshold read with the arithmetic's margin against the decision: a figure within it names nothing, the
    # evidence says so (near_threshold) and the verdict words it.
    decision = decide(scores, now.x_floor, own, joints, limits, OWN_TERM_MIN, CONSERVATIVE)
    arm_wide, on_joints = decision.arm_wide, list(decision.on_joints)
    acting = [j for j, v, ok in zip(joints, scores["per_joint_beyond"], seen, strict=True)
              if v >= limits["joint_min_explained"] and ok]
    decisive = decision.decisive
    evidence = _evidence(name, trial, scores, context, now, current, own)
    if broken is not None:
        evidence = replace(evidence, fit_failed=broken)
    elif decide(scores, now.x_floor, own, joints, limits, OWN_TERM_MIN, PERMISSIVE).decisive != decisive:
        evidence = replace(evidence, near_threshold=tuple(
            n.as_document() for n in near_thresholds(scores, now.x_floor, own, joints, limits, OWN_TERM_MIN)))
    found = {
        "effect": name,
        "link": EFFECTS[name].side if side == Side.COMBINED else side,  # a drive effect's follows the torque sensor
        "joints": (acting if arm_wide else on_joints) if decisive else [],
        "decided_on": "arm" if arm_wide else ("joints" if on_joints else None),
        "explained": round(scores["explained"], 4),
        "explained_beyond_noise": round(scores["beyond"], 4),
        "decisive": decisive,
        "evidence": evidence,
        "add": add_line(name),
        **({"replaces": replaced_by(name, model_effects)} if replaced_by(name, model_effects) else {}),
    }
    raised = raised_joints(scores, now, joints, limits) if decisive and broken is None else {}
    if raised:  # no recommended rung raises a joint beyond the noise (diagnosis.raises)
        withhold(found, raised, near_raises(scores, now, joints, limits, raised))
    return found, scores["scaled"], broken


def _scored(tried: Sequence[str], trials: dict[str, tuple[fitting.FitResult, np.ndarray]],
            model_effects: Sequence[str], context: fitting.FitContext, now: CurrentResidual,
            current: fitting.FitResult | None, limits: Mapping[str, float], side: Side,
            ) -> tuple[list[dict[str, Any]], dict[str, np.ndarray], dict[str, dict[str, float]]]:
    """Each tried candidate scored (:func:`_candidate`), one that raises a joint tried again on the joints it helps or
    withheld (:func:`~sim2real.identification.diagnosis.raises.keep_off_raised`, which may replace its trial in
    ``trials``); (candidates, holdout residuals in floor units of those that solved, failed trials' figures)."""
    scored, residuals, failed = [], {}, {}
    for name in tried:
        candidate, scaled, broken = _candidate(name, trials[name], context, now, current, limits, side, model_effects)
        scored.append(candidate)
        if broken is None:
            residuals[name] = scaled
        else:
            failed[name] = broken
    keep_off_raised(scored, residuals, trials, model_effects, context, current, limits,
                    lambda name, trial, narrowed: _candidate(name, trial, narrowed, now, current, limits, side,
                                                             model_effects))
    return scored, residuals, failed


def _per_joint_status(joints: Sequence[str], now: CurrentResidual,
                      candidates: Sequence[Mapping[str, Any]]) -> dict[str, JointStanding]:
    """Each joint's residual x its floor and the candidate that removes most of its excess there."""
    out = {}
    for j, x in zip(joints, now.x_floor, strict=True):
        closest = max(candidates, key=lambda c: c["evidence"].per_joint_explained_beyond_noise[j], default=None)
        if closest is not None and closest["evidence"].per_joint_explained_beyond_noise[j] <= 0:
            closest = None  # nothing removes any of it
        out[j] = JointStanding(
            x_floor=round(float(x), 3), closest=closest["effect"] if closest else None,
            closest_explained_beyond_noise=closest["evidence"].per_joint_explained_beyond_noise[j] if closest else 0.0,
            closest_x_floor_after=closest["evidence"].per_joint_x_floor_after[j] if closest else round(float(x), 3))
    return out


def _named_notes(best: Mapping[str, Any], candidates: Sequence[Mapping[str, Any]], group: Sequence[Mapping[str, Any]],
                 confounded: Sequence[tuple[str, str]], residuals: Mapping[str, np.ndarray],
                 limits: Mapping[str, float]) -> list[Note]:
    """The notes of a verdict that names ``best``: its lag's other shapes, the candidates it predicts the same as
    (beyond those tied with it), the ties and its caution."""
    twins = [b for a, b in confounded if a == best["effect"]] + [a for a, b in confounded if b == best["effect"]]
    twins = [t for t in twins if t not in {c["effect"] for c in group}]  # the ties' note names those
    shapes = shapes_note(best, other_shapes(best, candidates, residuals, limits, CONFOUNDED_NOISE_FRACTION))
    notes = [shapes] if shapes is not None else []
    if twins:
        notes.append(Note(NoteKind.CONFOUNDED, effect=best["effect"],
                          figures={"twins": twins, "within": CONFOUNDED_NOISE_FRACTION}))
    return notes + caveat_notes(best, group)


def _relabellings(candidates: Sequence[dict[str, Any]], failed: Mapping[str, Any],
                  trials: Mapping[str, tuple[fitting.FitResult, np.ndarray]], current: fitting.FitResult | None,
                  context: fitting.FitContext, now: CurrentResidual,
                  ) -> tuple[dict[str, list[dict[str, Any]]], dict[str, list[dict[str, Any]]]]:
    """The decisive candidates whose own term is the model's relabelled (:func:`~sim2real.identification.diagnosis.
    caveats.relabelling`), each with its trades: they are made not decisive (named nowhere, whatever they seem to
    remove: the fall is the model's own term under another name) and their trades kept in their evidence. Also every
    decisive candidate's trades (:func:`trades_with_model`), for the caveats of the one named."""
    out, trades_of = {}, {}
    for c in candidates:
        if current is None or not c["decisive"] or c["effect"] in failed:
            continue
        trades_of[c["effect"]] = trades_with_model(trials[c["effect"]][0], current, c["effect"], context.nominal,
                                                   context.holdout_data, context.holdout_signals, now.unit)
        if demote_relabelling(c, trades_of[c["effect"]]):
            out[c["effect"]] = list(c["evidence"].relabels)
    return out, trades_of


def demote_relabelling(candidate: dict[str, Any], trades: Sequence[Mapping[str, Any]]) -> bool:
    """Make ``candidate`` not decisive when its ``trades`` with the model (:func:`~sim2real.identification.diagnosis.
    caveats.trades_with_model`) make it a relabelling (:func:`~sim2real.identification.diagnosis.caveats.relabelling`),
    keeping them in its evidence (``relabels``); whether it did."""
    relabels = relabelling(trades)
    if relabels:
        candidate["evidence"] = replace(candidate["evidence"], relabels=tuple(relabels))
        candidate.update({"decisive": False, "decided_on": None, "joints": []})
    return bool(relabels)


def _status(best: Mapping[str, Any] | None, recommended: Mapping[str, Any] | None, above: Sequence[str]) -> Status:
    if best is not None and best["decisive"]:
        return Status.ADD_EFFECT if recommended is not None else Status.NOT_TOLD_APART
    return Status.UNEXPLAINED if above else Status.AT_NOISE_FLOOR


def diagnose(model_effects: Sequence[str], context: fitting.FitContext, holdout_residual: np.ndarray, *,
             side: Side = Side.BODY, current: fitting.FitResult | None = None, limits: Mapping[str, float] | None = None,
             candidates: Sequence[str] | None = None) -> Diagnosis:
    """Rank every effect of ``candidates`` (default: the library) not in ``model_effects`` by the holdout residual it
    removes, on ``side`` (:class:`~sim2real.identification.records.Side`).

    ``context``: the side's fit context (nominal model, data and signals by role, fit settings, workers, where
    refinements are kept); the residual is the current model's holdout residual (judged minus predicted torque);
    ``current``: the current rung's fit, whose nonlinear parameters each trial holds or refines again and against which
    a candidate that trades places with an effect already in the model is found (:func:`trades_with_model`); ``limits``:
    :data:`DEFAULT_DIAGNOSIS`'s, as model.yaml's ``diagnosis`` sets them. Each candidate is fitted exactly as its rung
    would be (:func:`sim2real.identification.fitting.fit`, physically consistent), so ``rmse_after`` is the holdout
    error the ladder delivers when the user adds it.

    Parameters
    ----------
    model_effects, context, holdout_residual
        The current model's effects, the side's :class:`FitContext`, its holdout residual (samples x joints).
    side, current, limits, candidates : optional

    Returns
    -------
    Diagnosis
        ``status``, the ranked ``candidates`` with their evidence, ``notes``: data :mod:`sim2real.report` words.

    Examples
    --------
    >>> from sim2real.identification import fitting
    >>> from sim2real.measurements import noise_floor_of, prepare_for_model
    >>> runs = prepare_for_model(example_dir / "measurements.yaml", urdf, root=example_dir)
    >>> nominal = fitting.load_nominal(urdf, runs[0].joint_names)
    >>> samples = [[fitting.RunSamples.of(run, noise_floor_of(run)) for run in rs] for rs in (runs.fit, runs.holdout)]
    >>> fit, holdout = [fitting.stack_runs(of_role, nominal.joint_names) for of_role in samples]
    >>> context = fitting.FitContext.on_nominal(nominal, fit, holdout, fitting.DEFAULT_SETTINGS)  # the nominal rung
    >>> diagnosis = diagnose([], context, holdout.tau - context.holdout_signals.tau_nominal,
    ...                      candidates=["viscous_friction", "coulomb_friction"])
    >>> diagnosis.status.value, diagnosis.candidates[0].effect
    ('add_effect', 'viscous_friction')
    """
    limits = {**DEFAULT_DIAGNOSIS, **(limits or {})}
    joints = list(context.holdout_data.joint_names)
    now = CurrentResidual.of(holdout_residual, context.holdout_data.noise_floor)
    above = above_floor(joints, now.x_floor, limits["noise_floor_factor"])  # clearly above: by more than the margin
    trials, tried, skipped = _tried(model_effects, context, now, current, limits, candidates)
    tried_candidates, residuals_after, failed = _scored(tried, trials, model_effects, context, now, current, limits,
                                                        side)
    relabelled, trades_of = _relabellings(tried_candidates, failed, trials, current, context, now)
    ranked = _rank([c for c in tried_candidates if c["effect"] not in failed], float(limits["parsimony_noise_fraction"]))
    ranked += [c for c in tried_candidates if c["effect"] in failed]  # last, whatever they would have scored
    confounded = _confounded(ranked, residuals_after, CONFOUNDED_NOISE_FRACTION, float(limits["min_gain"]))
    tied_with_best = ties(ranked, residuals_after, now.rows)
    group = [ranked[0], *tied_with_best] if tied_with_best else []  # the best and those it is not told apart from
    if current is not None:
        for c in (group or ranked[:1]) if ranked and ranked[0]["decisive"] else []:
            # every decisive candidate's, found above
            c["evidence"] = replace(c["evidence"], trades_with=tuple(trades_of[c["effect"]]))
    ranked, recommended = recommend(ranked, tied_with_best)
    best = ranked[0] if ranked else None
    status = _status(best, recommended, above)
    notes = _named_notes(best, ranked, group, confounded, residuals_after, limits) \
        if status == Status.ADD_EFFECT and best is not None else []
    if failed:
        notes.append(Note(NoteKind.FAILED_TRIALS, figures={"failed": {k: failed[k] for k in sorted(failed)}}))
    if relabelled:
        notes.append(Note(NoteKind.RELABELLED, figures={"relabelled": relabelled}))
    notes += [n for n in [raises_note(ranked)] if n is not None]
    notes += near_threshold_notes(ranked, group, joints_near_floor(joints, now.x_floor, limits["noise_floor_factor"]))
    return Diagnosis(
        side=side, status=status, candidates=tuple(_typed(c) for c in ranked), confounded=tuple(confounded),
        tied=tuple(c["effect"] for c in group), residual_rmse=round(now.rmse, 6),
        noise_floor_ratio=round(now.ratio, 4) if np.isfinite(now.ratio) else None, noise_rmse=now.noise,
        noise_floor_factor=limits["noise_floor_factor"], min_explained=limits["min_explained"],
        per_joint=_per_joint_status(joints, now, ranked), above_floor=tuple(above), skipped=tuple(skipped),
        failed=tuple(sorted(failed)), notes=tuple(notes), joints=tuple(joints))


def _typed(candidate: Mapping[str, Any]) -> Candidate:
    return Candidate(effect=candidate["effect"], side=Side(candidate["link"]), joints=tuple(candidate["joints"]),
                     decided_on=candidate["decided_on"], explained=candidate["explained"],
                     explained_beyond_noise=candidate["explained_beyond_noise"], decisive=candidate["decisive"],
                     evidence=candidate["evidence"], add=candidate["add"], replaces=tuple(candidate.get("replaces") or ()),
                     kept_to=tuple(candidate.get("kept_to") or ()))
