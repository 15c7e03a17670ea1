"""The verdict of a diagnosis: the headline of its status (:data:`HEADLINE`), then its notes and, where nothing is
named, the model-free ceiling's reading (:func:`verdict`)."""

from __future__ import annotations

from collections.abc import Callable

from sim2real.identification.diagnosis import Diagnosis
from sim2real.identification.diagnosis.caveats import troubles
from sim2real.identification.records import Status
from sim2real.report.verdicts.ceiling import ceiling_text
from sim2real.report.verdicts.names import SIDE_TEXT, separating_runs
from sim2real.report.verdicts.notes import NOTE_KEYS, NOTE_TEXT, trouble_text
from sim2real.stats import floor_multiple

LOOK_AT_WINDOWS = " Look at the worst windows in the gap report."


def _added(d: Diagnosis, robot: str) -> str:
    best = d.best
    assert best is not None
    after = best.evidence.per_joint_x_floor_after
    if best.decided_on == "arm":
        reach = (f"it explains {best.explained:.0%} of the holdout residual ({best.explained_beyond_noise:.0%} "
                 f"of what lies above the noise floor, each joint in units of its own floor), bringing it from "
                 f"{floor_multiple(d.noise_floor_ratio or 0.0)} to {floor_multiple(best.evidence.x_floor_after)} the "
                 f"floor ({d.residual_rmse:.3g} to {best.evidence.rmse_after:.3g} N*m)")
    else:
        moves = ", ".join(f"{j} {floor_multiple(d.per_joint[j].x_floor)} -> {floor_multiple(after[j])}"
                          for j in best.joints)
        reach = (f"on {', '.join(best.joints)} it removes most of what lies above the noise floor ({moves} the joint's "
                 f"own floor), though only {best.explained:.0%} of the arm-wide residual")
    joint_text = f" on {', '.join(best.joints)}" if best.joints else ""
    removal = ""
    if best.replaces:
        lines = " and ".join(f"'- {r}'" for r in best.replaces)
        removal = (f" and remove {lines}: {best.effect} holds {', '.join(best.replaces)} (a special case of it), and "
                   "both in one model fit the same torque twice")
    return (f"On {SIDE_TEXT[d.side]}, the model is missing {best.effect}{joint_text}: {reach}. "
            f"Add the line '{best.add}' under 'effects:' in configs/{robot}/model.yaml{removal}.")


def _not_told_apart(d: Diagnosis, robot: str) -> str:
    group = [c for name in d.tied if (c := d.candidate(name)) is not None]
    names = [c.effect for c in group]
    reasons = "; ".join(f"{c.effect}: {', '.join(map(trouble_text, troubles(c.evidence)))}" for c in group)
    runs = (f" The run that would tell them apart: {separating_runs(names[0], names[1:], robot)} designs it; "
            "record it and add it to the fit runs." if len(names) > 1 else
            f" Record a run designed for the model (`snakemake results/{robot}/excitation/identification.csv`) "
            "and add it to the fit runs.")
    return (f"On {SIDE_TEXT[d.side]}, {' and '.join(names)} {'each remove' if len(names) > 1 else 'removes'} part of "
            f"the residual, but no line is recommended: {reasons}. What these runs show is not yet a trustworthy "
            "effect." + runs)


def _at_noise_floor(d: Diagnosis, robot: str) -> str:
    x_now = {j: row.x_floor for j, row in d.ordered(d.per_joint).items()}
    worst = max(x_now, key=x_now.get) if x_now else "-"  # type: ignore[arg-type]
    return (f"Nothing to add on {SIDE_TEXT[d.side]}: every joint's holdout residual is within {d.noise_floor_factor}x its "
            f"own noise floor (worst {worst} {floor_multiple(max(x_now.values()) if x_now else 0)}; "
            f"{d.residual_rmse:.3g} N*m against {d.noise_rmse:.3g} N*m arm-wide) and no effect removes more than "
            f"{d.min_explained:.0%} of what lies above it.")


def _unexplained(d: Diagnosis, robot: str) -> str:
    def joint(j: str) -> str:
        row = d.per_joint[j]
        return (f"{j} {floor_multiple(row.x_floor)} its floor"
                + (f" (closest: {row.closest}, removing {row.closest_explained_beyond_noise:.0%} of its excess)"
                   if row.closest else ""))

    best = d.best
    return (f"No effect in the library explains the residual on {SIDE_TEXT[d.side]}: "
            f"{'; '.join(joint(j) for j in d.above_floor)}. The best candidate arm-wide "
            f"({best.effect if best else 'none'}) removes only {best.explained_beyond_noise if best else 0:.0%} "
            "of what lies above the floor.")


HEADLINE: dict[Status, Callable[[Diagnosis, str], str]] = {
    Status.ADD_EFFECT: _added, Status.NOT_TOLD_APART: _not_told_apart, Status.AT_NOISE_FLOOR: _at_noise_floor,
    Status.UNEXPLAINED: _unexplained,
}


def verdict(d: Diagnosis, robot: str) -> str:
    """The verdict: the headline of its status, the notes of the side, the model-free ceiling's reading where nothing
    is named, then the notes the other side gives it."""
    own = [n for n in d.notes if n.kind not in NOTE_KEYS]
    across = [n for n in d.notes if n.kind in NOTE_KEYS]
    ceiling = ceiling_text(d.model_free, robot, d.joints) if d.model_free is not None else ""
    text = HEADLINE[d.status](d, robot)
    if d.status == Status.UNEXPLAINED and not ceiling:
        text += LOOK_AT_WINDOWS
    text += "".join(NOTE_TEXT[n.kind](n, robot) for n in own)
    if d.status == Status.UNEXPLAINED and ceiling:
        text += " " + ceiling + " The gap report's worst windows and residual figures show it."
    return text + "".join(NOTE_TEXT[n.kind](n, robot) for n in across)
