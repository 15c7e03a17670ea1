"""A rung's notes in words (ladder.json ``ladder[].notes``): held nonlinear parameters, a delay the torque cannot
show, what is non-physical in a solution, and how the inertial prior's weight was chosen."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from sim2real.identification.records import NoteKind

def violations_text(violations: Sequence[Mapping[str, Any]]) -> str:
    """What is non-physical in a solution (:func:`sim2real.identification.fitting.consistent._violations`)."""
    return "; ".join(f"link_inertia: non-physical inertia of {', '.join(v['bodies'])}" if "bodies" in v
                     else f"{v['effect']}: {v['below_bound']} value(s) below their physical bound" for v in violations)


PRIOR_GRID_TEXT = "the previous rung's weight and a decade either side"
PRIOR_BOUND_TEXT = {
    "weakest": "; at the weakest pull searched: the held-out error still fell as the pull weakened, so the data ask "
    "for inertias freer than the search allows",
    "strongest": "; at the strongest pull searched: the held-out data see no cost in holding the inertias at CAD",
}


def chosen_by_text(chosen_by: Mapping[str, Any] | str) -> str:
    """How the inertial prior's weight was chosen (a rung's ``consistency.inertia_prior.chosen_by``)."""
    if isinstance(chosen_by, str):
        return chosen_by
    if chosen_by["method"] == "setting":
        return "the model.yaml setting fit.inertia_regularization (a fraction of the noise floor's variance)"
    if chosen_by["method"] == "held_from_previous_rung":
        raised = ", ".join(f"{j} from {a:.2f}x to {b:.2f}x its floor" for j, (a, b) in chosen_by["raised"].items())
        return (f"holding the previous rung's: {chosen_by_text(chosen_by['cross_validation'])} chose "
                f"{chosen_by['cross_validated']:.3g}, which raised {raised} on the holdout runs, and no rung raises a "
                "joint beyond the noise")
    grid = chosen_by["first_grid"]
    first_grid = ", ".join(f"{g:g}" for g in grid) if isinstance(grid, list) else PRIOR_GRID_TEXT
    return (f"cross-validation on {chosen_by['blocks']} held-out blocks of the fit runs (the strongest pull towards "
            "CAD within 1% of the best held-out error, the search going on past its first grid "
            f"({first_grid}) while the scores say so; weights are fractions of the noise floor's variance, scores "
            f"held-out RMS in N*m, each joint weighted by its floor){PRIOR_BOUND_TEXT.get(chosen_by['bound'] or '', '')}")


def rung_note(note: Mapping[str, Any] | str) -> str:
    """A rung's note (ladder.json ``ladder[].notes``) in words."""
    if isinstance(note, str):
        return note
    kind, figures = NoteKind(note["kind"]), note.get("figures") or {}
    if kind == NoteKind.NONLINEAR_HELD:
        return ("the previous rung's nonlinear parameters (friction slopes and offsets, delay) are held: refined "
                "again, they predicted the holdout runs worse")
    if kind == NoteKind.DELAY_NOT_SEEN:
        return (f"{note['effect']}: the judged torque is measured ({figures['torque_source']}); a delay between command "
                "and applied torque does not show in it, so the torque-domain fit keeps it at 0")
    if kind == NoteKind.CONSISTENCY_INFEASIBLE:
        return (f"physical consistency: {figures['reason']}; the rung keeps the UNCONSTRAINED fit, which may be "
                "non-physical. Check the torque signs and units of the runs and the URDF's inertials")
    return (f"physical consistency: the data contradict a physical model with these effects: the unconstrained fit "
            f"needs non-physical values ({violations_text(figures['violations'])}) and fits the fit runs to {figures['free_rmse']:.3g} "
            f"against {figures['physical_rmse']:.3g} for the best physical fit (RMS in N*m, each joint weighted by "
            "its noise floor). An effect is missing, or the torque columns' sign or units are wrong")
