"""What a diagnosis returns: a :class:`Diagnosis`, typed data the report words (:mod:`sim2real.report.verdicts`).

Its document (:meth:`Diagnosis.as_document`, ladder.json's ``diagnosis``) holds the same data in JSON, read back by
:meth:`Diagnosis.from_document`; gap.json's ``diagnosis`` is that document with the words added. Each row of it is a
frozen dataclass that spells its own keys, here alone: a candidate's evidence (:class:`CandidateEvidence`), a joint's
standing (:class:`JointStanding`); the model-free ceiling's are :mod:`~sim2real.identification.diagnosis.
ceiling_records`'.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from sim2real.identification.diagnosis.ceiling_records import ModelFreeCeiling
from sim2real.identification.records import Note, Side, Status

# A sub-document whose layout another module owns (an effect's fitted values, a caveat's or a trial's figures), kept
# as the JSON data it is.
Figures = Mapping[str, object]


def _optional(document: Mapping[str, Any], key: str, kind: Any) -> Any:
    return kind(document[key]) if key in document else None


@dataclass(frozen=True)
class CandidateEvidence:
    """A trial's evidence: the effect's residual signature on the current holdout residual (``signature``, its
    ``statistic``, per joint, and for a lag the lag that best aligns the torques, ``lag_s``: None for another effect
    or without a measured torque; :meth:`sim2real.identification.effects.base.Effect.evidence`), what its fit removes
    (per joint, of the residual and of its excess above the floor), what is left (``rmse_after``, N*m; x the floor,
    arm-wide and per joint), the joints it pushes further above their floor, its own term per joint (x the floor;
    None for an effect without linear coefficients), its fitted values, coefficients and number of parameters, the
    bodies it leaves beyond plausible and the inertia bounds it pushes or releases; then what the diagnosis found of
    it (None where not: a failed solve, decisions near a threshold, a relabelling, its trades with the model, its
    tie with the best); for the recommended candidate whose rung chose the prior's weight again
    (:mod:`~sim2real.identification.diagnosis.promise`), the trial's figures after (``trial_after``) and the weight
    its rung chose (``rung_inertia_prior``); for a decisive candidate that raises joints beyond the noise
    (:mod:`~sim2real.identification.diagnosis.raises`), those joints (``raised``: before, after, x the floor) and its
    trial kept on the joints it helps where that trial did not do (``kept_to_trial``); for a candidate recommended on
    those joints, its trial on every joint (``arm_wide_trial``)."""

    signature: str
    statistic: str
    per_joint: Mapping[str, float]
    per_joint_explained: Mapping[str, float]
    per_joint_explained_beyond_noise: Mapping[str, float]
    rmse_after: float
    x_floor_after: float
    per_joint_x_floor_after: Mapping[str, float]
    harmed_joints: tuple[str, ...]
    fitted: Figures
    linear_coefficients: tuple[float, ...]
    nonlinear_coefficients: tuple[float, ...]
    parameters: int
    implausible_bodies: tuple[Figures, ...]
    bounds_pushed: Mapping[str, tuple[str, ...]]
    bounds_released: Mapping[str, tuple[str, ...]]
    lag_s: Mapping[str, float] | None = None
    per_joint_own_term_x_floor: Mapping[str, float] | None = None
    fit_failed: Figures | None = None
    near_threshold: tuple[Figures, ...] | None = None
    relabels: tuple[Figures, ...] | None = None
    trades_with: tuple[Figures, ...] | None = None
    tie_with_best: Figures | None = None
    trial_after: Figures | None = None
    rung_inertia_prior: float | None = None
    raised: Mapping[str, tuple[float, float]] | None = None
    kept_to_trial: Figures | None = None
    arm_wide_trial: Figures | None = None

    def as_document(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "signature": self.signature, "statistic": self.statistic, "per_joint": dict(self.per_joint),
            "per_joint_explained": dict(self.per_joint_explained),
            "per_joint_explained_beyond_noise": dict(self.per_joint_explained_beyond_noise),
            "rmse_after": self.rmse_after, "x_floor_after": self.x_floor_after,
            "per_joint_x_floor_after": dict(self.per_joint_x_floor_after),
            "harmed_joints": list(self.harmed_joints), "fitted": dict(self.fitted),
            "coefficients": {"linear": list(self.linear_coefficients), "nonlinear": list(self.nonlinear_coefficients)},
            "parameters": self.parameters, "implausible_bodies": [dict(b) for b in self.implausible_bodies],
            "bounds": {"pushes": {k: list(v) for k, v in self.bounds_pushed.items()},
                       "releases": {k: list(v) for k, v in self.bounds_released.items()}},
        }
        optional = {"lag_s": self.lag_s, "per_joint_own_term_x_floor": self.per_joint_own_term_x_floor,
                    "fit_failed": self.fit_failed, "tie_with_best": self.tie_with_best, "trial_after": self.trial_after,
                    "kept_to_trial": self.kept_to_trial, "arm_wide_trial": self.arm_wide_trial}
        out.update({key: dict(value) for key, value in optional.items() if value is not None})
        if self.rung_inertia_prior is not None:
            out["rung_inertia_prior"] = self.rung_inertia_prior
        if self.raised is not None:
            out["raised"] = {j: list(v) for j, v in self.raised.items()}
        listed = {"near_threshold": self.near_threshold, "relabels": self.relabels, "trades_with": self.trades_with}
        out.update({key: [dict(v) for v in value] for key, value in listed.items() if value is not None})
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> CandidateEvidence:
        bounds = document["bounds"]
        return cls(
            signature=document["signature"], statistic=document["statistic"], per_joint=document["per_joint"],
            per_joint_explained=document["per_joint_explained"],
            per_joint_explained_beyond_noise=document["per_joint_explained_beyond_noise"],
            rmse_after=document["rmse_after"], x_floor_after=document["x_floor_after"],
            per_joint_x_floor_after=document["per_joint_x_floor_after"],
            harmed_joints=tuple(document["harmed_joints"]), fitted=document["fitted"],
            linear_coefficients=tuple(document["coefficients"]["linear"]),
            nonlinear_coefficients=tuple(document["coefficients"]["nonlinear"]),
            parameters=document["parameters"], implausible_bodies=tuple(document["implausible_bodies"]),
            bounds_pushed={k: tuple(v) for k, v in bounds["pushes"].items()},
            bounds_released={k: tuple(v) for k, v in bounds["releases"].items()}, lag_s=document.get("lag_s"),
            per_joint_own_term_x_floor=document.get("per_joint_own_term_x_floor"),
            fit_failed=document.get("fit_failed"), near_threshold=_optional(document, "near_threshold", tuple),
            relabels=_optional(document, "relabels", tuple), trades_with=_optional(document, "trades_with", tuple),
            tie_with_best=document.get("tie_with_best"), trial_after=document.get("trial_after"),
            rung_inertia_prior=document.get("rung_inertia_prior"),
            raised={j: tuple(v) for j, v in document["raised"].items()} if "raised" in document else None,
            kept_to_trial=document.get("kept_to_trial"), arm_wide_trial=document.get("arm_wide_trial"))

    @property
    def bounds_pushed_net(self) -> int:
        """How many inertia bounds the fit pushes to, less those it releases."""
        return sum(len(v) for v in self.bounds_pushed.values()) - sum(len(v) for v in self.bounds_released.values())


@dataclass(frozen=True)
class JointStanding:
    """A joint's residual x its floor, the candidate that removes most of its excess there (None: none removes any)
    and what that one removes and leaves; ``judged``: false where the fit runs barely move the joint (its drives held
    at the nominal model's)."""

    x_floor: float
    closest: str | None
    closest_explained_beyond_noise: float
    closest_x_floor_after: float
    judged: bool = True

    def as_document(self) -> dict[str, Any]:
        out: dict[str, Any] = {"x_floor": self.x_floor, "closest": self.closest,
                               "closest_explained_beyond_noise": self.closest_explained_beyond_noise,
                               "closest_x_floor_after": self.closest_x_floor_after}
        if not self.judged:
            out["judged"] = False
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> JointStanding:
        return cls(x_floor=document["x_floor"], closest=document["closest"],
                   closest_explained_beyond_noise=document["closest_explained_beyond_noise"],
                   closest_x_floor_after=document["closest_x_floor_after"], judged=document.get("judged", True))


@dataclass(frozen=True)
class Candidate:
    """One effect tried on top of the current model, and what its trial showed.

    ``evidence``: its residual signature and the trial's figures (:class:`CandidateEvidence`)."""

    effect: str
    side: Side
    joints: tuple[str, ...]
    decided_on: str | None  # "arm", "joints", or None (not decisive)
    explained: float
    explained_beyond_noise: float
    decisive: bool
    evidence: CandidateEvidence
    add: str  # the line to add under ``effects:``
    replaces: tuple[str, ...] = ()  # lines of the model it holds, to be removed
    kept_to: tuple[str, ...] = ()  # the joints its line is kept on (empty: every joint; diagnosis.raises)

    def as_document(self) -> dict[str, Any]:
        out = {"effect": self.effect, "link": str(self.side), "joints": list(self.joints),
               "decided_on": self.decided_on, "explained": self.explained,
               "explained_beyond_noise": self.explained_beyond_noise, "decisive": self.decisive,
               "evidence": self.evidence.as_document(), "add": self.add}
        if self.replaces:
            out["replaces"] = list(self.replaces)
        if self.kept_to:
            out["kept_to"] = list(self.kept_to)
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> Candidate:
        return cls(effect=document["effect"], side=Side(document["link"]), joints=tuple(document["joints"]),
                   decided_on=document.get("decided_on"), explained=document["explained"],
                   explained_beyond_noise=document["explained_beyond_noise"], decisive=document["decisive"],
                   evidence=CandidateEvidence.from_document(document["evidence"]), add=document["add"],
                   replaces=tuple(document.get("replaces") or ()), kept_to=tuple(document.get("kept_to") or ()))


@dataclass(frozen=True)
class Diagnosis:
    """Which effect the model lacks on one side, or what kind of thing is left when none is.

    ``candidates``: ranked, the recommended one first; ``per_joint``: each joint's standing (:class:`JointStanding`); ``skipped``: the candidates not tried, each a :class:`Note` of why;
    ``notes``: what the verdict says beside its headline, in order; ``model_free``: the model-free ceiling
    (:class:`ModelFreeCeiling`), on a side judged against the motion;
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
    per_joint: Mapping[str, JointStanding]
    above_floor: tuple[str, ...]
    skipped: tuple[Note, ...] = ()
    failed: tuple[str, ...] = ()
    notes: tuple[Note, ...] = ()
    model_free: ModelFreeCeiling | None = field(default=None)
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
            "per_joint": {j: row.as_document() for j, row in self.per_joint.items()}, "above_floor": list(self.above_floor),
            "skipped": [n.as_document() for n in self.skipped], "failed": list(self.failed),
            "notes": [n.as_document() for n in self.notes], "joints": list(self.joints),
        }
        if self.model_free is not None:
            out["model_free"] = self.model_free.as_document()
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> Diagnosis:
        return cls(
            side=Side(document["link"]), status=Status(document["status"]),
            candidates=tuple(Candidate.from_document(c) for c in document["candidates"]),
            confounded=tuple((a, b) for a, b in document["confounded"]), tied=tuple(document["tied"]),
            residual_rmse=document["residual_rmse"], noise_floor_ratio=document["noise_floor_ratio"],
            noise_rmse=document["noise_rmse"], noise_floor_factor=document["noise_floor_factor"],
            min_explained=document["min_explained"],
            per_joint={j: JointStanding.from_document(row) for j, row in document["per_joint"].items()},
            above_floor=tuple(document["above_floor"]),
            skipped=tuple(Note.from_document(n) for n in document["skipped"]), failed=tuple(document["failed"]),
            notes=tuple(Note.from_document(n) for n in document["notes"]), model_free=_optional(document, "model_free", ModelFreeCeiling.from_document),
            joints=tuple(document.get("joints") or ()),
        )


def candidate_named(diagnosis: Diagnosis | None) -> Candidate | None:
    """The candidate a diagnosis asks to add (status ``add_effect``), or None."""
    if diagnosis is None or diagnosis.status != Status.ADD_EFFECT:
        return None
    return diagnosis.best

