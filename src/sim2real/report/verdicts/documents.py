"""gap.json's worded sections: ladder.json's content with its words (:func:`worded`), each diagnosis with its
verdict, notes and ceiling (:func:`diagnosis_section`), each rung with its notes."""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

from sim2real.identification.diagnosis import Diagnosis
from sim2real.identification.ladder_rows import Rung, rungs_of
from sim2real.identification.records import SensorPlacement
from sim2real.report.verdicts.ceiling import ceiling_section
from sim2real.report.verdicts.headline import verdict
from sim2real.report.verdicts.notes import NOTE_KEYS, NOTE_TEXT, implausible_text
from sim2real.report.verdicts.rungs import chosen_by_text, rung_note
from sim2real.report.verdicts.sides import judged_text, sides_section
from sim2real.report.verdicts.skipped import skip_reason

DATA_ONLY = ("notes", "noise_rmse", "noise_floor_factor", "min_explained", "joints")


def diagnosis_section(document: Mapping[str, Any], robot: str) -> dict[str, Any]:
    """gap.json's ``diagnosis`` (or ``actuator.diagnosis``): ladder.json's, data without words, with its words; one
    worded already (its verdict written, its data-only keys gone) as it is, so that wording is idempotent."""
    if "verdict" in document:
        return copy.deepcopy(dict(document))
    d = Diagnosis.from_document(document)
    out = {key: copy.deepcopy(value) for key, value in document.items() if key not in DATA_ONLY}
    out["verdict"] = verdict(d, robot)
    out["candidates"] = [replace(c, evidence=replace(c.evidence, implausible_bodies=tuple(
        implausible_text(b) for b in c.evidence.implausible_bodies))).as_document() for c in d.candidates]
    out["skipped"] = [{"effect": n.effect, "reason": skip_reason(n)} for n in d.skipped]
    if d.model_free is not None:
        out["model_free"] = ceiling_section(d.model_free, robot, d.joints)
    for note in d.notes:
        if note.kind in NOTE_KEYS:
            out[NOTE_KEYS[note.kind]] = NOTE_TEXT[note.kind](note, robot).strip()
    return out


def _worded_rung(rung: Rung) -> Rung:
    """A rung with its words: its notes and how its inertial prior's weight was chosen."""
    prior = rung.inertia_prior
    consistency = rung.consistency
    if isinstance(prior, Mapping) and "chosen_by" in prior:
        consistency = {**rung.consistency, "inertia_prior": {**prior, "chosen_by": chosen_by_text(prior["chosen_by"])}}
    return replace(rung, notes=tuple(rung_note(note) for note in rung.notes), consistency=consistency)


def _ladder_section(ladder: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """A side's rungs with their words (:func:`_worded_rung`)."""
    return [copy.deepcopy(_worded_rung(rung).as_document()) for rung in rungs_of(ladder)]


def worded(ladder: Mapping[str, Any], robot: str) -> dict[str, Any]:
    """ladder.json's content with its words: each diagnosis's verdict and notes, each rung's notes, what the sides can
    tell apart (what gap.json holds of it)."""
    out = dict(ladder)
    if "ladder" in out:
        out["ladder"] = _ladder_section(out["ladder"])
    if out.get("diagnosis"):
        out["diagnosis"] = diagnosis_section(out["diagnosis"], robot)
    if out.get("links"):
        out["links"] = sides_section(out["links"])
    if out.get("actuator"):
        sensor = (ladder.get("links") or {}).get("torque_sensor", SensorPlacement.MOTOR_SIDE)
        actuator = {"judged": judged_text(sensor), **out["actuator"]}
        actuator["ladder"] = _ladder_section(actuator["ladder"])
        if actuator.get("diagnosis"):
            actuator["diagnosis"] = diagnosis_section(actuator["diagnosis"], robot)
        out["actuator"] = actuator
    return out
