"""Decisions with margins: a decision of the diagnosis (name a candidate, tell two apart, call a joint above its
floor) never hinges on the arithmetic's last digits.

Another CPU runs other BLAS kernels, so the fits behind every figure move legitimately by far more than a
float's last bit (an SDP solved to Clarabel's tolerances, a nonlinear refinement whose iterates depend on the order
of sums). ``benchmarks/bench_pinned_spread.py`` measures how far, across OpenBLAS kernel families, on the demo: a
joint's residual x its floor moved by up to 0.96 % of itself, a candidate's ``explained_beyond_noise`` by 0.0047,
its ``explained`` by 0.0003 (docs/performance.md). The margins below are about twice those. Each threshold is then
read both ways: with the margin against the decision (conservative) and with it for the decision (permissive).
Where the two readings differ, the figure sits within the arithmetic's precision of its threshold: the
conservative reading decides (a candidate is not named on it, a joint is not counted above its floor, two
candidates are tied) and the figures are kept (:class:`Near`), for the verdict to say so. On any CPU whose figures
differ by less than the margin, the decision is then the same.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim2real.identification.records import Note, NoteKind

# A share of a residual's energy (explained, explained beyond the noise floor, a joint's share of its excess):
# this much either side of its threshold, absolute.
SHARE_MARGIN = 0.01
# A multiple of a joint's floor (its residual, an effect's own term there): this share of the threshold either side.
X_FLOOR_MARGIN = 0.02
# Two candidates' paired difference over blocks of the holdout, in units of the tie's spread: this share of it.
TIE_MARGIN = 0.05

CONSERVATIVE, PERMISSIVE = 1.0, -1.0


@dataclass(frozen=True)
class Near:
    """A figure a decision read within the margin of its threshold: ``figure`` names it (``explained_beyond_noise``,
    ``explained``, ``joint_explained_beyond_noise``, ``own_term_x_floor``, ``x_floor``, ``tie``), ``joint`` where it
    is a joint's, its ``value``, the ``threshold`` and the ``margin`` either side."""

    figure: str
    value: float
    threshold: float
    margin: float
    joint: str | None = None

    def as_document(self) -> dict[str, Any]:
        out: dict[str, Any] = {"figure": self.figure, "value": round(float(self.value), 4),
                               "threshold": float(self.threshold), "margin": round(float(self.margin), 4)}
        if self.joint is not None:
            out["joint"] = self.joint
        return out


def within(value: float, threshold: float, margin: float) -> bool:
    """Whether ``value`` sits within ``margin`` of ``threshold`` (either side)."""
    return bool(abs(float(value) - float(threshold)) <= margin)


@dataclass(frozen=True)
class Decision:
    """A candidate's decision read one way (:data:`CONSERVATIVE` or :data:`PERMISSIVE`): arm-wide, and the joints it
    is named on."""

    arm_wide: bool
    on_joints: tuple[str, ...]

    @property
    def decisive(self) -> bool:
        return self.arm_wide or bool(self.on_joints)


def decide(scores: Mapping[str, Any], x_floor: np.ndarray, own: np.ndarray | None, joints: Sequence[str],
           limits: Mapping[str, float], own_term_min: float, way: float) -> Decision:
    """A candidate's decision from its ``scores`` (diagnosis.candidates._scores), the current residual per joint
    ``x_floor`` and its own term per joint ``own`` (x floor; None: seen everywhere), each threshold moved by its
    margin ``way`` (:data:`CONSERVATIVE`: against the decision, :data:`PERMISSIVE`: for it).

    Arm-wide: it removes ``min_explained`` of the excess above the floors and ``min_gain`` of the whole residual. On a
    joint above ``noise_floor_factor`` x its floor: it removes ``joint_decisive`` of that joint's excess, its own term
    shows there (``own_term_min``), it gains arm-wide and pushes no joint further above its floor."""
    arm_wide = (scores["beyond"] >= limits["min_explained"] + way * SHARE_MARGIN
                and scores["explained"] >= limits["min_gain"] + way * SHARE_MARGIN)
    if scores["gain"] <= 0 or any(scores["harmed"]):
        return Decision(arm_wide, ())
    above = limits["noise_floor_factor"] * (1.0 + way * X_FLOOR_MARGIN)
    seen = [True] * len(joints) if own is None else [bool(o >= own_term_min * (1.0 + way * X_FLOOR_MARGIN)) for o in own]
    on = [j for j, x, v, ok in zip(joints, x_floor, scores["per_joint_beyond"], seen, strict=True)
          if x > above and v >= limits["joint_decisive"] + way * SHARE_MARGIN and ok]
    return Decision(arm_wide, tuple(on))


def near_thresholds(scores: Mapping[str, Any], x_floor: np.ndarray, own: np.ndarray | None, joints: Sequence[str],
                    limits: Mapping[str, float], own_term_min: float) -> list[Near]:
    """The figures of a candidate whose decision the margins change (:func:`decide` read both ways), each within its
    margin of its threshold."""
    share = [("explained_beyond_noise", scores["beyond"], limits["min_explained"], None),
             ("explained", scores["explained"], limits["min_gain"], None)]
    share += [("joint_explained_beyond_noise", v, limits["joint_decisive"], j)
              for j, v in zip(joints, scores["per_joint_beyond"], strict=True)]
    out = [Near(f, v, t, SHARE_MARGIN, j) for f, v, t, j in share if within(v, t, SHARE_MARGIN)]
    factor = limits["noise_floor_factor"]
    out += [Near("x_floor", x, factor, factor * X_FLOOR_MARGIN, j) for j, x in zip(joints, x_floor, strict=True)
            if within(x, factor, factor * X_FLOOR_MARGIN)]
    if own is not None:
        out += [Near("own_term_x_floor", o, own_term_min, own_term_min * X_FLOOR_MARGIN, j)
                for j, o in zip(joints, own, strict=True) if within(o, own_term_min, own_term_min * X_FLOOR_MARGIN)]
    return out


def joints_near_floor(joints: Sequence[str], x_floor: np.ndarray, factor: float) -> list[Near]:
    """The joints whose residual sits within the margin of ``factor`` x its floor: counted within it (no candidate
    is named on them, and they do not keep the verdict from the floor)."""
    return [Near("x_floor", x, factor, factor * X_FLOOR_MARGIN, j) for j, x in zip(joints, x_floor, strict=True)
            if within(x, factor, factor * X_FLOOR_MARGIN)]


def above_floor(joints: Sequence[str], x_floor: np.ndarray, factor: float) -> list[str]:
    """The joints clearly above ``factor`` x their floor (by more than the margin)."""
    return [j for j, x in zip(joints, x_floor, strict=True) if x > factor * (1.0 + X_FLOOR_MARGIN)]


def tie_near(total: float, spread: float, tie_spread: float) -> bool:
    """Whether two candidates' paired difference ``total`` sits within the margin of the tie's bound
    (``tie_spread`` x ``spread``): tied, the conservative reading."""
    bound = tie_spread * spread
    return bound > 0 and within(abs(total), bound, TIE_MARGIN * bound)


def near_threshold_notes(candidates: Sequence[Mapping[str, Any]], group: Sequence[Mapping[str, Any]],
                         joints: Sequence[Near]) -> list[Note]:
    """The note of a diagnosis some of whose decisions took the conservative side: the candidates the margins kept
    from being named (their ``near_threshold`` evidence), those tied with the best only within the margin, and the
    joints counted within their floor (``joints``: :func:`joints_near_floor`)."""
    held_back = {str(c["effect"]): list(c["evidence"].near_threshold) for c in candidates
                 if c["evidence"].near_threshold}
    ties = [str(c["effect"]) for c in group if (c["evidence"].tie_with_best or {}).get("near_threshold")]
    if not (held_back or ties or joints):
        return []
    return [Note(NoteKind.NEAR_THRESHOLD, figures={"candidates": held_back, "ties": ties,
                                                    "joints": [n.as_document() for n in joints],
                                                    "tie_margin": TIE_MARGIN})]
