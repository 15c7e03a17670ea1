"""gap.json's top level as a typed record: :class:`GapReport` writes each of its keys (``as_document``) and reads them
(``from_document``) here alone, and so does :class:`LinkSection` for the actuator link's part. The report builds one
(:mod:`sim2real.report.gap`); gap.md, its first screen, the figures and the pull-request comment
(:mod:`sim2real.report.gapdiff`) read its attributes. The sections below the top level keep their documents: a rung is
:class:`~sim2real.identification.ladder_rows.Rung`, a diagnosis is read by
:class:`~sim2real.identification.diagnosis.Diagnosis`.

A report read back from a file may come from an older build, or be only part of one: every key but ``robot`` may be
missing, and reads as None (or empty).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from sim2real.identification.ladder_rows import Rung, rungs_of

# The sections gap.json takes from ladder.json, in words.
LADDER_SECTIONS = ("ladder", "diagnosis", "actuator", "links")


def nominal_section(metrics: Mapping[str, Any], where: Mapping[str, Any]) -> dict[str, Any]:
    """gap.json's ``nominal``: the nominal URDF's torque metrics and where it fails, once a ladder calibrates the
    model (:attr:`GapReport.nominal_metrics`, :attr:`GapReport.nominal_where`)."""
    return {"metrics": metrics, "where": where}


@dataclass(frozen=True)
class LinkSection:
    """The actuator link's part of gap.json (``actuator``): what it judges in words (``judged``), its rungs, its noise
    floor (its ``torque_rmse``, over the arm and per joint) and its diagnosis's section."""

    ladder: tuple[Rung, ...]
    noise_floor: Mapping[str, Any]
    judged: str | None = None
    diagnosis: Mapping[str, Any] | None = None

    @property
    def floor(self) -> Mapping[str, Any]:
        """The link's noise floor's torque RMSE, over the arm and per joint."""
        return self.noise_floor.get("torque_rmse") or {}

    def as_document(self) -> dict[str, Any]:
        out: dict[str, Any] = {"ladder": [rung.as_document() for rung in self.ladder], "noise_floor": self.noise_floor}
        optional = {"judged": self.judged, "diagnosis": self.diagnosis}
        out.update({key: value for key, value in optional.items() if value is not None})
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> LinkSection:
        return cls(ladder=tuple(rungs_of(document.get("ladder"))), noise_floor=document.get("noise_floor") or {},
                   judged=document.get("judged"), diagnosis=document.get("diagnosis"))


@dataclass(frozen=True)
class GapReport:
    """gap.json's top level: the robot and its joints, the arm-wide noise floor, the joints not judged, the runs, the
    judged model's torque metrics (with its state domain) and where it fails, the nominal URDF's (``nominal``, once a
    ladder calibrates the model), and the ladder's sections in words (the body link's rungs and diagnosis, the
    actuator link's part, what the runs can tell apart). None: not known (yet, or in this report)."""

    robot: str
    joints: tuple[str, ...] = ()
    noise_floor: Mapping[str, Any] | None = None
    not_judged: Mapping[str, Any] | None = None
    runs: tuple[Mapping[str, Any], ...] | None = None
    metrics: Mapping[str, Any] | None = None
    where: Mapping[str, Any] | None = None
    nominal: Mapping[str, Any] | None = None
    ladder: tuple[Rung, ...] | None = None
    diagnosis: Mapping[str, Any] | None = None
    actuator: LinkSection | None = None
    links: Mapping[str, Any] | None = None

    @property
    def model(self) -> Mapping[str, Any] | None:
        """The judged model (``metrics.model``: its rung and effects), None where it is the nominal URDF."""
        return (self.metrics or {}).get("model")

    @property
    def floor(self) -> Mapping[str, Any]:
        """The arm-wide noise floor's torque RMSE, over the arm and per joint (empty where the report has none)."""
        return (self.noise_floor or {}).get("torque_rmse") or {}

    @property
    def nominal_metrics(self) -> Mapping[str, Any] | None:
        """The nominal URDF's torque metrics where the report judges a calibrated model; None otherwise."""
        return (self.nominal or {}).get("metrics")

    @property
    def nominal_where(self) -> Mapping[str, Any] | None:
        """Where the nominal URDF fails, where the report judges a calibrated model; None otherwise."""
        return (self.nominal or {}).get("where")

    def as_document(self) -> dict[str, Any]:
        out: dict[str, Any] = {"robot": self.robot, "joints": list(self.joints)}
        optional = {"noise_floor": self.noise_floor, "not_judged": self.not_judged, "metrics": self.metrics,
                    "where": self.where, "nominal": self.nominal, "diagnosis": self.diagnosis, "links": self.links}
        out.update({key: value for key, value in optional.items() if value is not None})
        if self.runs is not None:
            out["runs"] = list(self.runs)
        if self.ladder is not None:
            out["ladder"] = [rung.as_document() for rung in self.ladder]
        if self.actuator is not None:
            out["actuator"] = self.actuator.as_document()
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> GapReport:
        runs, ladder, actuator = document.get("runs"), document.get("ladder"), document.get("actuator")
        return cls(robot=document["robot"], joints=tuple(document.get("joints") or ()),
                   noise_floor=document.get("noise_floor"), not_judged=document.get("not_judged"),
                   runs=tuple(runs) if runs is not None else None, metrics=document.get("metrics"),
                   where=document.get("where"), nominal=document.get("nominal"),
                   ladder=tuple(rungs_of(ladder)) if ladder is not None else None,
                   diagnosis=document.get("diagnosis"),
                   actuator=LinkSection.from_document(actuator) if actuator else None, links=document.get("links"))

    def with_ladder(self, sections: Mapping[str, Any]) -> GapReport:
        """The report with ladder.json's sections in words (:func:`sim2real.report.verdicts.worded`): the body
        link's rungs and diagnosis, the actuator link's part, what the runs can tell apart."""
        plain = json.loads(json.dumps({key: sections[key] for key in LADDER_SECTIONS if key in sections}))
        return replace(self, ladder=tuple(rungs_of(plain["ladder"])) if "ladder" in plain else None,
                       diagnosis=plain.get("diagnosis"), links=plain.get("links"),
                       actuator=LinkSection.from_document(plain["actuator"]) if plain.get("actuator") else None)

    @classmethod
    def of(cls, report: GapReport | Mapping[str, Any]) -> GapReport:
        """``report`` as a :class:`GapReport` (gap.json's content is read with :meth:`from_document`)."""
        return report if isinstance(report, GapReport) else cls.from_document(report)
