"""gap.md's first screen in words: the verdict in at most three sentences, from gap.json's diagnosis
(:func:`first_screen_verdict`), and what kind of thing is left on a joint (:func:`left_text`).

The sentences: the status; the line to add, or what kind of thing is left (joint by joint in the per-joint table
beside it, so named here by kind, never by joint); the worst joint in units of its floor. The diagnosis's own verdict,
with its reasons, follows further down gap.md."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

from sim2real.identification.diagnosis.caveats import troubles
from sim2real.identification.diagnosis.ceiling_records import CeilingReading, ModelFreeCeiling
from sim2real.identification.diagnosis.result import Candidate
from sim2real.identification.records import Status
from sim2real.report.verdicts.names import SIDE_TEXT, separating_runs
from sim2real.stats import floor_multiple

LEFT_TEXT = {"at_floor": "at its floor", "motion": "a function of the motion the library lacks"}
FOLLOWS_TEXT = {"time": "not the motion: drifts with time", "run": "not the motion: an offset per run",
                "history": "not the motion: follows the history since a reversal", None: "not the motion, nor time"}


def left_text(row: CeilingReading) -> str:
    """What kind of thing is left on a joint (the model-free ceiling's ``kind`` and ``follows``), in a few words; the
    features a learner on the motion gains most with, as gap.json words them."""
    if row.kind == "motion" and row.imitated:  # the motion only imitates what the run's time explains
        return FOLLOWS_TEXT[row.follows].replace("not the motion: ", "") + ", which the motion imitates"
    if row.kind == "motion":
        with_ = [str(f) for f in row.gains_most_with or ()]
        return LEFT_TEXT["motion"] + (f" ({', '.join(with_)})" if with_ else "")
    return LEFT_TEXT.get(row.kind) or FOLLOWS_TEXT[row.follows]


def _kinds_left(ceiling: Mapping[str, Any] | None, above: Sequence[str]) -> str:
    """The kinds of thing left above the floors (each with how many joints), in the order met."""
    per_joint = ModelFreeCeiling.from_document(ceiling).per_joint if ceiling else {}
    kinds: dict[str, int] = {}
    for joint in above:
        if joint in per_joint and per_joint[joint].kind != "at_floor":
            kind = left_text(replace(per_joint[joint], gains_most_with=()))
            kinds[kind] = kinds.get(kind, 0) + 1
    return "; ".join(f"{kind} ({count} joint{'s' if count > 1 else ''})" for kind, count in kinds.items())


def _best(diagnosis: Mapping[str, Any]) -> Candidate | None:
    """The candidate a diagnosis of gap.json ranks first (None: none tried)."""
    candidates = diagnosis.get("candidates") or []
    return Candidate.from_document(candidates[0]) if candidates else None


def _first_status(diagnosis: Mapping[str, Any], side: str) -> str:
    status, best = diagnosis.get("status"), _best(diagnosis)
    if status == Status.ADD_EFFECT and best and best.decided_on == "joints":
        # decided on its own joints (the table's "closest candidate there"), not on the arm-wide share
        return (f"On {side}, the model lacks {best.effect} on {len(best.joints)} joint"
                f"{'s' if len(best.joints) > 1 else ''}, where it removes most of what lies above their floors.")
    if status == Status.ADD_EFFECT and best:
        reach = (f": it removes {best.explained_beyond_noise:.0%} of what lies above the noise floor"
                 f", to {floor_multiple(best.evidence.x_floor_after)} the floor arm-wide")
        return f"On {side}, the model lacks {best.effect}{reach}."
    if status == Status.NOT_TOLD_APART:
        return (f"On {side}, {' and '.join(diagnosis.get('tied') or [])} each remove part of what is left, but no "
                "line is recommended: these runs do not tell a trustworthy effect.")
    if status == Status.AT_NOISE_FLOOR:
        return f"Nothing to add on {side}: every joint's holdout residual is at its own noise floor."
    return f"No effect in the library explains what is left on {side}."


def _first_action(diagnosis: Mapping[str, Any], robot: str) -> str | None:
    status, best = diagnosis.get("status"), _best(diagnosis)
    if status == Status.ADD_EFFECT and best:
        removal = "".join(f" and remove '- {r}'" for r in best.replaces)
        caution = "; read its caution in the diagnosis below first" if troubles(best.evidence) else ""
        return f"Add the line '{best.add}' under 'effects:' in configs/{robot}/model.yaml{removal}{caution}."
    tied = list(diagnosis.get("tied") or [])
    if status == Status.NOT_TOLD_APART and len(tied) > 1:
        return (f"The run that would tell them apart: {separating_runs(tied[0], tied[1:], robot)} designs it; record "
                "it and add it to the fit runs.")
    if status == Status.NOT_TOLD_APART:
        return (f"Record a run designed for the model (`snakemake results/{robot}/excitation/identification.csv`) and "
                "add it to the fit runs.")
    if status == Status.UNEXPLAINED:
        kinds = _kinds_left(diagnosis.get("model_free"), diagnosis.get("above_floor") or [])
        return (f"What is left, joint by joint in the table below: {kinds}." if kinds else
                "The worst windows and the residual figures below show where it lies.")
    return None


def first_screen_verdict(diagnosis: Mapping[str, Any], robot: str, x_floor: Mapping[str, float],
                         rmse: Mapping[str, float], floor: Mapping[str, float]) -> list[str]:
    """gap.md's verdict in at most three sentences (gap.json's ``diagnosis``; the current model's ``x_floor``,
    ``rmse`` and noise ``floor`` per joint): the status; the line to add, or the kinds of thing left; the worst
    joint in units of its floor."""
    side = SIDE_TEXT.get(str(diagnosis.get("link")), "the body link").split(" (")[0]
    sentences = [_first_status(diagnosis, side)]
    action = _first_action(diagnosis, robot)
    if action:
        sentences.append(action)
    if x_floor:
        worst = max(x_floor, key=x_floor.get)  # type: ignore[arg-type]
        sentences.append(f"Worst joint: {worst}, {floor_multiple(x_floor[worst])} its noise floor "
                         f"({rmse[worst]:.3g} N m against {floor[worst]:.3g} N m).")
    return sentences
