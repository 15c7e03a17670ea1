"""What a diagnosis returns: a :class:`Diagnosis`, typed data the report words (:mod:`sim2real.report.verdicts`).

Its document (:meth:`Diagnosis.as_document`, ladder.json's ``diagnosis``) holds the same data in JSON, read back by
:meth:`Diagnosis.from_document`; gap.json's ``diagnosis`` is that document with the words added.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from sim2real.identification.records import Note, Side, Status


@dataclass(frozen=True)
class Candidate:
    """One effect tried on top of the current model, and what its trial showed.

    ``evidence``: its residual signature (:meth:`sim2real.identification.effects.base.Effect.evidence`) and the
    trial's figures (``x_floor_after``, ``per_joint_x_floor_after``, ``fitted``, ``implausible_bodies``, ``bounds``,
    ``trades_with``, ``tie_with_best``, ``fit_failed`` ...)."""

    effect: str
    side: Side
    joints: tuple[str, ...]
    decided_on: str | None  # "arm", "joints", or None (not decisive)
    explained: float
    explained_beyond_noise: float
    decisive: bool
    evidence: Mapping[str, Any]
    add: str  # the line to add under ``effects:``
    replaces: tuple[str, ...] = ()  # lines of the model it holds, to be removed

    def as_document(self) -> dict[str, Any]:
        out = {"effect": self.effect, "link": str(self.side), "joints": list(self.joints),
               "decided_on": self.decided_on, "explained": self.explained,
               "explained_beyond_noise": self.explained_beyond_noise, "decisive": self.decisive,
               "evidence": dict(self.evidence), "add": self.add}
        if self.replaces:
            out["replaces"] = list(self.replaces)
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> Candidate:
        return cls(effect=document["effect"], side=Side(document["link"]), joints=tuple(document["joints"]),
                   decided_on=document.get("decided_on"), explained=document["explained"],
                   explained_beyond_noise=document["explained_beyond_noise"], decisive=document["decisive"],
                   evidence=document["evidence"], add=document["add"], replaces=tuple(document.get("replaces") or ()))


@dataclass(frozen=True)
class Diagnosis:
    """Which effect the model lacks on one side, or what kind of thing is left when none is.

    ``candidates``: ranked, the recommended one first; ``per_joint``: each joint's residual (x its floor) and the
    candidate that comes closest there; ``skipped``: the candidates not tried, each a :class:`Note` of why;
    ``notes``: what the verdict says beside its headline, in order; ``model_free``: the model-free ceiling's
    document (:func:`sim2real.identification.diagnosis.model_free_ceiling`), on a side judged against the motion;
    ``noise_rmse``, ``noise_floor_factor``, ``min_explained``: the figures the headline quotes; ``joints``: their
    order (:meth:`ordered`)."""

    side: Side
    status: Status
    candidates: tuple[Candidate, ...]
    confounded: tuple[tuple[str, str], ...]
    tied: tuple[str, ...]
    residual_rmse: float
    noise_floor_ratio: float | None
    noise_rmse: float
    noise_floor_factor: float
    min_explained: float
    per_joint: Mapping[str, Mapping[str, Any]]
    above_floor: tuple[str, ...]
    skipped: tuple[Note, ...] = ()
    failed: tuple[str, ...] = ()
    notes: tuple[Note, ...] = ()
    model_free: Mapping[str, Any] | None = field(default=None)
    joints: tuple[str, ...] = ()  # the joints in the robot's order (a document's mappings are sorted by name)

    @property
    def best(self) -> Candidate | None:
        """The candidate ranked first (the recommended one, when one is)."""
        return self.candidates[0] if self.candidates else None

    def candidate(self, effect: str) -> Candidate | None:
        return next((c for c in self.candidates if c.effect == effect), None)

    def ordered(self, per_joint: Mapping[str, Any]) -> dict[str, Any]:
        """``per_joint`` in the robot's joint order (a JSON document's keys are sorted by name)."""
        order = [j for j in self.joints if j in per_joint] or list(per_joint)
        return {j: per_joint[j] for j in order}

    def with_notes(self, *notes: Note | None) -> Diagnosis:
        """The same diagnosis with ``notes`` (None: none) said after its own."""
        added = tuple(n for n in notes if n is not None)
        return replace(self, notes=self.notes + added) if added else self

    def as_document(self) -> dict[str, Any]:
        """ladder.json's ``diagnosis``: plain JSON data, no words."""
        out: dict[str, Any] = {
            "link": str(self.side), "status": str(self.status),
            "candidates": [c.as_document() for c in self.candidates],
            "confounded": [list(pair) for pair in self.confounded], "tied": list(self.tied),
            "residual_rmse": self.residual_rmse, "noise_floor_ratio": self.noise_floor_ratio,
            "noise_rmse": self.noise_rmse, "noise_floor_factor": self.noise_floor_factor,
            "min_explained": self.min_explained,
            "per_joint": {j: dict(row) for j, row in self.per_joint.items()}, "above_floor": list(self.above_floor),
            "skipped": [n.as_document() for n in self.skipped], "failed": list(self.failed),
            "notes": [n.as_document() for n in self.notes], "joints": list(self.joints),
        }
        if self.model_free is not None:
            out["model_free"] = dict(self.model_free)
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> Diagnosis:
        return cls(
            side=Side(document["link"]), status=Status(document["status"]),
            candidates=tuple(Candidate.from_document(c) for c in document["candidates"]),
            confounded=tuple((a, b) for a, b in document["confounded"]), tied=tuple(document["tied"]),
            residual_rmse=document["residual_rmse"], noise_floor_ratio=document["noise_floor_ratio"],
            noise_rmse=document["noise_rmse"], noise_floor_factor=document["noise_floor_factor"],
            min_explained=document["min_explained"], per_joint=document["per_joint"],
            above_floor=tuple(document["above_floor"]),
            skipped=tuple(Note.from_document(n) for n in document["skipped"]), failed=tuple(document["failed"]),
            notes=tuple(Note.from_document(n) for n in document["notes"]), model_free=document.get("model_free"),
            joints=tuple(document.get("joints") or ()),
        )


def candidate_named(diagnosis: Diagnosis | None) -> Candidate | None:
    """The candidate a diagnosis asks to add (status ``add_effect``), or None."""
    if diagnosis is None or diagnosis.status != Status.ADD_EFFECT:
        return None
    return diagnosis.best

