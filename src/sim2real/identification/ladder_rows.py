"""A rung of ``ladder.json`` as a typed row: :class:`Rung` (its effects, parameters, intervals, what it says of its
fit) and :class:`RungMetrics` (its figures on the holdout runs). Each key of a rung is written (``as_document``) and
read (``from_document``) here alone: the sysid rule writes its rungs through them
(:mod:`sim2real.identification.side_ladder`), and the gap report, the pull-request comment and the fleet read their
attributes. gap.json carries the same rungs, each with its replay's ``position_rmse`` and its notes in words.

A figure over the joints keeps the shape of :func:`sim2real.stats.rmse` (``overall`` and ``per_joint``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

Figures = Mapping[str, Any]  # {"overall": x, "per_joint": {joint: x}} (sim2real.stats.rmse)


@dataclass(frozen=True)
class RungMetrics:
    """A rung's figures: its holdout torque RMSE (``torque_rmse``), the same on the fit runs (``fit_torque_rmse``),
    its headline, each joint in units of its own noise floor (``torque_x_floor``), the same rung's holdout RMSE
    without the physical constraints (``unconstrained_torque_rmse``, where it is constrained), and its replay's
    position RMSE (``position_rmse``, the gap report's). None: not computed for this rung."""

    torque_rmse: Figures
    fit_torque_rmse: Figures | None = None
    torque_x_floor: Figures | None = None
    unconstrained_torque_rmse: Figures | None = None
    position_rmse: Figures | None = None

    def as_document(self) -> dict[str, Any]:
        out: dict[str, Any] = {"torque_rmse": self.torque_rmse}
        optional = {"fit_torque_rmse": self.fit_torque_rmse, "torque_x_floor": self.torque_x_floor,
                    "unconstrained_torque_rmse": self.unconstrained_torque_rmse, "position_rmse": self.position_rmse}
        out.update({key: value for key, value in optional.items() if value is not None})
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> RungMetrics:
        """The metrics of a rung's document (a part missing, as in a hand-made ladder: empty, or None)."""
        return cls(torque_rmse=document.get("torque_rmse") or {}, fit_torque_rmse=document.get("fit_torque_rmse"),
                   torque_x_floor=document.get("torque_x_floor"),
                   unconstrained_torque_rmse=document.get("unconstrained_torque_rmse"),
                   position_rmse=document.get("position_rmse"))


@dataclass(frozen=True)
class Rung:
    """One rung of a side's ladder: its effects (none: the nominal model), their fitted values (``params``) and
    intervals, its :class:`RungMetrics`, its physical-consistency record (``consistency``, where it is constrained:
    the inertial prior's weight and how it was chosen, whether the unconstrained fit is physical) and its notes (a
    :class:`~sim2real.identification.records.Note`'s document each; in gap.json, their words). None: not in the
    document (the sysid rule writes ``params`` and ``intervals`` always; a hand-made ladder may leave them out)."""

    effects: tuple[str, ...]
    metrics: RungMetrics
    params: Mapping[str, Any] | None = None
    intervals: Mapping[str, Any] | None = None
    consistency: Mapping[str, Any] | None = None
    notes: tuple[Any, ...] = ()

    @property
    def values(self) -> Mapping[str, Any]:
        """Each effect's fitted values (``params``; none for the nominal model)."""
        return self.params or {}

    @property
    def inertia_prior(self) -> Mapping[str, Any] | None:
        """The inertial prior's record (its weight, how it was chosen), None where the rung has none."""
        return (self.consistency or {}).get("inertia_prior")

    def with_position(self, position: Figures) -> Rung:
        """The rung with its replay's position RMSE."""
        return replace(self, metrics=replace(self.metrics, position_rmse=position))

    def as_document(self) -> dict[str, Any]:
        out: dict[str, Any] = {"effects": list(self.effects), "metrics": self.metrics.as_document()}
        optional = {"params": self.params, "intervals": self.intervals, "consistency": self.consistency}
        out.update({key: value for key, value in optional.items() if value is not None})
        if self.notes:
            out["notes"] = list(self.notes)
        return out

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> Rung:
        """The rung of a document (ladder.json's, gap.json's with its words; a part missing: empty, or None)."""
        return cls(effects=tuple(document.get("effects") or ()),
                   metrics=RungMetrics.from_document(document.get("metrics") or {}),
                   params=document.get("params"), intervals=document.get("intervals"),
                   consistency=document.get("consistency"), notes=tuple(document.get("notes") or ()))


def rungs_of(documents: Sequence[Mapping[str, Any]] | None) -> list[Rung]:
    """A side's rungs (``ladder.json``'s or gap.json's ``ladder``) as rows; none for a side without a ladder."""
    return [Rung.from_document(document) for document in documents or ()]


@dataclass(frozen=True)
class SideRows:
    """One side's part of ``ladder.json`` as read back: its rungs, its noise floor's torque RMSE (over the arm and per
    joint) and its diagnosis's document (None: not diagnosed)."""

    rungs: tuple[Rung, ...]
    floor: Figures
    diagnosis: Mapping[str, Any] | None = None

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> SideRows:
        floor = (document.get("noise_floor") or {}).get("torque_rmse") or {}
        return cls(tuple(rungs_of(document.get("ladder"))), floor, document.get("diagnosis"))


@dataclass(frozen=True)
class LadderDocument:
    """``ladder.json`` as its readers take it: the robot, the judged torque (``torque_source``: ``tau`` or
    ``tau_cmd``), the body side's rows, the actuator side's (None on runs that judge one side) and what the runs can
    tell apart (``links``). None: not in the document."""

    robot: str | None
    torque_source: str | None
    body: SideRows
    actuator: SideRows | None = None
    links: Mapping[str, Any] | None = None

    @classmethod
    def from_document(cls, document: Mapping[str, Any]) -> LadderDocument:
        actuator = document.get("actuator")
        return cls(robot=document.get("robot"), torque_source=document.get("torque_source"),
                   body=SideRows.from_document(document),
                   actuator=SideRows.from_document(actuator) if actuator else None, links=document.get("links"))
