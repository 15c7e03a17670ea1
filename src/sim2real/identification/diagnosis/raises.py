"""No rung raises a joint: a candidate is named only if, joint by joint, it raises none beyond what the noise floor
and the holdout's blocks can resolve (:func:`raised_joints`).

A candidate that lowers the arm as a whole but raises one joint is no rung the loop can promise: the user who adds its
line would see that joint get worse. Such a candidate is set aside (:func:`set_aside_raisers`): it stays in the
ranking with its figures, no longer decisive, so the ranking and the ``add`` line go to the best candidate that raises
no joint (or to none), and the verdict says which joints the set-aside one lowers and which it raises
(:data:`~sim2real.identification.records.NoteKind.RAISES_JOINTS`). model.yaml has no line that keeps an effect on
some joints only, so the one it would help cannot be kept there: it is recommended not at all.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.identification.diagnosis.caveats import TIE_BLOCKS, TIE_SPREAD
from sim2real.identification.diagnosis.current import CurrentResidual
from sim2real.identification.records import Note, NoteKind

# A joint's holdout residual may rise by this much (RMS, x its floor) before the rise is a joint made worse: less is
# no difference the floor can tell.
RAISE_TOLERANCE = 0.1


def raised_joints(after: np.ndarray, now: CurrentResidual, joints: Sequence[str]) -> dict[str, dict[str, float]]:
    """The joints a candidate's holdout residual ``after`` (floor units, as :attr:`CurrentResidual.scaled`) raises
    beyond the noise: by more than :data:`RAISE_TOLERANCE` x its floor, and by more than :data:`TIE_SPREAD` standard
    errors of the paired difference of squared residuals over contiguous blocks of the holdout (the blocks'
    bootstrap the ties use). ``{joint: {"from": x, "to": x}}`` in floor units."""
    rows = now.rows
    blocks = max(2, min(TIE_BLOCKS, rows // 50))
    difference = np.array([np.sum(a**2 - b**2, axis=0)
                           for a, b in zip(np.array_split(after, blocks), np.array_split(now.scaled, blocks), strict=True)])
    total = difference.sum(axis=0)
    spread = np.sqrt(blocks) * difference.std(axis=0, ddof=1)
    x_after = np.sqrt(np.sum(after**2, axis=0) / max(rows, 1))
    return {j: {"from": round(float(a), 3), "to": round(float(b), 3)}
            for j, a, b, t, s in zip(joints, now.x_floor, x_after, total, spread, strict=True)
            if b - a > RAISE_TOLERANCE and t > TIE_SPREAD * s}


def set_aside_raisers(candidates: list[dict[str, Any]], residuals: Mapping[str, np.ndarray], now: CurrentResidual,
                      joints: Sequence[str]) -> list[Note]:
    """Each decisive candidate that raises a joint (:func:`raised_joints`) made not decisive, in place, its raised
    joints in its evidence (``raised_joints``); the note of the one that explains most of them (which joints it
    lowers and which it raises), or none."""
    set_aside = []
    for candidate in candidates:
        scaled = residuals.get(candidate["effect"])
        if scaled is None or not candidate["decisive"]:
            continue
        raised = raised_joints(scaled, now, joints)
        if raised:
            candidate["evidence"]["raised_joints"] = raised
            candidate.update(decisive=False, decided_on=None, joints=[])
            set_aside.append(candidate)
    if not set_aside:
        return []
    first = max(set_aside, key=lambda c: (c["explained"], c["effect"]))
    after = first["evidence"]["per_joint_x_floor_after"]
    lowered = {j: {"from": round(float(x), 3), "to": after[j]} for j, x in zip(joints, now.x_floor, strict=True)
               if after[j] < x - RAISE_TOLERANCE}
    return [Note(NoteKind.RAISES_JOINTS, effect=first["effect"],
                 figures={"lowers": lowered, "raises": first["evidence"]["raised_joints"],
                          "explained": first["explained"]})]


def raise_notes(notes: Sequence[Note], best: Mapping[str, Any] | None) -> list[Note]:
    """The set-aside candidate's note where it would have been named: it explains more than the candidate named
    instead (or nothing is named)."""
    if best is None or not best["decisive"]:
        return list(notes)
    return [n for n in notes if n.figures["explained"] > best["explained"]]
