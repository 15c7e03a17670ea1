"""What keeps a verdict from being a clean decision, and the notes it then carries (:func:`caveat_notes`).

* **Ties** (:func:`tied`, :func:`ties`): a decisive candidate named on the same joints as the best whose holdout
  residual is the best one's within the spread of their paired difference over blocks of the holdout is not told
  apart from it on these runs; the verdict recommends the best-ranked plausible one (:func:`recommend`) or none,
  and names the separating run the experiment design builds.
* **Inertias** (:func:`implausible_bodies`, :func:`bound_changes`): the bodies a candidate's fit leaves beyond
  plausible, or pushes to the bounds the consistent fit holds, where the current model does not.
* **Trades with the model** (:func:`trades_with_model`): a candidate whose own term the fit gives back through the
  effects already in the model.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from sim2real.identification import fitting
from sim2real.identification.diagnosis.lags import same_lag
from sim2real.identification.diagnosis.margins import tie_near
from sim2real.identification.diagnosis.result import CandidateEvidence
from sim2real.identification.effects.base import Signals
from sim2real.identification.records import Note, NoteKind

# Effects that are special cases of another: never tried once the larger one is in the model, and never a tie
# (parsimony decides). Gaz's sigmoid with no velocity offset is a Coulomb tanh: asymmetric_friction holds
# coulomb_friction; so does load_friction, with no load coefficient.
NESTED_IN: dict[str, tuple[str, ...]] = {"link_inertia": ("payload",), "asymmetric_friction": ("coulomb_friction",),
                                        "sensor_drift": ("torque_bias",), "load_friction": ("coulomb_friction",)}
# Of those, the special cases whose columns lie in the span of the larger effect's (a payload's are the last link's
# inertial columns): both in one model fit the same torque twice, a fit only the inertial prior keeps from singular,
# so the larger effect replaces the line (diagnosis.trials.replaced_by). A Coulomb friction beside an asymmetric
# one is not: a second sigmoid of its own slope, another shape of friction. A load friction's unloaded level is the
# Coulomb friction's very column.
SPANNED_BY: dict[str, tuple[str, ...]] = {"link_inertia": ("payload",), "load_friction": ("coulomb_friction",)}

# Ties: the holdout is cut into this many blocks of time (at most; 50 samples each at least); two candidates whose
# summed squared residuals differ by less than TIE_SPREAD standard errors of that difference over the blocks (paired,
# block by block) are not told apart on these runs.
TIE_BLOCKS = 20


TIE_SPREAD = 2.0


# A candidate trades places with the model when the fit gives back, through the terms of the effects already in
# the model, so much of the candidate's own term that the prediction moves by at most TRADE_NET of it (RMS); the
# effects named are those whose term moved against it (correlation at most TRADE_CORRELATION).
TRADE_NET = 0.5


TRADE_CORRELATION = -0.5


# A trade this close to a correlation of -1, which leaves the prediction within the noise floor of the current one
# (its net move, RMS over the holdout, at most RELABEL_NET x the floor), is no new term at all: the candidate's own
# term is an effect of the model relabelled, its fall the current model's (relabelling), and it is never named. A
# torque gain against the link inertias' scale trades as closely (-0.997 on the lab's sensor_gains arm) but moves
# the prediction by several floors: a change the data resolve, named with its caution.
RELABEL_CORRELATION = -0.95


RELABEL_NET = 1.0


# Two candidates act "on the same joints" when the joints each is named on overlap by this share (Jaccard).
TIE_JOINT_OVERLAP = 0.5


def effect_term(result: fitting.FitResult, name: str, nominal: Any, data: fitting.TorqueData, signals: Signals,
          ) -> np.ndarray | None:
    """What the effect ``name`` adds to ``result``'s prediction on ``data`` (None: no linear coefficients)."""
    import dataclasses

    coefficients = np.asarray(result.theta.get(name, []), dtype=float)
    if not coefficients.size:
        return None
    without = dataclasses.replace(result, theta={**result.theta, name: np.zeros_like(coefficients)})
    return fitting.predict(result, nominal, data, signals) - fitting.predict(without, nominal, data, signals)


def trades_with_model(trial: fitting.FitResult, current: fitting.FitResult, name: str, nominal: Any,
                      data: fitting.TorqueData, signals: Signals, unit: np.ndarray) -> list[dict[str, Any]]:
    """Effects already in the model that the candidate ``name`` trades places with: adding it, the fit moves their
    terms against the candidate's own (a torque gain against the link inertias' scale) until the prediction moves
    by at most :data:`TRADE_NET` of the own term. On these runs they are confounded: the candidate's fall is the
    model's effect relabelled. Each with the size of its move (x the own term's RMS), its correlation with the
    own term, in floor units on the holdout, and the net move of the prediction (RMS, x the floor); empty when the
    candidate adds a term of its own."""
    own = effect_term(trial, name, nominal, data, signals)
    if own is None:
        return []
    for effect in current.effects:
        # a line the candidate replaces (diagnosis.trials.replaced_by) hands it its term by design: what the
        # candidate adds of its own is its term less that one
        replaced = effect_term(current, effect, nominal, data, signals) if effect not in trial.effects else None
        if replaced is not None:
            own = own - replaced
    own = own / unit
    size = float(np.sqrt(np.mean(own**2)))
    if size <= 0:
        return []
    moves = {}
    for effect in current.effects:
        if effect not in trial.effects:
            continue
        after = effect_term(trial, effect, nominal, data, signals)
        before = effect_term(current, effect, nominal, data, signals)
        if after is not None and before is not None:
            moves[effect] = (after - before) / unit
    net = own + sum(moves.values(), np.zeros_like(own))
    net_size = float(np.sqrt(np.mean(net**2)))
    if net_size > TRADE_NET * size:
        return []
    out = []
    for effect, change in moves.items():
        denominator = float(np.linalg.norm(change) * np.linalg.norm(own))
        correlation = float(np.sum(change * own) / denominator) if denominator > 0 else 0.0
        if correlation <= TRADE_CORRELATION:
            out.append({"effect": effect, "moved_x_own_term": round(float(np.sqrt(np.mean(change**2))) / size, 3),
                        "correlation": round(correlation, 3), "net_x_floor": round(net_size, 3)})
    return out


def relabelling(trades: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The trades (:func:`trades_with_model`) that make a candidate a relabelling of the model: its own term given
    back through an effect already held, correlation near -1 (:data:`RELABEL_CORRELATION`), the prediction unchanged
    within the noise floor (:data:`RELABEL_NET`)."""
    return [dict(t) for t in trades
            if t["correlation"] <= RELABEL_CORRELATION and t.get("net_x_floor", np.inf) <= RELABEL_NET]


def _block_sse(scaled: np.ndarray, blocks: int) -> np.ndarray:
    """Squared residual (floor units) summed over joints and over each of ``blocks`` contiguous blocks of rows."""
    return np.array([float(np.sum(part**2)) for part in np.array_split(scaled, blocks)])


def tied(a: np.ndarray, b: np.ndarray) -> tuple[bool, float, float]:
    """Whether two candidates' block scores (:func:`_block_sse`) differ by less than :data:`TIE_SPREAD` standard
    errors of their paired difference; (tie, difference, standard error), in floor units squared."""
    difference = a - b
    spread = float(np.sqrt(difference.size) * np.std(difference, ddof=1)) if difference.size > 1 else 0.0
    total = float(difference.sum())
    return abs(total) <= TIE_SPREAD * spread, total, spread


def _bodies(result: fitting.FitResult | None) -> dict[str, Any]:
    inertia = ((result.values if result is not None else None) or {}).get("link_inertia") or {}
    return inertia.get("bodies") or {}


def implausible_bodies(result: fitting.FitResult, current: fitting.FitResult | None = None) -> list[dict[str, Any]]:
    """The bodies a fit leaves beyond plausible (:mod:`sim2real.identification.effects.link_inertia`), each with why
    (``{"body", "reasons"}``); with ``current`` (the model the fit adds to), only those the current model does not
    already leave so: a candidate is judged on what it changes, never on a state it inherits. A consistent fit holds
    every body inside its bands (:mod:`sim2real.identification.inertial.bands`): only an unconstrained one can leave
    any."""
    inherited = {name for name, body in _bodies(current).items() if body.get("implausible")}
    return [{"body": name, "reasons": list(body["implausible"])} for name, body in _bodies(result).items()
            if body.get("implausible") and name not in inherited]


def binding_bodies(result: fitting.FitResult | None) -> dict[str, list[str]]:
    """The bodies whose bounds bind in a fit, with which (``mass_upper``, ``hull``, ...; :func:`sim2real.identification.
    inertial.bands.binding`): where the data push a link as far as physics lets them."""
    return {name: list(body["binding"]) for name, body in _bodies(result).items() if body.get("binding")}


def bound_changes(result: fitting.FitResult, current: fitting.FitResult | None) -> dict[str, dict[str, list[str]]]:
    """What a candidate's fit does to the bounds that bind: those it ``pushes`` (bind in its fit, not in the current
    model's) and those it ``releases`` (bind in the current model's, not in its fit), by body."""
    now, then = binding_bodies(result), binding_bodies(current)
    pushed = {name: [b for b in bounds if b not in then.get(name, [])] for name, bounds in now.items()}
    released = {name: [b for b in bounds if b not in now.get(name, [])] for name, bounds in then.items()}
    return {"pushes": {k: v for k, v in pushed.items() if v}, "releases": {k: v for k, v in released.items() if v}}


def nested_pair(a: str, b: str) -> bool:
    """Whether one of two effects is a special case of the other (:data:`NESTED_IN`)."""
    return b in NESTED_IN.get(a, ()) or a in NESTED_IN.get(b, ())


def _overlap(first: Sequence[str], second: Sequence[str]) -> float:
    """Jaccard overlap of two joint lists (1 when both name none: arm-wide)."""
    a, b = set(first), set(second)
    return len(a & b) / len(a | b) if a | b else 1.0


def ties(candidates: list[dict[str, Any]], residuals: Mapping[str, np.ndarray], rows: int) -> list[dict[str, Any]]:
    """The decisive candidates the best one is not told apart from on these runs: each removes about the same
    residual (:func:`tied`, over blocks of the holdout) on joints the best one is named on. Each gets its test's
    numbers in its evidence (``tie_with_best``)."""
    if not candidates or not candidates[0]["decisive"]:
        return []
    best = candidates[0]
    blocks = max(2, min(TIE_BLOCKS, rows // 50))
    best_blocks = _block_sse(residuals[best["effect"]], blocks)
    out = []
    for c in candidates[1:]:
        # A nested pair is parsimony's to decide (_rank), two shapes of one lag the ranking's (same_lag); on other
        # joints it is another effect, not a rival.
        if (not c["decisive"] or nested_pair(best["effect"], c["effect"]) or same_lag(best["effect"], c["effect"])
                or _overlap(best["joints"], c["joints"]) < TIE_JOINT_OVERLAP):
            continue
        same, difference, spread = tied(_block_sse(residuals[c["effect"]], blocks), best_blocks)
        near = tie_near(difference, spread, TIE_SPREAD)  # within the arithmetic's margin of the bound: tied
        if same or near:
            c["evidence"] = replace(c["evidence"], tie_with_best={
                "difference": round(difference, 3), "spread": round(spread, 3), "blocks": blocks,
                **({"near_threshold": True} if near else {})})
            out.append(c)
    return out


def troubles(evidence: CandidateEvidence) -> list[dict[str, Any]]:
    """Why a candidate (its ``evidence``) would leave the model less trustworthy, each a record (``kind`` and its
    figures): inertias bent beyond plausible (``implausible``), pushed to their bounds (``bounds``), or a trade with an
    effect already in the model (``trade``)."""
    reasons: list[dict[str, Any]] = []
    if evidence.implausible_bodies:
        reasons.append({"kind": "implausible", "bodies": list(evidence.implausible_bodies)})
    if evidence.bounds_pushed:  # pairs, in the order of the bodies (a document's mappings are sorted by name)
        reasons.append({"kind": "bounds", "bodies": [[name, list(b)] for name, b in evidence.bounds_pushed.items()]})
    for trade in evidence.trades_with or ():
        reasons.append({"kind": "trade", **trade})
    return reasons


def recommend(candidates: list[dict[str, Any]], ties: list[dict[str, Any]],
               ) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:
    """The candidate to add among the best and those tied with it: the first in the ranking (:func:`~sim2real.identification.diagnosis.candidates._rank`: the
    best holdout residual, nested effects by parsimony) that is physically plausible (no inertia bent beyond
    plausible, no trade with the model); None when the best is tied and none of the tied is plausible. A best
    candidate that nothing ties is recommended, its trouble said beside it (:func:`caveat_notes`): early in the loop
    bent inertias are the symptom of what is still missing. The recommended one goes first."""
    if not candidates or not candidates[0]["decisive"]:
        return candidates, None
    if not ties:
        return candidates, candidates[0]
    group = [candidates[0], *ties]
    chosen = next((c for c in group if not troubles(c["evidence"])), None)
    if chosen is None and all(troubles(c["evidence"]) == troubles(group[0]["evidence"]) for c in group):
        chosen = group[0]  # a condition every tied candidate shares tells none of them apart: the best, cautioned
    if chosen is None:
        return candidates, None
    return [chosen] + [c for c in candidates if c is not chosen], chosen


def caveat_notes(best: Mapping[str, Any], group: Sequence[Mapping[str, Any]]) -> list[Note]:
    """The notes a verdict carries when its candidate is not a clean decision: ties with other candidates (and the
    run that would separate them), and what its fit does that makes it less trustworthy (inertias implausible or
    pushed to their bounds, effects of the model it trades with)."""
    notes = []
    others = [c["effect"] for c in group if c["effect"] != best["effect"]]
    if others:
        notes.append(Note(NoteKind.TIED, effect=best["effect"],
                          figures={"others": others, "first": group[0]["effect"], "spread": TIE_SPREAD}))
    reasons = troubles(best["evidence"])
    if reasons:
        notes.append(Note(NoteKind.CAUTION, effect=best["effect"], figures={"troubles": reasons}))
    return notes
