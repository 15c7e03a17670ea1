"""No recommended rung raises a joint: the joints a candidate's trial raises beyond the noise (:func:`raised_joints`),
and what the diagnosis then recommends (:func:`keep_off_raised`).

A candidate fitted arm-wide may lower most joints and raise one: a friction whose shared slope or the link inertias
refitted beside it trade one joint's residual for the others'. The loop promises that no rung it recommends raises a
joint beyond the noise, so such a candidate is never recommended arm-wide. Where its effect takes a per-joint line
(:attr:`sim2real.identification.effects.base.Effect.per_joint_line`), it is tried again kept on the joints it helps
(``- coulomb_friction: {joints: [...]}``), exactly as the next round fits that line, and recommended so when that
trial is still decisive and raises none; otherwise it is withheld, named on nothing, and the next candidate is
considered. The verdict says which joints it raises, by how much, and why its line is kept to some joints or withheld.

"Beyond the noise" is two conditions at once, each read as the loop already reads such a figure:

* the joint ends more than :data:`RAISE_TOLERANCE` x its floor above both where it was and the floor factor (a joint
  that ends within ``noise_floor_factor`` of its floor, give or take the tolerance, is raised by nothing: the loop's
  goal is reached there),
  read with the arithmetic's margin (:data:`~sim2real.identification.diagnosis.margins.X_FLOOR_MARGIN` of the
  threshold) against the recommendation (:data:`~sim2real.identification.diagnosis.margins.CONSERVATIVE`);
* the rise is resolved by the holdout: the joint's squared residual, summed over blocks of the holdout as the tie
  test sums it (:func:`~sim2real.identification.diagnosis.caveats.tied`), rises by more than
  :data:`~sim2real.identification.diagnosis.caveats.TIE_SPREAD` standard errors of the paired difference (the tie's
  bound, read with its margin the same way): a rise a block of the holdout could give or take is no rise these runs
  can tell from noise.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from sim2real.identification import fitting
from sim2real.identification.diagnosis.caveats import TIE_BLOCKS, TIE_SPREAD, _block_sse
from sim2real.identification.diagnosis.current import CurrentResidual
from sim2real.identification.diagnosis.margins import (CONSERVATIVE, PERMISSIVE, SHARE_MARGIN, TIE_MARGIN,
                                                       X_FLOOR_MARGIN, Near)
from sim2real.identification.diagnosis.trials import trial_fits
from sim2real.identification.effects import EFFECTS
from sim2real.identification.fitting import EFFECT_JOINTS_SETTING
from sim2real.identification.records import Note, NoteKind

# A joint is raised when it ends this much above both where it was and the floor factor (x its floor), and the
# holdout resolves the rise.
RAISE_TOLERANCE = 0.1

# Why a candidate that raises a joint is not recommended arm-wide: kept on the joints it helps (``kept_to``), or
# withheld because its effect takes no per-joint line, it helps no joint it does not raise, or its trial kept on
# those joints still raises one or names nothing.
OUTCOMES = ("kept_to", "not_per_joint", "helps_none", "kept_to_raises", "kept_to_not_decisive", "kept_to_not_tried")

# The withheld candidates tried again on the joints they help, the one that removes most first: a trial costs a
# rung's fit, and the first that holds is recommended (the others are not tried: kept_to_not_tried).
KEPT_TO_TRIALS = 2


def raised_joints(scores: Mapping[str, Any], now: CurrentResidual, joints: Sequence[str], limits: Mapping[str, float],
                  way: float = CONSERVATIVE) -> dict[str, tuple[float, float]]:
    """The joints a trial (its ``scores``: ``x_after`` and ``scaled``, its holdout residual in floor units) raises
    beyond the noise (see the module's docstring), each with (before, after) x its floor; each threshold moved by
    its margin ``way`` (:data:`CONSERVATIVE`: more joints count as raised)."""
    blocks = max(2, min(TIE_BLOCKS, now.rows // 50))
    out = {}
    for k, joint in enumerate(joints):
        before, after = float(now.x_floor[k]), float(scores["x_after"][k])
        bar = max(before, float(limits["noise_floor_factor"])) + RAISE_TOLERANCE
        if after <= bar * (1.0 - way * X_FLOOR_MARGIN):
            continue
        rise = _block_sse(scores["scaled"][:, k], blocks) - _block_sse(now.scaled[:, k], blocks)
        spread = float(np.sqrt(rise.size) * np.std(rise, ddof=1)) if rise.size > 1 else 0.0
        if float(rise.sum()) > TIE_SPREAD * spread * (1.0 - way * TIE_MARGIN):
            out[joint] = (round(before, 3), round(after, 3))
    return out


def near_raises(scores: Mapping[str, Any], now: CurrentResidual, joints: Sequence[str], limits: Mapping[str, float],
                raised: Mapping[str, tuple[float, float]]) -> list[Near]:
    """The joints of ``raised`` (read conservatively) that the permissive reading does not raise: their figure after
    (x the floor) sits within the arithmetic's margin of a threshold of :func:`raised_joints`."""
    loose = raised_joints(scores, now, joints, limits, PERMISSIVE)
    factor = float(limits["noise_floor_factor"])
    return [Near("raised_x_floor", after, max(before, factor) + RAISE_TOLERANCE,
                 (max(before, factor) + RAISE_TOLERANCE) * X_FLOOR_MARGIN, joint)
            for joint, (before, after) in raised.items() if joint not in loose]


def helped_joints(candidate: Mapping[str, Any], joints: Sequence[str], limits: Mapping[str, float]) -> list[str]:
    """The joints a raising candidate helps: those not raised where it removes ``joint_min_explained`` of the excess
    above the floor, read with the share's margin against the joint (in the robot's order): a joint the line is
    kept on is one the trial clearly helps."""
    raised = candidate["evidence"].raised or {}
    share = candidate["evidence"].per_joint_explained_beyond_noise
    return [j for j in joints if j not in raised and share[j] >= limits["joint_min_explained"] + SHARE_MARGIN]


def withhold(candidate: dict[str, Any], raised: Mapping[str, tuple[float, float]], near: Sequence[Near] = ()) -> None:
    """Make a decisive ``candidate`` that raises joints (``raised``) not decisive, named on nothing, keeping the
    joints it raises in its evidence, and the figures within the margin of a threshold (``near``: :func:`near_raises`)
    that the conservative reading decided."""
    evidence = candidate["evidence"]
    held_back = tuple(evidence.near_threshold or ()) + tuple(n.as_document() for n in near)
    candidate["evidence"] = replace(evidence, raised={j: tuple(v) for j, v in raised.items()},
                                    near_threshold=held_back or None)
    candidate.update({"decisive": False, "decided_on": None, "joints": [], "withheld": "not_per_joint"})


Trial = tuple[fitting.FitResult, np.ndarray]


def keep_off_raised(candidates: list[dict[str, Any]], residuals: dict[str, np.ndarray], trials: dict[str, Trial],
                    model_effects: Sequence[str], context: fitting.FitContext, current: fitting.FitResult | None,
                    limits: Mapping[str, float],
                    rescore: Callable[[str, Trial, fitting.FitContext], tuple[dict[str, Any], np.ndarray, Any]]) -> None:
    """Each withheld candidate (:func:`withhold`) whose effect takes a per-joint line and helps some joint, tried
    again kept on those joints (the setting the next round fits its line with) and scored by ``rescore`` (the
    diagnosis's own scoring: the candidate, its holdout residual in floor units, its failed solve's figures or None);
    where that trial is decisive and raises none, it replaces the candidate in ``candidates`` (its residual in
    ``residuals``, its trial in ``trials``), its line kept to those joints. Otherwise the candidate stays withheld,
    with why."""
    joints = list(context.holdout_data.joint_names)
    fixed = current.nonlinear if current is not None else None
    withheld = sorted((k for k, c in enumerate(candidates) if c.get("withheld")),
                      key=lambda k: (-candidates[k]["explained"], candidates[k]["effect"]))
    tried = 0
    for k in withheld:
        candidate = candidates[k]
        if not EFFECTS[candidate["effect"]].per_joint_line:
            continue
        helped = helped_joints(candidate, joints, limits)
        if not helped:
            candidate["withheld"] = "helps_none"
            continue
        if tried >= KEPT_TO_TRIALS:  # one kept on its joints already, or as many tried: the rest are not
            candidate["withheld"] = "kept_to_not_tried"
            continue
        tried += 1
        name = candidate["effect"]
        kept = {**(context.settings.get(EFFECT_JOINTS_SETTING) or {}), name: helped}
        narrowed = context.with_settings({**context.settings, EFFECT_JOINTS_SETTING: kept})
        trial = trial_fits([name], model_effects, narrowed, fixed)[name]
        restricted, scaled, broken = rescore(name, trial, narrowed)
        if restricted.get("withheld") or not restricted["decisive"] or broken is not None:
            candidate["withheld"] = "kept_to_raises" if restricted.get("withheld") else "kept_to_not_decisive"
            candidate["evidence"] = replace(candidate["evidence"], kept_to_trial={
                "joints": helped, "x_floor_after": restricted["evidence"].x_floor_after,
                "raised": {j: list(v) for j, v in (restricted["evidence"].raised or {}).items()}})
            continue
        arm_wide = candidate["evidence"]
        restricted["evidence"] = replace(restricted["evidence"], arm_wide_trial={
            "x_floor_after": arm_wide.x_floor_after, "per_joint_x_floor_after": dict(arm_wide.per_joint_x_floor_after),
            "raised": {j: list(v) for j, v in (arm_wide.raised or {}).items()}})
        restricted.update({"kept_to": helped, "add": add_line(name, helped)})
        candidates[k] = restricted
        residuals[name] = scaled
        trials[name] = trial
        tried = KEPT_TO_TRIALS


def rung_raises(rung_residual: np.ndarray, now: CurrentResidual, joints: Sequence[str],
                         limits: Mapping[str, float]) -> tuple[dict[str, tuple[float, float]], list[str]]:
    """What a rung does joint by joint against the current one, read as a candidate's trial is: the joints it raises
    beyond the noise (:func:`raised_joints`, each with (before, after) x its floor) and those it helps (the others
    where it removes ``joint_min_explained`` of the excess above the floor, read with the share's margin against the
    joint). For the rungs no trial stands for: a line the model-free ceiling declares (a drift of each run's own, which
    no held-out run judges), and a rung whose inertial prior's weight is chosen again. ``rung_residual``: that rung's
    holdout residual (N*m), ``now``: the current rung's."""
    scaled = rung_residual / now.unit
    sse_after = np.sum(scaled**2, axis=0)
    scores = {"scaled": scaled, "x_after": np.sqrt(sse_after / max(now.rows, 1))}
    raised = raised_joints(scores, now, joints, limits)
    with np.errstate(invalid="ignore", divide="ignore"):
        beyond = np.where(now.excess > 0, (now.sse - sse_after) / now.excess, 0.0)
    helped = [j for j, share in zip(joints, beyond, strict=True)
              if j not in raised and share >= limits["joint_min_explained"] + SHARE_MARGIN]
    return raised, helped


def raises_note(candidates: Sequence[Mapping[str, Any]]) -> Note | None:
    """The note of a diagnosis some of whose candidates raise a joint beyond the noise: each one's joints raised
    (before, after, x the floor), and whether its line is kept to the joints it helps (``kept_to``) or withheld, and
    why (:data:`OUTCOMES`)."""
    said = {}
    for c in candidates:
        evidence = c["evidence"]
        if c.get("kept_to"):
            said[c["effect"]] = {"outcome": "kept_to", "joints": list(c["kept_to"]),
                                 "raised": dict((evidence.arm_wide_trial or {}).get("raised") or {})}
        elif c.get("withheld"):
            said[c["effect"]] = {"outcome": c["withheld"], "raised": {j: list(v) for j, v in evidence.raised.items()},
                                 **({"kept_to_trial": dict(evidence.kept_to_trial)} if evidence.kept_to_trial else {})}
    return Note(NoteKind.RAISES, figures={"candidates": said, "tolerance": RAISE_TOLERANCE}) if said else None


def add_line(effect: str, joints: Sequence[str] | None = None) -> str:
    """The exact line to add under ``effects:`` in configs/{robot}/model.yaml; ``joints``: the line kept on them."""
    return "- " + effect + ("" if not joints else ": {joints: [" + ", ".join(joints) + "]}")
