"""A solver's status judged by what it means: the residuals of the solution it returns, measured here.

Clarabel ends a solve "Solved" when its scaled residuals meet its tolerances, and "AlmostSolved" when they meet only
its reduced ones (it stalled on the way: the last digits of its factorisations differ by CPU, so one CPU's "Solved"
is another's "AlmostSolved" on the same program). Neither word is taken on trust for the solution a rung keeps:
:func:`measure` computes, on the unscaled program, the primal residual ``||A x + s - b||``, the dual residual
``||P x + q + A' z||`` (both infinity norms, relative as Clarabel's are) and the relative duality gap, and
:func:`judge` keeps an "almost solved" solution only when those meet :data:`ACCEPTED` (Clarabel's own default
tolerances), else polishes it (solves again at the default tolerances, a milder path than the precise solve's that
stalled) and keeps whichever solution measures better, saying so (:class:`SolveCheck`). A solution that no attempt
brings within :data:`ACCEPTED` is kept as "optimal_inaccurate", with its residuals stated.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

# Clarabel's default tolerances (tol_feas, tol_gap_rel): a solution measured within them is solved, whatever the
# status of the (tighter) solve that produced it.
ACCEPTED = 1e-8


@dataclass(frozen=True)
class Residuals:
    """A conic solution's residuals on the unscaled program, each relative (as Clarabel scales its own)."""

    primal: float
    dual: float
    gap: float

    @property
    def worst(self) -> float:
        return max(self.primal, self.dual, self.gap)

    def as_document(self) -> dict[str, float]:
        return {"primal": float(f"{self.primal:.3g}"), "dual": float(f"{self.dual:.3g}"), "gap": float(f"{self.gap:.3g}")}


@dataclass(frozen=True)
class SolveCheck:
    """How the kept solution was judged: ``clarabel``, the status of the precise solve; ``kept``: ``solved`` (it
    said Solved), ``measured`` (it said AlmostSolved, and its residuals meet :data:`ACCEPTED`), ``polished`` (a
    second solve did) or ``inaccurate`` (none did: the best measured is kept); its measured ``residuals``."""

    clarabel: str
    kept: str
    residuals: Residuals

    @property
    def plain(self) -> bool:
        """The solver said Solved: nothing to state beside the status."""
        return self.kept == "solved"

    @property
    def status(self) -> str:
        """The status as cvxpy names it, from the measured residuals."""
        return "optimal_inaccurate" if self.kept == "inaccurate" else "optimal"

    def as_document(self) -> dict[str, Any]:
        return {"clarabel": self.clarabel, "kept": self.kept, "residuals": self.residuals.as_document(),
                "accepted_within": ACCEPTED}


def measure(gram: np.ndarray, q: np.ndarray, a: Any, b: np.ndarray, solution: Any) -> Residuals:
    """The residuals of Clarabel's ``solution`` (x, s, z and both objectives) of ``min 1/2 x'Px + q'x, Ax + s = b``,
    ``P`` zero but for its leading block ``gram`` (the data term; Clarabel takes its upper triangle)."""
    x, s, z = (np.asarray(v, dtype=float) for v in (solution.x, solution.s, solution.z))
    px = np.zeros_like(x)
    px[: gram.shape[0]] = gram @ x[: gram.shape[0]]
    ax, atz = a @ x, a.T @ z

    def norm(v: np.ndarray) -> float:
        return float(np.max(np.abs(v))) if v.size else 0.0

    primal = norm(ax + s - b) / max(1.0, norm(b), norm(ax), norm(s))
    dual = norm(px + q + atz) / max(1.0, norm(px), norm(q), norm(atz))
    pobj, dobj = float(solution.obj_val), float(solution.obj_val_dual)
    gap = abs(pobj - dobj) / max(1.0, min(abs(pobj), abs(dobj)))
    return Residuals(primal, dual, gap)


def judge(first: Any, solve_again: Callable[[], Any], residuals: Callable[[Any], Residuals]) -> tuple[Any, SolveCheck]:
    """The solution to keep of a precise solve ``first`` that Clarabel says is Solved or AlmostSolved, and how it was
    judged. ``solve_again()``: the polishing solve; ``residuals(solution)``: :func:`measure` on the program."""
    status = str(first.status)
    measured = residuals(first)
    if status == "Solved":
        return first, SolveCheck(status, "solved", measured)
    if measured.worst <= ACCEPTED:
        return first, SolveCheck(status, "measured", measured)
    second = solve_again()
    if str(second.status) in ("Solved", "AlmostSolved"):
        again = residuals(second)
        if again.worst < measured.worst:
            return second, SolveCheck(status, "polished" if again.worst <= ACCEPTED else "inaccurate", again)
    return first, SolveCheck(status, "inaccurate", measured)
