"""Diagnosis: which physical effect is the model missing?

On the holdout residual of the last rung, every effect of the library not yet in the model is
tried: it is added to the model, the model is refitted on the fit runs, and its holdout residual
is compared with the current one. Every residual is taken in units of each joint's own noise floor
(:func:`sim2real.identification.fitting.joint_weights`, the weights of the fit too): a wrist residual 8x its floor
weighs what a shoulder residual 8x its floor weighs, although its N*m are ten times smaller.
``explained`` is the fraction of the current holdout residual energy (in those units) the candidate
removes (1 - SSE_after / SSE_now, clipped to 0..1); because it is measured on runs the fit never
saw, an effect that only soaks up noise explains nothing.
``explained_beyond_noise`` is the same removal as a share of the residual energy above the noise
floor, the part any model could remove: near the floor a real effect removes most of that excess
but only a small share of the whole residual, so the decision is taken on it.

Each candidate also carries its residual signature (:meth:`sim2real.identification.effects.base.Effect.evidence`
on the current holdout residual), the joints it acts on (those where it removes a good share of
that joint's residual), its fitted values and ``add``, the line to add to configs/{robot}/model.yaml.

The diagnosis runs per link of the model (:mod:`sim2real.identification.links`): ``candidates`` are the effects
of that link, and the verdict names the link. Candidates whose holdout predictions agree to within a
tenth of the noise floor are listed as ``confounded``: these data cannot tell them apart.

A verdict the user can trust says when it is not a clean decision:

* **ties** (``tied``): a decisive candidate named on the same joints as the best whose holdout residual is
  the best one's within the spread of their paired difference over blocks of the holdout (:func:`tied`) is
  not told apart from it on these runs; the verdict says so, recommends the physically plausible, simpler one
  (or none: status ``not_told_apart``) and names the separating run the experiment design builds;
* **inertias**: each candidate is fitted with the link inertias it needs; the bodies it leaves beyond
  plausible are in its evidence, the ranking prefers, among those that do as well, one that keeps them
  plausible, and the verdict says when the named one does not;
* **trades with the model**: a candidate whose own term the fit gives back through the effects already in
  the model (a torque gain against the link inertias' scale) is said to trade places with them;
* **failed trials** (``failed``): a candidate extends the current model, so its fit matches the fit runs at
  least as well; one that ends far worse there (:data:`FAILED_TRIAL_FACTOR`) is a solve that failed, not an
  effect that explains nothing: it is left out of the ranking and the verdict says so.

A candidate is decisive arm-wide (it removes ``min_explained`` of the excess above the floors), or
on joints: a joint above ``noise_floor_factor`` x its floor whose excess it mostly removes
(``joint_decisive``) names it on that joint, however small that joint's share of the arm.
When no candidate is decisive, the verdict says so instead of forcing a label: ``at_noise_floor``
when every joint is within ``noise_floor_factor`` of its own floor, ``unexplained`` otherwise, with
each joint still above its floor and the candidate that comes closest there (``per_joint``). The diagnosis never looks at the lab's truth.yaml: it sees only runs.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.identification import fitting
from sim2real.identification.effects import EFFECTS
from sim2real.identification.effects.base import Signals, per_joint_dict
from sim2real.stats import floor_multiple
from sim2real.identification.diagnosis.caveats import (
    NESTED_IN, SPANNED_BY, bound_changes, caveats, implausible_bodies, not_told_apart_verdict, recommend, separating_runs, ties,
    trades_with_model,
)
from sim2real.forked import map_forked
from sim2real.identification.diagnosis.screens import screen_ripples
from sim2real.identification.diagnosis.lags import (after_other_shape, other_shapes, same_lag, screen_lags,
                                                     shapes_sentence)
from sim2real.identification.inertial import import_solver

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


# How each link is named in verdicts (sim2real.identification.links.LINK_MODES says which links a data set has).
LINK_TEXT: dict[str, str] = {
    "body": "the body link (measured torque against the motion)",
    "actuator": "the actuator link (measured against commanded torque)",
    "combined": "the commanded torque against the motion (actuator and body together: no torque sensor)",
}


CONFOUNDED_NOISE_FRACTION = 0.1  # two candidates whose predictions differ by less: not told apart


# A per-joint fix may not push another joint further above its floor by more than this (x its floor).
HARM_TOLERANCE = 0.1


# A joint is named for an effect when the effect's own fitted term there is at least this (RMS, x its floor).
OWN_TERM_MIN = 0.5


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


def _own_term_x_floor(result: fitting.FitResult, name: str, nominal: Any, data: fitting.TorqueData,
                      signals: Signals, unit: np.ndarray) -> np.ndarray | None:
    """RMS per joint of what the effect ``name`` itself adds to the prediction, x each joint's floor
    (None for an effect without linear coefficients: a delay acts through the whole prediction)."""
    import dataclasses

    coefficients = np.asarray(result.theta.get(name, []), dtype=float)
    if not coefficients.size:
        return None
    without = dataclasses.replace(result, theta={**result.theta, name: np.zeros_like(coefficients)})
    term = fitting.predict(result, nominal, data, signals) - fitting.predict(without, nominal, data, signals)
    return np.sqrt(np.mean((term / unit) ** 2, axis=0))


def add_line(effect: str) -> str:
    """The exact line to add under ``effects:`` in configs/{robot}/model.yaml."""
    return f"- {effect}"


def replaced_by(name: str, model_effects: Sequence[str]) -> list[str]:
    """The effects of the model whose columns lie in the span of the candidate ``name``'s (:data:`SPANNED_BY`: a
    payload in the link inertias'). Its trial drops them and the verdict says to remove their lines: both in one model
    put the same torque in two sets of columns, a fit that only the inertial prior keeps from singular, and one that
    goes wrong where the prior is weak."""
    return [held for held in model_effects if held in SPANNED_BY.get(name, ())]


def removal_text(candidate: Mapping[str, Any]) -> str:
    """The verdict's words after its line to add, for a candidate that replaces lines of the model (empty otherwise)."""
    replaced = candidate.get("replaces") or []
    if not replaced:
        return ""
    lines = " and ".join(f"'{add_line(r)}'" for r in replaced)
    return (f" and remove {lines}: {candidate['effect']} holds {', '.join(replaced)} (a special case of it), and both in "
            "one model fit the same torque twice")


def trial_effects(model_effects: Sequence[str], name: str) -> list[str]:
    """The model a trial of ``name`` fits, as the user's model.yaml will list it: the candidate's line added at the end,
    the lines it holds removed (:func:`replaced_by`)."""
    replaced = replaced_by(name, model_effects)
    return [e for e in model_effects if e not in replaced] + [name]


def _sse(residual: np.ndarray) -> np.ndarray:
    return np.sum(residual**2, axis=0)


def _rank(candidates: list[dict[str, Any]], tolerance: float) -> list[dict[str, Any]]:
    """Decisive candidates first, each group by explained share; then the simplest candidate that does as
    well as the best goes first.

    Effects nest (a payload is a change of the last link's inertia; link_inertia holds it): the
    bigger one always explains a little more, the smaller one is the better name for what is missing.
    "As well" is judged in units of the noise floor: within ``tolerance`` of the best holdout residual
    (each joint in units of its own floor), a difference no excitation of this length can tell from noise.
    """
    ranked = sorted(candidates, key=lambda c: (not c["decisive"], -c["explained"], c["effect"]))
    if not ranked:
        return ranked
    best = ranked[0]
    if not best["decisive"]:
        return ranked  # nothing is named: the order is only what comes closest
    limit = best["evidence"]["x_floor_after"] + tolerance
    close = [c for c in ranked if c["decisive"] == best["decisive"] and c["evidence"]["x_floor_after"] <= limit]
    # Among those that do as well, one that keeps every inertia plausible first, then one that pushes fewer bounds,
    # then the simplest: of two shapes of
    # one lag, the delay (a filter gives the simulation a state of its own).
    simplest = min(close, key=lambda c: (bool(c["evidence"]["implausible_bodies"]), _bounds_pushed(c),
                                         c["evidence"]["parameters"],
                                         EFFECTS[c["effect"]].lowpass, -c["explained"], c["effect"]))
    return [simplest] + [c for c in ranked if c is not simplest]


def _bounds_pushed(candidate: Mapping[str, Any]) -> int:
    """How many bounds a candidate's fit pushes the link inertias to, less those it releases (:func:`bound_changes`):
    of two that do as well, the one that leaves the links freer names what acted like mass."""
    bounds = candidate["evidence"].get("bounds") or {}
    return (sum(len(v) for v in (bounds.get("pushes") or {}).values())
            - sum(len(v) for v in (bounds.get("releases") or {}).values()))


def _confounded(
    candidates: Sequence[Mapping[str, Any]], residuals: Mapping[str, np.ndarray], tolerance: float, min_gain: float
) -> list[tuple[str, str]]:
    """Pairs of candidates that each remove at least ``min_gain`` of the residual and predict the same
    holdout torque to within ``tolerance`` (RMS in floor units): on these data one is the other (ranked order).
    ``residuals`` are already in floor units."""
    useful = [c["effect"] for c in candidates if c["explained"] >= min_gain]
    pairs = []
    for i, a in enumerate(useful):
        for b in useful[i + 1 :]:
            if same_lag(a, b):
                continue  # two shapes of one lag: no run separates them (the verdict's shape sentence says so)
            if float(np.sqrt(np.mean((residuals[a] - residuals[b]) ** 2))) <= tolerance:
                pairs.append((a, b))
    return pairs


def _joint_text(joints: Sequence[str], before: Mapping[str, float], after: Mapping[str, float]) -> str:
    return ", ".join(f"{j} {floor_multiple(before[j])} -> {floor_multiple(after[j])}" for j in joints)


def candidates_to_try(model_effects: Sequence[str], torque_source: str, forward: bool,
                      candidates: Sequence[str] | None = None) -> tuple[list[str], list[dict[str, str]]]:
    """The effects of ``candidates`` (default: the library) :func:`diagnose` fits on top of ``model_effects``, and
    those it does not, each with why; ``torque_source`` is the judged torque's, ``forward`` the signals' (the
    actuator link predicts the measured torque from the command)."""
    tried: list[str] = []
    skipped: list[dict[str, str]] = []
    for name in candidates if candidates is not None else EFFECTS:
        effect = EFFECTS[name]
        if name in model_effects:
            continue
        if effect.per_run:
            skipped.append({"effect": name, "reason": "estimated on every run itself, the holdout runs included, so no "
                            "held-out run can judge it: the model-free ceiling says when each run's offsets call for "
                            "it, and the user declares it"})
            continue
        holder = next((held for held in model_effects if name in NESTED_IN.get(held, ())), None)
        if holder is not None:
            skipped.append({"effect": name, "reason": f"{holder} in the model already holds it (a special case of it)"})
            continue
        if effect.needs_commands and torque_source != "tau_cmd" and not forward:
            skipped.append({
                "effect": name,
                "reason": "an effect of the actuator link (command -> applied torque), and the torque judged here "
                "is measured by a sensor (tau) after it; runs that also log tau_cmd judge it on the actuator link",
            })
            continue
        if effect.sensor_side and (torque_source == "tau_cmd" or forward):
            skipped.append({
                "effect": name,
                "reason": "an error of the torque sensor, and these runs judge the commanded torque (tau_cmd): "
                "on commands the same column is the actuator's (actuator_gain, command_bias)",
            })
            continue
        tried.append(name)
    return tried, skipped


def _trial_way(item: tuple[str, Mapping[str, Any]], model_effects: Sequence[str], **inputs: Any,
               ) -> tuple[fitting.FitResult, np.ndarray] | None:
    """One way (:func:`sim2real.identification.fitting.previous_ways`) of fitting the candidate ``item[0]`` on the current model,
    and its holdout residual (:func:`sim2real.identification.fitting.rung._fit_way`)."""
    name, way = item
    replaced = replaced_by(name, model_effects)
    # the held or starting nonlinear parameters of the lines the candidate replaces have no place in its model
    way = {key: ({e: v for e, v in value.items() if e not in replaced} if isinstance(value, Mapping) else value)
           for key, value in way.items()}
    return fitting.fit_way(way, effect_names=trial_effects(model_effects, name), **inputs)


def trial_fits(names: Sequence[str], workers: int, *, model_effects: Sequence[str], nominal: Any, fit_data: Any,
               holdout_data: Any, nonlinear_fixed: Mapping[str, np.ndarray] | None, settings: Mapping[str, Any] | None,
               fit_signals: Signals, holdout_signals: Signals, refinements: fitting.Refinements | None = None,
               ) -> dict[str, tuple[fitting.FitResult, np.ndarray]]:
    """Each candidate of ``names`` fitted as its rung will be: the current nonlinear parameters refined again or
    held, whichever predicts better (:func:`sim2real.identification.fitting.fit_on_the_previous`); (fit, holdout residual).

    Every way of every candidate is one piece of work, on up to ``workers`` processes side by side
    (:func:`sim2real.forked.map_forked`: the same numbers as one after the other). The candidates' first ways
    go first (they refine, and take longest).
    """
    previous = fitting.previous_nonlinear(nonlinear_fixed)
    ways = fitting.previous_ways(previous, uncertainty=False)
    items = [(name, way) for way in ways for name in names]
    if workers > 1 and len(items) > 1:
        import_solver()
    fits = map_forked(_trial_way, items, workers, {"model_effects": list(model_effects), "nominal": nominal,
                                                    "data": fit_data, "settings": settings, "signals": fit_signals,
                                                    "holdout_data": holdout_data, "holdout_signals": holdout_signals,
                                                    "refinements": refinements})
    out = {}
    for name in names:
        candidate = [fit for (item_name, _), fit in zip(items, fits, strict=True) if item_name == name]
        result, residual, _ = fitting.better_way(
            candidate, trial_effects(model_effects, name), nominal, fit_data, holdout_data,
            {e: v for e, v in previous.items() if e not in replaced_by(name, model_effects)}, settings,
            fit_signals=fit_signals, holdout_signals=holdout_signals, uncertainty=False)
        out[name] = (result, residual)
    return out


def diagnose(
    model_effects: Sequence[str],
    nominal: Any,
    fit_data: Any,
    holdout_data: Any,
    holdout_residual: np.ndarray,
    settings: Mapping[str, Any] | None = None,
    fit_signals: Signals | None = None,
    holdout_signals: Signals | None = None,
    robot: str = "{robot}",
    nonlinear_fixed: Mapping[str, np.ndarray] | None = None,
    candidates: Sequence[str] | None = None,
    link: str = "body",
    workers: int = 1,
    current: fitting.FitResult | None = None,
    refinements: fitting.Refinements | None = None,
) -> dict[str, Any]:
    """Rank every effect of ``candidates`` (default: the library) not in ``model_effects`` by the
    holdout residual it removes; ``link`` names the link of the model judged (:data:`LINK_TEXT`);
    ``current``: the current rung's fit, against which a candidate that trades places with an effect already
    in the model is found (:func:`trades_with_model`).

    ``nominal``, ``fit_data``, ``holdout_data`` are :mod:`sim2real.identification.fitting` objects; the residual is the
    current model's holdout residual (judged minus predicted torque). Each candidate is fitted exactly
    as its rung would be (:func:`sim2real.identification.fitting.fit`, physically consistent, the current model's
    nonlinear parameters ``nonlinear_fixed`` held), so ``rmse_after`` is the holdout error the ladder
    delivers when the user adds it. ``workers``: processes that fit the candidates side by side (:func:`trial_fits`);
    ``refinements``: where their refinements are kept, for the rung of the one the user adds.
    """
    settings = dict(settings or {})
    limits = {**DEFAULT_DIAGNOSIS, **settings.get("diagnosis", {})}
    fit_signals = fit_signals or fitting.make_signals(nominal, fit_data)
    holdout_signals = holdout_signals or fitting.make_signals(nominal, holdout_data)
    joints = list(holdout_data.joint_names)
    floor = np.asarray(holdout_data.noise_floor, dtype=float)
    noise = float(np.sqrt(np.mean(floor**2)))
    # Every decision is taken in units of each joint's own noise floor (fitting.joint_weights): a wrist
    # residual 8x its floor weighs what a shoulder residual 8x its floor weighs, whatever their N*m.
    unit = noise / fitting.joint_weights(floor) if noise > 0 else np.ones(len(joints))
    scaled_now = holdout_residual / unit
    rows = holdout_residual.shape[0]
    sse_now = _sse(scaled_now)
    total_now = float(sse_now.sum())
    rmse_now = float(np.sqrt(np.mean(holdout_residual**2)))
    x_now = np.sqrt(sse_now / max(rows, 1))  # per joint, x its floor
    ratio = float(np.sqrt(np.mean(x_now**2)))
    excess_now = np.clip(sse_now - rows, 0.0, None)  # per joint, above white noise at the floor
    above = [j for j, x in zip(joints, x_now, strict=True) if x > limits["noise_floor_factor"]]
    ranked_candidates = []
    residuals_after: dict[str, np.ndarray] = {}
    tried, skipped = candidates_to_try(model_effects, holdout_data.torque_source, holdout_signals.forward, candidates)
    # A lag is fitted only where it could matter (diagnosis.lags): screened, or waiting for its other shape's trial.
    waiting = screen_lags(tried, skipped, current, nominal, holdout_data, holdout_signals, holdout_residual, unit,
                          excess_now, x_now, limits)
    # A ripple is fitted only where some joint's residual repeats with its position (diagnosis.screens).
    screen_ripples(tried, skipped, current, nominal, fit_data, fit_signals, holdout_data, holdout_residual, unit,
                   excess_now, x_now, limits)
    trial_inputs = {"model_effects": list(model_effects), "nominal": nominal, "fit_data": fit_data,
                    "holdout_data": holdout_data, "nonlinear_fixed": nonlinear_fixed, "settings": settings.get("fit"),
                    "fit_signals": fit_signals, "holdout_signals": holdout_signals, "refinements": refinements}
    trials = trial_fits(tried, workers, **trial_inputs)
    second = after_other_shape(waiting, trials, skipped, unit, sse_now, excess_now, x_now, limits)
    if second:
        trials.update(trial_fits(second, workers, **trial_inputs))
        tried += second
    failed: dict[str, dict[str, float]] = {}
    for name in tried:
        effect = EFFECTS[name]
        result, residual = trials[name]
        broken = failed_trial(result, current, fit_data)
        if broken is not None:
            failed[name] = broken
        scaled = residual / unit
        sse_after = _sse(scaled)
        gain = total_now - float(sse_after.sum()) if broken is None else 0.0
        explained = float(np.clip(gain / total_now, 0.0, 1.0)) if total_now > 0 else 0.0
        beyond = float(np.clip(gain / excess_now.sum(), 0.0, 1.0)) if excess_now.sum() > 0 else 0.0
        with np.errstate(invalid="ignore", divide="ignore"):
            per_joint = np.clip(np.where(sse_now > 0, 1.0 - sse_after / sse_now, 0.0), 0.0, 1.0)
            per_joint_beyond = np.clip(np.where(excess_now > 0, (sse_now - sse_after) / excess_now, 0.0), 0.0, 1.0)
        if broken is not None:  # a failed solve removes nothing and is named nowhere
            per_joint, per_joint_beyond = np.zeros_like(per_joint), np.zeros_like(per_joint_beyond)
        x_after = np.sqrt(sse_after / max(rows, 1))
        arm_wide = beyond >= limits["min_explained"] and explained >= limits["min_gain"]
        # A joint above its floor whose excess the candidate mostly removes names it on that joint, however
        # small that joint's share of the arm; never at the price of the arm as a whole (gain > 0).
        # Nor at the price of another joint: one pushed further above its floor is no joint's fix.
        harmed = [j for j, a, b in zip(joints, x_now, x_after, strict=True)
                  if b > max(a, limits["noise_floor_factor"]) + HARM_TOLERANCE]
        on_joints = [j for j, x, v in zip(joints, x_now, per_joint_beyond, strict=True)
                     if x > limits["noise_floor_factor"] and v >= limits["joint_decisive"]] if gain > 0 and not harmed else []
        # Named on the joints where its own term shows, not where the residual fell because the rest of the
        # model no longer bends to soak it up (joint 7's friction frees the link inertias of joints 2 to 6).
        own = _own_term_x_floor(result, name, nominal, holdout_data, holdout_signals, unit)
        seen = [True] * len(joints) if own is None else [bool(o >= OWN_TERM_MIN) for o in own]
        on_joints = [j for j in on_joints if seen[joints.index(j)]]
        acting = [j for j, v, ok in zip(joints, per_joint_beyond, seen, strict=True)
                  if v >= limits["joint_min_explained"] and ok]
        decisive = arm_wide or bool(on_joints)
        evidence = effect.evidence(holdout_residual, holdout_signals)
        evidence["per_joint_explained"] = per_joint_dict(joints, per_joint, 3)
        evidence["per_joint_explained_beyond_noise"] = per_joint_dict(joints, per_joint_beyond, 3)
        evidence["rmse_after"] = round(float(np.sqrt(np.mean(residual**2))), 6)
        evidence["x_floor_after"] = round(float(np.sqrt(np.mean(x_after**2))), 4)
        evidence["per_joint_x_floor_after"] = per_joint_dict(joints, x_after, 3)
        evidence["harmed_joints"] = harmed
        if own is not None:
            evidence["per_joint_own_term_x_floor"] = per_joint_dict(joints, own, 3)
        evidence["fitted"] = result.values[name]
        # Its own coefficients (the linear ones added to the nominal model, and the nonlinear ones): what a
        # design that separates two confounded candidates predicts each of them adds (sim2real.excitation).
        evidence["coefficients"] = {"linear": [float(v) for v in result.theta.get(name, [])],
                                    "nonlinear": [float(v) for v in result.nonlinear.get(name, [])]}
        evidence["parameters"] = int(len(result.theta.get(name, [])) + len(result.nonlinear.get(name, [])))
        evidence["implausible_bodies"] = implausible_bodies(result, current)
        evidence["bounds"] = bound_changes(result, current)
        if broken is None:
            residuals_after[name] = scaled
        else:
            evidence["fit_failed"] = broken
        ranked_candidates.append({
            "effect": name,
            "link": effect.link if link == "combined" else link,  # a drive effect's follows the torque sensor
            "joints": (acting if arm_wide else on_joints) if decisive else [],
            "decided_on": "arm" if arm_wide else ("joints" if on_joints else None),
            "explained": round(explained, 4),
            "explained_beyond_noise": round(beyond, 4),
            "decisive": decisive,
            "evidence": evidence,
            "add": add_line(name),
            **({"replaces": replaced_by(name, model_effects)} if replaced_by(name, model_effects) else {}),
        })
    solved = [c for c in ranked_candidates if c["effect"] not in failed]
    candidates = _rank(solved, float(limits["parsimony_noise_fraction"]))
    candidates += [c for c in ranked_candidates if c["effect"] in failed]  # last, whatever they would have scored
    confounded = _confounded(candidates, residuals_after, CONFOUNDED_NOISE_FRACTION, float(limits["min_gain"]))
    tied_with_best = ties(candidates, residuals_after, rows)
    group = [candidates[0], *tied_with_best] if tied_with_best else []  # the best and those it is not told apart from
    if current is not None:
        for c in (group or candidates[:1]) if candidates and candidates[0]["decisive"] else []:
            c["evidence"]["trades_with"] = trades_with_model(trials[c["effect"]][0], current, c["effect"], nominal,
                                                             holdout_data, holdout_signals, unit)
    candidates, recommended = recommend(candidates, tied_with_best)
    best = candidates[0] if candidates else None
    where = LINK_TEXT.get(link, link)
    x_now_map = per_joint_dict(joints, x_now, 3)
    per_joint_status = {}
    for j, x in zip(joints, x_now, strict=True):
        closest = max(candidates, key=lambda c: c["evidence"]["per_joint_explained_beyond_noise"][j], default=None)
        if closest is not None and closest["evidence"]["per_joint_explained_beyond_noise"][j] <= 0:
            closest = None  # nothing removes any of it
        per_joint_status[j] = {
            "x_floor": round(float(x), 3),
            "closest": closest["effect"] if closest else None,
            "closest_explained_beyond_noise": closest["evidence"]["per_joint_explained_beyond_noise"][j] if closest else 0.0,
            "closest_x_floor_after": closest["evidence"]["per_joint_x_floor_after"][j] if closest else round(float(x), 3),
        }
    if best is not None and best["decisive"] and recommended is None:
        status = "not_told_apart"
        verdict = not_told_apart_verdict(group, where, robot)
    elif best is not None and best["decisive"]:
        status = "add_effect"
        after = best["evidence"]["per_joint_x_floor_after"]
        twins = [b for a, b in confounded if a == best["effect"]] + [a for a, b in confounded if b == best["effect"]]
        twins = [t for t in twins if t not in {c["effect"] for c in group}]  # the ties' sentence names those
        shape_text = shapes_sentence(best, other_shapes(best, candidates, residuals_after, limits,
                                                                   CONFOUNDED_NOISE_FRACTION))
        twin_text = shape_text + (f" These data cannot tell it apart from {', '.join(twins)} (the same prediction to within "
                     f"{CONFOUNDED_NOISE_FRACTION:g}x the noise floor). The run that would: "
                     + separating_runs(best["effect"], twins, robot)
                     + " designs it (the motion on which their fitted predictions differ most, within the limits of "
                     f"configs/{robot}/excitation.yaml); record it and add it to the fit runs." if twins else "")
        if best["decided_on"] == "arm":
            reach = (f"it explains {best['explained']:.0%} of the holdout residual ({best['explained_beyond_noise']:.0%} "
                     f"of what lies above the noise floor, each joint in units of its own floor), bringing it from "
                     f"{floor_multiple(ratio)} to {floor_multiple(best['evidence']['x_floor_after'])} the floor ({rmse_now:.3g} to "
                     f"{best['evidence']['rmse_after']:.3g} N*m)")
        else:
            reach = (f"on {', '.join(best['joints'])} it removes most of what lies above the noise floor "
                     f"({_joint_text(best['joints'], x_now_map, after)} the joint's own floor), though only "
                     f"{best['explained']:.0%} of the arm-wide residual")
        joint_text = f" on {', '.join(best['joints'])}" if best["joints"] else ""
        verdict = (
            f"On {where}, the model is missing {best['effect']}{joint_text}: {reach}. "
            f"Add the line '{best['add']}' under 'effects:' in configs/{robot}/model.yaml{removal_text(best)}.{twin_text}"
            + caveats(best, group, robot)
        )
    elif not above:
        status = "at_noise_floor"
        verdict = (
            f"Nothing to add on {where}: every joint's holdout residual is within {limits['noise_floor_factor']}x its "
            f"own noise floor (worst {max(x_now_map, key=x_now_map.get) if x_now_map else '-'} "
            f"{floor_multiple(max(x_now_map.values()) if x_now_map else 0)}; {rmse_now:.3g} N*m against {noise:.3g} N*m arm-wide) "
            f"and no effect removes more than {limits['min_explained']:.0%} of what lies above it."
        )
    else:
        status = "unexplained"
        details = "; ".join(
            f"{j} {floor_multiple(per_joint_status[j]['x_floor'])} its floor"
            + (f" (closest: {per_joint_status[j]['closest']}, removing "
               f"{per_joint_status[j]['closest_explained_beyond_noise']:.0%} of its excess)"
               if per_joint_status[j]["closest"] else "")
            for j in above)
        verdict = (
            f"No effect in the library explains the residual on {where}: {details}. The best candidate arm-wide "
            f"({best['effect'] if best else 'none'}) removes only {best['explained_beyond_noise'] if best else 0:.0%} "
            "of what lies above the floor. Look at the worst windows in the gap report."
        )
    if failed:
        verdict += " " + failed_text(failed)
    return {
        "link": link,
        "candidates": candidates,
        "verdict": verdict,
        "status": status,
        "confounded": [list(pair) for pair in confounded],
        "tied": [c["effect"] for c in group],
        "residual_rmse": round(rmse_now, 6),
        "noise_floor_ratio": round(ratio, 4) if np.isfinite(ratio) else None,
        "per_joint": per_joint_status,
        "above_floor": above,
        "skipped": skipped,
        "failed": sorted(failed),
    }


def failed_text(failed: Mapping[str, Mapping[str, Any]]) -> str:
    """The verdict's sentence on trials that did not solve (:func:`failed_trial`)."""
    def x(value: float | None) -> str:
        return floor_multiple(value) if value is not None else "not finite"

    parts = [f"{name} ({x(figures['fit_x_floor'])} the floors on the fit runs against the model's "
             f"{x(figures['model_fit_x_floor'])})" for name, figures in sorted(failed.items())]
    return (f"The trial of {', '.join(parts)} did not solve: a model that extends the current one fits its runs at "
            "least as well, so it is left out of the ranking, neither named nor ruled out. The sysid log has the "
            "solver's messages.")
