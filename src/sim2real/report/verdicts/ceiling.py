"""The model-free ceiling's words: what a flexible learner on the motion (or the pose) says is left, what the rest
follows, and what to do about a run's own offsets (:func:`ceiling_text`, gap.json's ``model_free``:
:func:`ceiling_section`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

from sim2real.identification.diagnosis.ceiling import (
    CLOSE_TO_RUNG, POSE_LEARNERS, imitated_joints, offset_joints,
)
from sim2real.identification.diagnosis.ceiling_records import CeilingReading, EffectAdvice, ModelFreeCeiling
from sim2real.identification.effects.sensor_drift import SHAPE as DRIFT_SHAPE
from sim2real.stats import floor_multiple

KIND_TEXT = {
    "time": "drifts with time within each run (a warm-up, a sensor offset that wanders, or an error of the slow pose "
    "the run moves through)",
    "run": "is an offset that differs from run to run",
    "history": "follows the history of the motion: the displacement since the last velocity reversal "
    "(hysteresis, presliding friction)",
}
GAIN_REGIME_TEXT = {"slow_reversal": "slow motion and velocity reversals", "hard_acceleration": "hard accelerations"}
# What sits at an offset of its own in each run or drifts within one is the sensor's, not the robot's: said where the
# ceiling finds it, with what a user does about it, and for runs already logged the effect that estimates it.
OFFSET_ADVICE = ("On {joints} the torque sits at an offset of its own in each run or drifts within it (a torque sensor "
                 "warming up, or zeroed at another moment): no property of the robot, but every fit takes part of it "
                 "for one (a link inertia fitted to one run's offset misses the next run's), so it can hide an effect "
                 "the library has. Log once the arm has warmed up, its torque sensors zeroed at rest, and run the loop "
                 "again")
DECLARE_ADVICE = ("; or, for these runs, add the line '{line}' under 'effects:' in configs/{robot}/model.yaml: "
                  f"each run's drift ({DRIFT_SHAPE}) is then estimated on that run itself, "
                  "the holdout runs included, and never written into the assets.")
# A declared drift is held to the loop's rule like a candidate (sim2real.identification.diagnosis.raises): the robot's
# parameters, fitted again beside it, may trade one joint for the others.
KEPT_DECLARE = (" Written for every joint, it raises {raised} (the robot's parameters, fitted again beside it, trade "
                "that joint for the others): the line is kept on {kept}.")
WITHHELD_DECLARE = (". A drift of each run's own is not advised for these runs: declared, it raises {raised} (the "
                    "robot's parameters, fitted again beside it, trade that joint for the others), and kept on the "
                    "joints it helps it still raises one.")


FEATURE_TEXT = {
    "position": "position of {joint}", "velocity": "velocity of {joint}", "acceleration": "acceleration of {joint}",
    "predicted_torque": "the torque the model predicts for {joint}", "velocity_sign": "the sign of velocity of {joint}",
    "speed": "the speed of {joint}", "gravity_torque": "the gravity torque of {joint}",
    "torque_times_sign": "the torque the model predicts for {joint} times the sign of its velocity",
    "abs_torque_times_sign": "|the torque the model predicts for {joint}| times the sign of its velocity",
    **{f"gravity_along_{axis}": f"the gravity torque of {{joint}} under gravity along the base's {axis}"
       for axis in ("x", "y", "z")},
    "sin_position": "the sine of the angle of {joint}", "cos_position": "the cosine of the angle of {joint}",
}


def feature_text(feature: Mapping[str, Any] | str) -> str:
    """A learner's feature (:func:`sim2real.identification.diagnosis.ceiling_features.feature`) in words."""
    if isinstance(feature, str):
        return feature
    if feature["feature"] == "periodic_position":
        every = f", every {feature['period']:.3g} rad" if "period" in feature else ""
        return f"position of {feature['joint']} (periodic{every})"
    return FEATURE_TEXT[feature["feature"]].format(joint=feature["joint"])


def _learned(j: str, r: CeilingReading) -> str:
    with_ = [feature_text(f) for f in r.gains_most_with or ()]
    follows = f", mostly as a function of {' and '.join(with_)}" if with_ else ""
    if r.gains_most_in:
        follows += f", most in {GAIN_REGIME_TEXT[r.gains_most_in]}"
    return f"{j} {floor_multiple(r.rung_x_floor)} -> {floor_multiple(r.ceiling_x_floor)} its floor{follows}"


def _drift_share(r: CeilingReading) -> float:
    """The share of a joint's excess the drift it follows removes."""
    assert r.beyond_motion is not None and r.follows is not None
    return r.beyond_motion[r.follows]


def _motion_sentence(per_joint: Mapping[str, CeilingReading], joints: Sequence[str]) -> str:
    def beside(r: CeilingReading) -> str:
        if r.follows not in ("time", "run"):
            return ""
        return (f", beside a drift of each run's own that removes {_drift_share(r):.0%} of its excess "
                "(the learner, fitted again without it, still explains much)")

    return ("A flexible learner on the motion explains much of what is left, so the library lacks an effect that is "
            f"a function of the motion: {'; '.join(_learned(j, per_joint[j]) + beside(per_joint[j]) for j in joints)}. "
            "Model that dependence (an effect of the library's shape; a periodic one of a joint's position is "
            "position_ripple's, one period per joint) before trusting the rest.")


def _pose_sentence(per_joint: Mapping[str, CeilingReading], joints: Sequence[str], points_to: EffectAdvice | None,
                   robot: str) -> str:
    """Joints where a function of the pose alone explains what is left (a pose learner carried it to the holdout's
    poses): said so, with the pose dependence named, and the library's effect that carries it where it has one."""
    text = ("A function of the pose alone explains much of what is left, carried from the fit runs' poses to the "
            f"holdout's: {'; '.join(_learned(j, per_joint[j]) for j in joints)}.")
    if points_to:
        text += (f" On {', '.join(points_to.joints)} it follows the arm's gravity torque under a gravity turned "
                 f"sideways, the mark of a base mounted off level: add the line '{points_to.line}' under "
                 f"'effects:' in configs/{robot}/model.yaml.")
    else:
        text += (" No effect of the library has its shape (a cable's or a hose's pull, a spring, a mass the model "
                 "misplaces): model that dependence before trusting the rest.")
    return text


def _imitated_sentence(per_joint: Mapping[str, CeilingReading], joints: Sequence[str]) -> str:
    parts = [f"{_learned(j, per_joint[j])}, yet a drift of each run's own removes "
             f"{_drift_share(per_joint[j]):.0%} of its excess (the learner "
             f"{per_joint[j].explained_beyond_noise:.0%}): it {KIND_TEXT[per_joint[j].follows or '']}" for j in joints]
    return ("A learner on the motion explains part of what is left where each run's motion follows its time, and "
            f"there it only imitates a drift: {'; '.join(parts)}.")


def _still_sentence(per_joint: Mapping[str, CeilingReading], joints: Sequence[str]) -> str:
    parts = []
    for j in joints:
        r = per_joint[j]
        what = KIND_TEXT[r.follows] if r.follows else ("follows none of time within a run, the run or the "
                                                       "history since a reversal (a sensor's own dynamics, "
                                                       "noise the floor misses)")
        parts.append(f"{j} ({floor_multiple(r.rung_x_floor)} its floor; the learner "
                     f"{floor_multiple(r.ceiling_x_floor)}): it {what}")
    return (f"No function of the motion explains the rest: a flexible learner on the motion comes within "
            f"{1 - CLOSE_TO_RUNG:.0%} of the last rung on {', '.join(joints)}. " + "; ".join(parts) + ".")


def ceiling_text(ceiling: ModelFreeCeiling, robot: str, joints: Sequence[str] = ()) -> str:
    """What the model-free ceiling says (:func:`sim2real.identification.diagnosis.model_free_ceiling`): joints where
    the library lacks a function of the motion, joints where the motion only imitates a drift, and joints where
    nothing of the motion explains the rest, with what it follows and what to do about offsets. ``joints``: their
    order (default: the document's)."""
    per_joint = ceiling.ordered(joints)
    imitated = imitated_joints(per_joint)
    posed = [j for j, r in per_joint.items() if r.kind == "motion" and j not in imitated
             and r.learner in POSE_LEARNERS]
    motion = [j for j, r in per_joint.items() if r.kind == "motion" and j not in imitated and j not in posed]
    still = [j for j, r in per_joint.items() if r.kind == "not_motion"]
    sentences = ([_pose_sentence(per_joint, posed, ceiling.points_to, robot)] if posed else []) + (
        [_motion_sentence(per_joint, motion)] if motion else []) + (
        [_imitated_sentence(per_joint, imitated)] if imitated else []) + (
        [_still_sentence(per_joint, still)] if still else [])
    offsets = offset_joints(per_joint)
    if offsets:
        sentences.append(OFFSET_ADVICE.format(joints=", ".join(offsets)) + _declare_words(ceiling, robot))
    return " ".join(sentences)


def _raised_words(raised: Mapping[str, Sequence[float]]) -> str:
    return ", ".join(f"{j} from {floor_multiple(a)} to {floor_multiple(b)} its floor" for j, (a, b) in raised.items())


def _declare_words(ceiling: ModelFreeCeiling, robot: str) -> str:
    """The end of the offsets' advice: the drift's line to declare for these runs (kept on some joints, and why), or
    why none is advised."""
    declare, withheld = ceiling.declare, ceiling.withheld
    if declare is not None:
        text = DECLARE_ADVICE.format(line=declare.line, robot=robot)
        if declare.kept_to and declare.raised:
            text += KEPT_DECLARE.format(raised=_raised_words(declare.raised), kept=", ".join(declare.kept_to))
        return text
    if withheld is not None and withheld.raised:
        return WITHHELD_DECLARE.format(raised=_raised_words(withheld.raised))
    return "."


def ceiling_section(ceiling: ModelFreeCeiling, robot: str, joints: Sequence[str] = ()) -> dict[str, Any]:
    """gap.json's ``model_free``: the ceiling's document with its words (``text``, the features in words)."""
    worded = replace(ceiling, per_joint={
        j: row if row.gains_most_with is None else replace(row, gains_most_with=tuple(
            feature_text(f) for f in row.gains_most_with)) for j, row in ceiling.per_joint.items()})
    return {**worded.as_document(), "text": ceiling_text(ceiling, robot, joints)}
