"""The identification's vocabulary as types: the two sides of a joint's torque, where a torque sensor sits, what a
diagnosis concludes, and its notes as records. Words are the report's (:mod:`sim2real.report.verdicts`); the
documents keep the keys users know (``gap.json["actuator"]``, ``torque_sensor: link``, ``- asymmetric_friction:
actuator``), which the values of these enums are.

* :class:`Side`: the split of the comparison. ``BODY``: the applied torque against the motion (the rigid body and
  what acts after the sensor); ``DRIVE``: the measured torque against the commanded one (command -> applied torque);
  ``COMBINED``: both at once, on runs without a torque sensor (the command against the motion).
* :class:`SensorPlacement` (defined with the runs' metadata, :mod:`sim2real.measurements.records`): where a joint
  torque sensor measures, ``LINK_SIDE`` (after the gearbox: the Panda's tau_J)
  or ``MOTOR_SIDE`` (a motor-current estimate, before the rotor inertia and the joint friction).
* :class:`Status`: what a diagnosis concludes.
* :class:`Note`: a fact a verdict, a rung or a skipped trial states, as data: its :class:`NoteKind`, the effect and
  the side it concerns, the joints, and the figures its words quote.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from sim2real.measurements.records import SensorPlacement

__all__ = ["Note", "NoteKind", "SensorPlacement", "Side", "Status"]


class Side(enum.StrEnum):
    """The split of a joint's torque that a ladder and its diagnosis judge (values: the documents' words)."""

    BODY = "body"
    DRIVE = "actuator"
    COMBINED = "combined"


class Status(enum.StrEnum):
    """What a diagnosis concludes."""

    ADD_EFFECT = "add_effect"  # a decisive candidate, recommended: its line is to be added
    NOT_TOLD_APART = "not_told_apart"  # decisive candidates tied, none keeps the model plausible: no line
    AT_NOISE_FLOOR = "at_noise_floor"  # every joint within the floor factor of its floor, nothing decisive
    UNEXPLAINED = "unexplained"  # joints above their floor that no candidate explains


class NoteKind(enum.StrEnum):
    """The facts notes state. Verdict notes first (in the order a verdict says them), then the skipped trials'
    reasons, then a rung's."""

    # the verdict's, within one side
    LAG_SHAPES = "lag_shapes"  # the named lag does as well in another shape (figures: shapes, lowpass)
    CONFOUNDED = "confounded"  # the named effect predicts what others do (figures: twins)
    TIED = "tied"  # ties with the best, the one recommended (figures: others, best_first, best)
    CAUTION = "caution"  # what the named candidate's fit does that makes it less trustworthy (figures: troubles)
    FAILED_TRIALS = "failed_trials"  # trials that did not solve (figures: failed)
    # decisions that take the conservative side (sim2real.identification.diagnosis.margins, caveats.relabelling)
    RELABELLED = "relabelled"  # candidates whose term is the model's own relabelled (figures: relabelled)
    NEAR_THRESHOLD = "near_threshold"  # figures within the arithmetic's margin (figures: candidates, joints, ties)
    RAISES = "raises"  # candidates that raise a joint beyond the noise, kept to some joints or withheld (candidates)
    # the verdict's, across the two sides (sim2real.identification.diagnosis.across)
    DRIVE_PLACEMENT = "drive_placement"  # a drive effect found where the sensor's placement did not expect it
    SENSOR_LAG = "sensor_lag"  # the body side finds the sensor's lag in the drive side's (figures: lag_s, effects)
    SENSOR_LAG_TRIAL = "sensor_lag_trial"  # the body side's trial says whose lag it is (figures: found_s, own_s, ...)
    OTHER_SIDE = "other_side"  # the line sits on the other side too, which it leaves worse (figures: worse, ...)
    HELD_ON_OTHER_SIDE = "held_on_other_side"  # the other side holds it already in a line kept there (figures: holder)
    # why a candidate was not tried
    PER_RUN = "per_run"
    NESTED = "nested"  # figures: holder
    DRIVE_BEHIND_SENSOR = "drive_behind_sensor"  # a command's effect, and the judged torque is a sensor's
    SENSOR_ON_COMMANDS = "sensor_on_commands"  # a sensor's error, and the judged torque is the command
    LAG_SCREENED = "lag_screened"  # figures: lead, delay_s, share
    OTHER_SHAPE = "other_shape"  # figures: other, share
    RIPPLE_AT_FLOOR = "ripple_at_floor"
    RIPPLE_SCREENED = "ripple_screened"  # figures: share, joint_share, joint
    # a rung's
    NONLINEAR_HELD = "nonlinear_held"
    DELAY_NOT_SEEN = "delay_not_seen"  # figures: torque_source
    CONSISTENCY_INFEASIBLE = "consistency_infeasible"  # figures: reason
    CONSISTENCY_CONTRADICTED = "consistency_contradicted"  # figures: violations, free_rmse, physical_rmse


@dataclass(frozen=True)
class Note:
    """A fact, as data: what :mod:`sim2real.report.verdicts` words."""

    kind: NoteKind
    effect: str | None = None
    side: Side | None = None
    joints: tuple[str, ...] = ()
    figures: Mapping[str, Any] = field(default_factory=dict)

    def as_document(self) -> dict[str, Any]:
        """The note in a JSON document (ladder.json)."""
        out: dict[str, Any] = {"kind": str(self.kind)}
        if self.effect is not None:
            out["effect"] = self.effect
        if self.side is not None:
            out["side"] = str(self.side)
        if self.joints:
            out["joints"] = list(self.joints)
        if self.figures:
            out["figures"] = dict(self.figures)
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> Note:
        return cls(kind=NoteKind(document["kind"]), effect=document.get("effect"),
                   side=Side(document["side"]) if document.get("side") is not None else None,
                   joints=tuple(document.get("joints") or ()), figures=dict(document.get("figures") or {}))
