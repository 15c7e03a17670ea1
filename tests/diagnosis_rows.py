"""A diagnosis's rows as a test makes them: a candidate's evidence with the figures a test sets, the rest of a plain
trial (nothing implausible, no bound pushed, no trade)."""

from __future__ import annotations

from typing import Any

from sim2real.identification.diagnosis.result import CandidateEvidence


def evidence(joints: tuple[str, ...] = ("panda_joint1",), **figures: Any) -> CandidateEvidence:
    """A candidate's evidence on ``joints``; ``figures``: its fields a test sets (``x_floor_after``, ``fitted`` ...)."""
    zero = dict.fromkeys(joints, 0.0)
    plain: dict[str, Any] = dict(
        signature="correlation with qd", statistic="correlation", per_joint=zero, per_joint_explained=zero,
        per_joint_explained_beyond_noise=zero, rmse_after=0.1, x_floor_after=1.0, per_joint_x_floor_after=zero,
        harmed_joints=(), fitted={}, linear_coefficients=(), nonlinear_coefficients=(), parameters=1,
        implausible_bodies=(), bounds_pushed={}, bounds_released={})
    return CandidateEvidence(**{**plain, **figures})


def evidence_document(joints: tuple[str, ...] = ("panda_joint1",), **figures: Any) -> dict[str, Any]:
    """:func:`evidence` as ladder.json holds it."""
    return evidence(joints, **figures).as_document()
