"""The model-free ceiling's records (:class:`ModelFreeCeiling`, gap.json's and ladder.json's ``model_free``): its
reading of each joint (:class:`CeilingReading`) and the lines it advises (:class:`EffectAdvice`), each a frozen
dataclass that spells its own keys, read back by ``from_document``."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


def _optional(document: Mapping[str, Any], key: str, kind: Any) -> Any:
    return kind(document[key]) if key in document else None


@dataclass(frozen=True)
class CeilingReading:
    """What the model-free ceiling reads on one joint (:func:`sim2real.identification.diagnosis.model_free_ceiling`):
    the rung's holdout RMS and the learner's (N*m, and x the floor), their ratio and the share of the excess the
    learner removes; ``kind``: ``at_floor`` (no learner fitted), ``motion`` or ``not_motion``. A fitted joint names
    its ``learner``; on the motion, the features it gains most with, the regime it gains most in (None: none) and the
    library's effect that carries it (``effect``, or None); where a drift of each run's own removes as much
    (``beyond_motion``: each kind's share), what it ``follows`` (None: none) and, on the motion, whether the learner
    only ``imitated`` it."""

    rung_rmse: float
    ceiling_rmse: float
    rung_x_floor: float
    ceiling_x_floor: float
    ratio: float
    explained_beyond_noise: float
    kind: str
    fitted: bool
    learner: str | None = None
    gains_most_with: tuple[Figures | str, ...] | None = None
    gains_most_in: str | None = None
    effect: str | None = None
    beyond_motion: Mapping[str, float] | None = None
    follows: str | None = None
    imitated: bool | None = None

    def as_document(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "rung_rmse": self.rung_rmse, "ceiling_rmse": self.ceiling_rmse, "rung_x_floor": self.rung_x_floor,
            "ceiling_x_floor": self.ceiling_x_floor, "ratio": self.ratio,
            "explained_beyond_noise": self.explained_beyond_noise, "kind": self.kind, "fitted": self.fitted}
        if self.learner is not None:
            out["learner"] = self.learner
        if self.gains_most_with is not None:  # a joint on the motion: its features and regime (None: none)
            out["gains_most_with"] = [f if isinstance(f, str) else dict(f) for f in self.gains_most_with]
            out["gains_most_in"] = self.gains_most_in
        if self.effect is not None:
            out["effect"] = self.effect
        if self.beyond_motion is not None:  # a drift weighed: what it follows (None: none)
            out["beyond_motion"] = dict(self.beyond_motion)
            out["follows"] = self.follows
        if self.imitated is not None:
            out["imitated"] = self.imitated
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> CeilingReading:
        return cls(rung_rmse=document["rung_rmse"], ceiling_rmse=document["ceiling_rmse"],
                   rung_x_floor=document["rung_x_floor"], ceiling_x_floor=document["ceiling_x_floor"],
                   ratio=document["ratio"], explained_beyond_noise=document["explained_beyond_noise"],
                   kind=document["kind"], fitted=document["fitted"], learner=document.get("learner"),
                   gains_most_with=_optional(document, "gains_most_with", tuple),
                   gains_most_in=document.get("gains_most_in"), effect=document.get("effect"),
                   beyond_motion=document.get("beyond_motion"), follows=document.get("follows"),
                   imitated=document.get("imitated"))


@dataclass(frozen=True)
class EffectAdvice:
    """An effect the ceiling advises adding (its ``line`` under ``effects:`` in model.yaml) for ``joints``. Where its
    rung, the line written for every joint, raises joints beyond the noise (``raised``: (before, after) x the floor;
    :func:`sim2real.identification.diagnosis.raises.rung_raises`), the line is kept on the joints it helps
    (``kept_to``), or the advice is withheld."""

    effect: str
    joints: tuple[str, ...]
    line: str
    kept_to: tuple[str, ...] = ()
    raised: Mapping[str, tuple[float, float]] | None = None

    def as_document(self) -> dict[str, Any]:
        out: dict[str, Any] = {"effect": self.effect, "joints": list(self.joints), "line": self.line}
        if self.kept_to:
            out["kept_to"] = list(self.kept_to)
        if self.raised:
            out["raised"] = {j: list(v) for j, v in self.raised.items()}
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> EffectAdvice:
        return cls(effect=document["effect"], joints=tuple(document["joints"]), line=document["line"],
                   kept_to=tuple(document.get("kept_to") or ()),
                   raised={j: (v[0], v[1]) for j, v in document["raised"].items()} if "raised" in document else None)


@dataclass(frozen=True)
class ModelFreeCeiling:
    """The model-free ceiling of a side judged against the motion: its learners (``learner``, their description),
    the holdout RMS after them (overall and per joint, N*m), the share of the rung a learner must come under to count
    (``close_to_rung``), each joint's reading, and the drift to declare (``declare``) and the mount the pose points to
    (``points_to``), each None when none; a drift the runs' offsets call for but whose rung raises joints on every
    line tried (``withheld``: not declared, and why)."""

    learner: str
    torque_rmse_overall: float
    torque_rmse_per_joint: Mapping[str, float]
    close_to_rung: float
    per_joint: Mapping[str, CeilingReading]
    declare: EffectAdvice | None = None
    points_to: EffectAdvice | None = None
    withheld: EffectAdvice | None = None

    def ordered(self, joints: Sequence[str] = ()) -> dict[str, CeilingReading]:
        """Each joint's reading in ``joints``' order (default, or none of them read: the document's)."""
        order = [j for j in joints if j in self.per_joint] or list(self.per_joint)
        return {j: self.per_joint[j] for j in order}

    def as_document(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "learner": self.learner,
            "torque_rmse": {"overall": self.torque_rmse_overall, "per_joint": dict(self.torque_rmse_per_joint)},
            "close_to_rung": self.close_to_rung,
            "per_joint": {j: row.as_document() for j, row in self.per_joint.items()}}
        if self.declare is not None:
            out["declare"] = self.declare.as_document()
        if self.points_to is not None:
            out["points_to"] = self.points_to.as_document()
        if self.withheld is not None:
            out["withheld"] = self.withheld.as_document()
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> ModelFreeCeiling:
        return cls(learner=document["learner"], torque_rmse_overall=document["torque_rmse"]["overall"],
                   torque_rmse_per_joint=document["torque_rmse"]["per_joint"],
                   close_to_rung=document["close_to_rung"],
                   per_joint={j: CeilingReading.from_document(row) for j, row in document["per_joint"].items()},
                   declare=_optional(document, "declare", EffectAdvice.from_document),
                   points_to=_optional(document, "points_to", EffectAdvice.from_document),
                   withheld=_optional(document, "withheld", EffectAdvice.from_document))
