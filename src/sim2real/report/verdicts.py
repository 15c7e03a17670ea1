"""Every word of the diagnosis: verdicts, notes, caveats, skipped trials, the model-free ceiling's reading, what the
sides can tell apart, written once from the typed data of :mod:`sim2real.identification`.

The identification returns data (:class:`~sim2real.identification.diagnosis.Diagnosis`, its notes
:class:`~sim2real.identification.records.Note` records; ladder.json holds their documents); :func:`worded` gives
that document with its words, what gap.json holds and gap.md reads. A new rule of the loop is a new
:class:`~sim2real.identification.records.NoteKind` and one renderer in :data:`NOTE_TEXT`.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from sim2real.excitation.names import separation_name
from sim2real.identification.diagnosis import Diagnosis
from sim2real.identification.diagnosis.caveats import troubles
from sim2real.identification.diagnosis.ceiling import (
    CLOSE_TO_RUNG, DRIFT_EFFECT, POSE_LEARNERS, imitated_joints, offset_joints,
)
from sim2real.identification.effects.sensor_drift import SHAPE as DRIFT_SHAPE
from sim2real.identification.records import Note, NoteKind, SensorPlacement, Side, Status
from sim2real.stats import floor_multiple

# How each side is named in verdicts (the documents' words: the body link, the actuator link).
SIDE_TEXT: dict[str, str] = {
    Side.BODY: "the body link (measured torque against the motion)",
    Side.DRIVE: "the actuator link (measured against commanded torque)",
    Side.COMBINED: "the commanded torque against the motion (actuator and body together: no torque sensor)",
}
# A side as a note on the other side names it ("the actuator link").
SIDE_NAME: dict[str, str] = {Side.BODY: "body", Side.DRIVE: "actuator", Side.COMBINED: "combined"}

# A bound of the consistent fit that binds (sim2real.identification.inertial.bands.binding), as gap.md says it.
BOUND_TEXT = {"mass_lower": "mass at its band's lower edge", "mass_upper": "mass at its band's upper edge",
              "hull": "centre of mass on its hull", "divergence": "divergence from CAD at its bound"}

LOOK_AT_WINDOWS = " Look at the worst windows in the gap report."


def bounds_text(bodies: Mapping[str, Sequence[str]] | Sequence[Sequence[Any]]) -> str:
    """Bodies held at their bounds, with which: a mapping, or (body, bounds) pairs in the bodies' order."""
    pairs = bodies.items() if isinstance(bodies, Mapping) else bodies
    return "; ".join(f"{name} ({', '.join(BOUND_TEXT[b] for b in bounds)})" for name, bounds in pairs)


def separating_runs(first: str, others: Sequence[str], robot: str) -> str:
    return "; ".join(f"`snakemake results/{robot}/excitation/{separation_name(first, other)}.csv`" for other in others)


# --- the headline, by status --------------------------------------------------------------------------------------

def _added(d: Diagnosis, robot: str) -> str:
    best = d.best
    assert best is not None
    after = best.evidence["per_joint_x_floor_after"]
    if best.decided_on == "arm":
        reach = (f"it explains {best.explained:.0%} of the holdout residual ({best.explained_beyond_noise:.0%} "
                 f"of what lies above the noise floor, each joint in units of its own floor), bringing it from "
                 f"{floor_multiple(d.noise_floor_ratio or 0.0)} to {floor_multiple(best.evidence['x_floor_after'])} the "
                 f"floor ({d.residual_rmse:.3g} to {best.evidence['rmse_after']:.3g} N*m)")
    else:
        moves = ", ".join(f"{j} {floor_multiple(d.per_joint[j]['x_floor'])} -> {floor_multiple(after[j])}"
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
    reasons = "; ".join(f"{c.effect}: {', '.join(map(trouble_text, troubles({'evidence': c.evidence})))}" for c in group)
    runs = (f" The run that would tell them apart: {separating_runs(names[0], names[1:], robot)} designs it; "
            "record it and add it to the fit runs." if len(names) > 1 else
            f" Record a run designed for the model (`snakemake results/{robot}/excitation/identification.csv`) "
            "and add it to the fit runs.")
    return (f"On {SIDE_TEXT[d.side]}, {' and '.join(names)} {'each remove' if len(names) > 1 else 'removes'} part of "
            f"the residual, but no line is recommended: {reasons}. What these runs show is not yet a trustworthy "
            "effect." + runs)


def _at_noise_floor(d: Diagnosis, robot: str) -> str:
    x_now = {j: row["x_floor"] for j, row in d.ordered(d.per_joint).items()}
    worst = max(x_now, key=x_now.get) if x_now else "-"  # type: ignore[arg-type]
    return (f"Nothing to add on {SIDE_TEXT[d.side]}: every joint's holdout residual is within {d.noise_floor_factor}x its "
            f"own noise floor (worst {worst} {floor_multiple(max(x_now.values()) if x_now else 0)}; "
            f"{d.residual_rmse:.3g} N*m against {d.noise_rmse:.3g} N*m arm-wide) and no effect removes more than "
            f"{d.min_explained:.0%} of what lies above it.")


def _unexplained(d: Diagnosis, robot: str) -> str:
    def joint(j: str) -> str:
        row = d.per_joint[j]
        return (f"{j} {floor_multiple(row['x_floor'])} its floor"
                + (f" (closest: {row['closest']}, removing {row['closest_explained_beyond_noise']:.0%} of its excess)"
                   if row["closest"] else ""))

    best = d.best
    return (f"No effect in the library explains the residual on {SIDE_TEXT[d.side]}: "
            f"{'; '.join(joint(j) for j in d.above_floor)}. The best candidate arm-wide "
            f"({best.effect if best else 'none'}) removes only {best.explained_beyond_noise if best else 0:.0%} "
            "of what lies above the floor.")


HEADLINE: dict[Status, Callable[[Diagnosis, str], str]] = {
    Status.ADD_EFFECT: _added, Status.NOT_TOLD_APART: _not_told_apart, Status.AT_NOISE_FLOOR: _at_noise_floor,
    Status.UNEXPLAINED: _unexplained,
}


# --- the notes ------------------------------------------------------------------------------------------------------

def implausible_text(body: Mapping[str, Any] | str) -> str:
    """A body a fit leaves beyond plausible (:func:`sim2real.identification.diagnosis.caveats.implausible_bodies`)."""
    return body if isinstance(body, str) else f"{body['body']} ({', '.join(body['reasons'])})"


def trouble_text(trouble: Mapping[str, Any]) -> str:
    """Why a candidate would leave the model less trustworthy (:func:`sim2real.identification.diagnosis.caveats.
    troubles`), in words."""
    if trouble["kind"] == "implausible":
        return f"it leaves link inertias implausible ({'; '.join(map(implausible_text, trouble['bodies']))})"
    if trouble["kind"] == "bounds":
        return f"it pushes link inertias to their bounds ({bounds_text(trouble['bodies'])})"
    return (f"it trades places with {trouble['effect']} already in the model (the fit moves that effect's term against "
            f"its own, {trouble['moved_x_own_term']:.2g}x its size, correlation {trouble['correlation']:.2f}: the "
            "prediction hardly changes, the fall is relabelled)")


def _lag_shapes(note: Note, robot: str) -> str:
    return (f" These data cannot tell it from {', '.join(note.figures['shapes'])}: two shapes of the same lag, which "
            "part only where the judged torque changes within it (a faster log, a command's own noise); either line "
            "holds the lag these runs show, and " + (
                "the filter is named: it removes the most." if note.figures["lowpass"] else
                "the delay is named, the plainer of the two (a filter gives the simulation a state of its own)."))


def _confounded(note: Note, robot: str) -> str:
    twins = note.figures["twins"]
    return (f" These data cannot tell it apart from {', '.join(twins)} (the same prediction to within "
            f"{note.figures['within']:g}x the noise floor). The run that would: "
            + separating_runs(str(note.effect), twins, robot)
            + " designs it (the motion on which their fitted predictions differ most, within the limits of "
            f"configs/{robot}/excitation.yaml); record it and add it to the fit runs.")


def _tied(note: Note, robot: str) -> str:
    others, best, first = note.figures["others"], note.effect, note.figures["first"]
    return (f" On these runs it is not told apart from {', '.join(others)}: each removes about the same residual "
            f"(within {note.figures['spread']:g} standard errors of their difference over blocks of the holdout). "
            + (f"{best} is recommended: it scores best of them and keeps the model plausible. " if best == first else
               f"{best} is recommended: it keeps the model plausible, which {first} does not. ")
            + f"The run that would tell them apart: {separating_runs(str(best), others, robot)} designs "
            "it; record it and add it to the fit runs.")


def _caution(note: Note, robot: str) -> str:
    return f" Caution: {'; '.join(trouble_text(t) for t in note.figures['troubles'])}."


def _failed_trials(note: Note, robot: str) -> str:
    def x(value: float | None) -> str:
        return floor_multiple(value) if value is not None else "not finite"

    parts = [f"{name} ({x(figures['fit_x_floor'])} the floors on the fit runs against the model's "
             f"{x(figures['model_fit_x_floor'])})" for name, figures in sorted(note.figures["failed"].items())]
    return (f" The trial of {', '.join(parts)} did not solve: a model that extends the current one fits its runs at "
            "least as well, so it is left out of the ranking, neither named nor ruled out. The sysid log has the "
            "solver's messages.")


def _drive_placement(note: Note, robot: str) -> str:
    if note.side == Side.BODY:
        return (f" The runs say the torque sensor is link-side, and yet the measured torque against the motion "
                f"shows {note.effect}: behind this sensor that is friction after it (output bearings, seals) or a "
                "sensor that sits before part of the drive. It is fitted on the body link; the calibrated model "
                "adds it to the joint's value.")
    return (f" The runs' metadata say the torque sensor is motor-side (torque_sensor: motor), but the measured "
            f"torque against the command shows {note.effect}, which lies between the motor and a link-side sensor: "
            "the data contradict the metadata. If the sensor measures after the gearbox, set "
            "`torque_sensor: link` in the runs' metadata YAML.")


def _sensor_lag(note: Note, robot: str) -> str:
    figures = note.figures
    return (f" The body link finds the torque sensor's reading {figures['lag_s'] * 1e3:.2g} ms behind the motion "
            f"({', '.join(figures['effects'])}): that much of the lag this link finds between the command and the "
            "reading is the sensor's, which this link, judging the reading against the command, counts as actuation "
            "lag; the calibrated actuators hold only what lies beyond it (params.yaml, by_link)."
            + (" A sensor's lag is a filter rather than a pure delay: at the command's rate its noise shows the "
               "difference, which no effect of this link removes." if figures["unexplained"] else ""))


def _sensor_lag_trial(note: Note, robot: str) -> str:
    figures = note.figures
    return (" This link cannot tell an actuation lag from a lag of the torque sensor (the reading lags the command "
            f"either way); the body link can, and its trial of {note.effect} finds the reading "
            f"{figures['found_s'] * 1e3:.2g} ms behind the motion (this link: {figures['own_s'] * 1e3:.2g} ms), "
            f"removing {figures['share']:.0%} of what lies above its floor: the lag is the sensor's. Add "
            f"'- {note.effect}' under 'effects:' and the calibrated actuators hold only what lies beyond it.")


def _other_side(note: Note, robot: str) -> str:
    figures, other = note.figures, SIDE_NAME[str(note.side)]
    explains = (f"explains {figures['explained']:.0%} of its residual" if figures["explained"] > 0
                else "explains nothing")
    return (f" The line sits on the {other} link too, where its trial {explains} and leaves "
            + ", ".join(f"{j} at {floor_multiple(figures['after'][j])} its floor ({floor_multiple(figures['now'][j])} "
                        "now)" for j in note.joints)
            + f". To keep it off the {other} link, write the line as '- {note.effect}: {figures['keep_on']}'.")


def _held_on_other_side(note: Note, robot: str) -> str:
    holder = note.figures["holder"]
    return (f" The {SIDE_NAME[str(note.side)]} link holds it already ({holder}, kept there, a more general shape of "
            f"it): write the line as '- {note.effect}: {note.figures['keep_on']}', so that it is not fitted there "
            f"beside {holder}.")


# --- decisions that take the conservative side (diagnosis.margins, caveats.relabelling) ------------------------------

def _relabelled(note: Note, robot: str) -> str:
    def one(effect: str, trades: Sequence[Mapping[str, Any]]) -> str:
        held = "; ".join(f"{t['effect']}'s term moves against its own, {t['moved_x_own_term']:.2g}x its size, "
                         f"correlation {t['correlation']:.2f}, the prediction moving by {t['net_x_floor']:.2g}x the "
                         "floor" for t in trades)
        return f"{effect} ({held})"

    parts = [one(effect, trades) for effect, trades in sorted(note.figures["relabelled"].items())]
    return (f" Not named: {'; '.join(parts)}. Such a candidate's own term is an effect the model already holds, "
            "relabelled: adding it, the fit gives that effect's term back, the prediction moves by less than the "
            "noise floor and the fall it seems to bring is the current model's under another name (on another CPU it "
            "is not even a fall), so it is never a line to add.")


NEAR_FIGURE_TEXT = {
    "explained_beyond_noise": "of what lies above the floors removed",
    "explained": "of the whole residual removed",
    "joint_explained_beyond_noise": "of the joint's excess removed",
    "own_term_x_floor": "its own term there, x the joint's floor",
    "x_floor": "the joint's residual, x its floor",
}


def near_text(near: Mapping[str, Any]) -> str:
    """One figure within the arithmetic's margin of its threshold (:class:`sim2real.identification.diagnosis.margins.
    Near`)."""
    where = f"{near['joint']}: " if near.get("joint") else ""
    return (f"{where}{near['value']:.3g} {NEAR_FIGURE_TEXT[near['figure']]}, against {near['threshold']:g} "
            f"(give or take {near['margin']:.2g})")


def _near_threshold(note: Note, robot: str) -> str:
    figures = note.figures
    parts = [f"{effect} is not named ({'; '.join(map(near_text, nears))})"
             for effect, nears in sorted(figures["candidates"].items())]
    if figures["ties"]:
        parts.append(f"{', '.join(figures['ties'])} {'is' if len(figures['ties']) == 1 else 'are'} counted tied with "
                     f"the best (within {figures['tie_margin']:.0%} of the tie's bound)")
    if figures["joints"]:
        parts.append("counted within the floor: " + "; ".join(map(near_text, figures["joints"])))
    return (" Where a figure sits within the arithmetic's precision of its threshold (another CPU's BLAS moves it that "
            "much), the decision takes the conservative side: " + "; ".join(parts) + ".")


NOTE_TEXT: dict[NoteKind, Callable[[Note, str], str]] = {
    NoteKind.RELABELLED: _relabelled, NoteKind.NEAR_THRESHOLD: _near_threshold,
    NoteKind.LAG_SHAPES: _lag_shapes, NoteKind.CONFOUNDED: _confounded, NoteKind.TIED: _tied,
    NoteKind.CAUTION: _caution, NoteKind.FAILED_TRIALS: _failed_trials, NoteKind.DRIVE_PLACEMENT: _drive_placement,
    NoteKind.SENSOR_LAG: _sensor_lag, NoteKind.SENSOR_LAG_TRIAL: _sensor_lag_trial, NoteKind.OTHER_SIDE: _other_side,
    NoteKind.HELD_ON_OTHER_SIDE: _held_on_other_side,
}
# The notes that look across the sides, each also under a key of its own in gap.json's diagnosis.
NOTE_KEYS: dict[NoteKind, str] = {
    NoteKind.DRIVE_PLACEMENT: "sensor_note", NoteKind.SENSOR_LAG: "lag_note", NoteKind.SENSOR_LAG_TRIAL: "lag_note",
    NoteKind.OTHER_SIDE: "other_link_note", NoteKind.HELD_ON_OTHER_SIDE: "held_note",
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


# --- skipped trials and rungs -----------------------------------------------------------------------------------------

SKIP_TEXT: dict[NoteKind, Callable[[Mapping[str, Any]], str]] = {
    NoteKind.PER_RUN: lambda f: (
        "estimated on every run itself, the holdout runs included, so no held-out run can judge it: the model-free "
        "ceiling says when each run's offsets call for it, and the user declares it"),
    NoteKind.NESTED: lambda f: f"{f['holder']} in the model already holds it (a special case of it)",
    NoteKind.DRIVE_BEHIND_SENSOR: lambda f: (
        "an effect of the actuator link (command -> applied torque), and the torque judged here is measured by a "
        "sensor (tau) after it; runs that also log tau_cmd judge it on the actuator link"),
    NoteKind.SENSOR_ON_COMMANDS: lambda f: (
        "an error of the torque sensor, and these runs judge the commanded torque (tau_cmd): on commands the same "
        "column is the actuator's (actuator_gain, command_bias)"),
    NoteKind.LAG_SCREENED: lambda f: (
        f"a {'lead of the judged torque ahead of' if f['lead'] else 'lag of the measured torque behind'} the model "
        f"({f['delay_s'] * 1e3:.2g} ms, linearised about none, every linear coefficient refitted beside it on the "
        f"holdout runs) would remove at most {f['share']:.0%} of what lies above the noise floor, under half of what "
        "names a candidate"),
    NoteKind.OTHER_SHAPE: lambda f: (
        f"its other shape, {f['other']}, tried beside it, removes {f['share']:.0%} of what lies above the noise "
        "floor, under half of what names a candidate"),
    NoteKind.RIPPLE_AT_FLOOR: lambda f: (
        "every joint's residual is within its noise floor times the diagnosis's factor: no joint's ripple to search "
        "for"),
}


def skip_reason(note: Note) -> str:
    """Why a candidate was not tried."""
    if note.kind == NoteKind.RIPPLE_SCREENED:
        f = note.figures
        return ("no joint's residual repeats with its own position: one sinusoid of each joint's position, its period "
                f"and coefficients fitted on the fit runs, would remove at most {f['share']:.0%} of what lies above the "
                f"noise floor of the holdout runs ({f['joint_share']:.0%} on {note.joints[0]}), under half of what "
                "names a candidate")
    return SKIP_TEXT[note.kind](note.figures)


def violations_text(violations: Sequence[Mapping[str, Any]]) -> str:
    """What is non-physical in a solution (:func:`sim2real.identification.fitting.rung._violations`)."""
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


# --- the model-free ceiling -------------------------------------------------------------------------------------------

KIND_TEXT = {
    "time": "drifts with time within each run (a warm-up, a sensor offset that wanders, or an error of the slow pose "
    "the run moves through)",
    "run": "is an offset that differs from run to run",
    "history": "follows the history of the motion: the displacement since the last velocity reversal "
    "(hysteresis, presliding friction)",
}
GAIN_REGIME_TEXT = {"slow_reversal": "slow motion and velocity reversals", "hard_acceleration": "hard accelerations"}
# What sits at an offset of its own in each run or drifts within one is the sensor's, not the robot's: said where the
# ceiling finds it, with what a user does about it, and for runs already logged the effect that estimates it.
OFFSET_ADVICE = ("On {joints} the torque sits at an offset of its own in each run or drifts within it (a torque sensor "
                 "warming up, or zeroed at another moment): no property of the robot, but every fit takes part of it "
                 "for one (a link inertia fitted to one run's offset misses the next run's), so it can hide an effect "
                 "the library has. Log once the arm has warmed up, its torque sensors zeroed at rest, and run the loop "
                 "again")
DECLARE_ADVICE = ("; or, for these runs, add the line '- {effect}' under 'effects:' in configs/{robot}/model.yaml: "
                  f"each run's drift ({DRIFT_SHAPE}) is then estimated on that run itself, "
                  "the holdout runs included, and never written into the assets.")


FEATURE_TEXT = {
    "position": "position of {joint}", "velocity": "velocity of {joint}", "acceleration": "acceleration of {joint}",
    "predicted_torque": "the torque the model predicts for {joint}", "velocity_sign": "the sign of velocity of {joint}",
    "speed": "the speed of {joint}", "gravity_torque": "the gravity torque of {joint}",
    "torque_times_sign": "the torque the model predicts for {joint} times the sign of its velocity",
    "abs_torque_times_sign": "|the torque the model predicts for {joint}| times the sign of its velocity",
    **{f"gravity_along_{axis}": f"the gravity torque of {{joint}} under gravity along the base's {axis}"
       for axis in ("x", "y", "z")},
    "sin_position": "the sine of the angle of {joint}", "cos_position": "the cosine of the angle of {joint}",
}


def feature_text(feature: Mapping[str, Any] | str) -> str:
    """A learner's feature (:func:`sim2real.identification.diagnosis.ceiling_features.feature`) in words."""
    if isinstance(feature, str):
        return feature
    if feature["feature"] == "periodic_position":
        every = f", every {feature['period']:.3g} rad" if "period" in feature else ""
        return f"position of {feature['joint']} (periodic{every})"
    return FEATURE_TEXT[feature["feature"]].format(joint=feature["joint"])


def _learned(j: str, r: Mapping[str, Any]) -> str:
    with_ = [feature_text(f) for f in r["gains_most_with"]]
    follows = f", mostly as a function of {' and '.join(with_)}" if with_ else ""
    if r.get("gains_most_in"):
        follows += f", most in {GAIN_REGIME_TEXT[r['gains_most_in']]}"
    return f"{j} {floor_multiple(r['rung_x_floor'])} -> {floor_multiple(r['ceiling_x_floor'])} its floor{follows}"


def _motion_sentence(per_joint: Mapping[str, Any], joints: Sequence[str]) -> str:
    def beside(r: Mapping[str, Any]) -> str:
        if r.get("follows") not in ("time", "run"):
            return ""
        return (f", beside a drift of each run's own that removes {r['beyond_motion'][r['follows']]:.0%} of its excess "
                "(the learner, fitted again without it, still explains much)")

    return ("A flexible learner on the motion explains much of what is left, so the library lacks an effect that is "
            f"a function of the motion: {'; '.join(_learned(j, per_joint[j]) + beside(per_joint[j]) for j in joints)}. "
            "Model that dependence (an effect of the library's shape; a periodic one of a joint's position is "
            "position_ripple's, one period per joint) before trusting the rest.")


def _pose_sentence(per_joint: Mapping[str, Any], joints: Sequence[str], points_to: Mapping[str, Any] | None,
                   robot: str) -> str:
    """Joints where a function of the pose alone explains what is left (a pose learner carried it to the holdout's
    poses): said so, with the pose dependence named, and the library's effect that carries it where it has one."""
    text = ("A function of the pose alone explains much of what is left, carried from the fit runs' poses to the "
            f"holdout's: {'; '.join(_learned(j, per_joint[j]) for j in joints)}.")
    if points_to:
        text += (f" On {', '.join(points_to['joints'])} it follows the arm's gravity torque under a gravity turned "
                 f"sideways, the mark of a base mounted off level: add the line '{points_to['line']}' under "
                 f"'effects:' in configs/{robot}/model.yaml.")
    else:
        text += (" No effect of the library has its shape (a cable's or a hose's pull, a spring, a mass the model "
                 "misplaces): model that dependence before trusting the rest.")
    return text


def _imitated_sentence(per_joint: Mapping[str, Any], joints: Sequence[str]) -> str:
    parts = [f"{_learned(j, per_joint[j])}, yet a drift of each run's own removes "
             f"{per_joint[j]['beyond_motion'][per_joint[j]['follows']]:.0%} of its excess (the learner "
             f"{per_joint[j]['explained_beyond_noise']:.0%}): it {KIND_TEXT[per_joint[j]['follows']]}" for j in joints]
    return ("A learner on the motion explains part of what is left where each run's motion follows its time, and "
            f"there it only imitates a drift: {'; '.join(parts)}.")


def _still_sentence(per_joint: Mapping[str, Any], joints: Sequence[str]) -> str:
    parts = []
    for j in joints:
        r = per_joint[j]
        what = KIND_TEXT[r["follows"]] if r["follows"] else ("follows none of time within a run, the run or the "
                                                             "history since a reversal (a sensor's own dynamics, "
                                                             "noise the floor misses)")
        parts.append(f"{j} ({floor_multiple(r['rung_x_floor'])} its floor; the learner "
                     f"{floor_multiple(r['ceiling_x_floor'])}): it {what}")
    return (f"No function of the motion explains the rest: a flexible learner on the motion comes within "
            f"{1 - CLOSE_TO_RUNG:.0%} of the last rung on {', '.join(joints)}. " + "; ".join(parts) + ".")


def ceiling_text(ceiling: Mapping[str, Any], robot: str, joints: Sequence[str] = ()) -> str:
    """What the model-free ceiling says (:func:`sim2real.identification.diagnosis.model_free_ceiling`): joints where
    the library lacks a function of the motion, joints where the motion only imitates a drift, and joints where
    nothing of the motion explains the rest, with what it follows and what to do about offsets. ``joints``: their
    order (default: the document's)."""
    per_joint = {j: ceiling["per_joint"][j] for j in ([j for j in joints if j in ceiling["per_joint"]]
                                                       or ceiling["per_joint"])}
    imitated = imitated_joints(per_joint)
    posed = [j for j, r in per_joint.items() if r["kind"] == "motion" and j not in imitated
             and r.get("learner") in POSE_LEARNERS]
    motion = [j for j, r in per_joint.items() if r["kind"] == "motion" and j not in imitated and j not in posed]
    still = [j for j, r in per_joint.items() if r["kind"] == "not_motion"]
    sentences = ([_pose_sentence(per_joint, posed, ceiling.get("points_to"), robot)] if posed else []) + (
        [_motion_sentence(per_joint, motion)] if motion else []) + (
        [_imitated_sentence(per_joint, imitated)] if imitated else []) + (
        [_still_sentence(per_joint, still)] if still else [])
    offsets = offset_joints(per_joint)
    if offsets:
        sentences.append(OFFSET_ADVICE.format(joints=", ".join(offsets)) + (
            "." if not ceiling.get("declare") else DECLARE_ADVICE.format(effect=DRIFT_EFFECT, robot=robot)))
    return " ".join(sentences)


def ceiling_section(ceiling: Mapping[str, Any], robot: str, joints: Sequence[str] = ()) -> dict[str, Any]:
    """gap.json's ``model_free``: the ceiling's document with its words (``text``, the features in words)."""
    out = copy.deepcopy(dict(ceiling))
    for row in out["per_joint"].values():
        if "gains_most_with" in row:
            row["gains_most_with"] = [feature_text(f) for f in row["gains_most_with"]]
    out["text"] = ceiling_text(ceiling, robot, joints)
    return out


# --- what the sides can tell apart -----------------------------------------------------------------------------------

MODE_TEXT: dict[str, str] = {
    "separate": "the runs log the measured torque (tau) and the command (tau_cmd): the actuator link is judged "
    "on tau against tau_cmd, the body link on tau against the motion",
    "commands_only": "the runs log only the command (tau_cmd): the actuator and the body are judged together, "
    "on tau_cmd against the motion",
    "sensor_only": "the runs log only the measured torque (tau): the body link is judged on tau against the "
    "motion; the actuator (command -> applied torque) cannot be seen",
}


def _why(why: str, sensor: str) -> str:
    """Why a group of effects can or cannot be told apart (:func:`sim2real.identification.sides.separability`)."""
    link_side, motor_side = sensor == SensorPlacement.LINK_SIDE, sensor == SensorPlacement.MOTOR_SIDE
    return {
        "drive_against_command": "judged on the measured torque against the command: no body effect enters that link"
        + (" (the sensor is link-side: the drive's rotor inertia and friction lie before it)" if link_side else "")
        + "; the sensor's own lag does (its reading lags the command too): the calibrated actuation lag is "
        "what this link finds beyond the body link's (sensor_delay, sensor_lag)",
        "body_against_motion": "judged on the measured torque against the motion: no actuator effect enters that link"
        + (" (the sensor is motor-side: the drive's rotor inertia and friction lie after it)" if motor_side else ""),
        "lag_of_whole_torque": "a lag of the whole torque (a delay, or a filter's), which no body effect makes; the "
        "replay of each rung (replay position RMSE) shows it in the state domain too",
        "constant_torque": "a constant torque per joint; no body effect of the library is constant",
        "common_gain": "a motor gain g common to all joints moves the arm exactly as the body with every torque "
        "scaled by 1/g (masses, inertias, armature and friction together): in the torque domain and in "
        "the replay alike. Only per-joint differences of the gain show. A joint torque sensor (tau) "
        "separates them",
        "no_sensor": "errors of a torque sensor, and these runs have none: not tried",
        "no_command": "the runs log no command (tau_cmd), so the actuator link is not seen: not fitted, not tried"
        + ("; the drive's effects are tried on the body link, where the measured torque shows what acts "
           "after the sensor" if link_side else ""),
        "confounded": "on these runs their fitted models predict the same torque (within a tenth of the noise floor)",
    }[why]


def sides_section(links: Mapping[str, Any]) -> dict[str, Any]:
    """gap.json's ``links``: ladder.json's with its words (one that has them already as it is)."""
    if "text" in links:
        return copy.deepcopy(dict(links))
    sensor = links.get("torque_sensor", SensorPlacement.MOTOR_SIDE)
    out = {key: copy.deepcopy(value) for key, value in links.items() if key != "drive_after_sensor"}
    out["text"] = MODE_TEXT[links["mode"]]
    for group in (*out["can_tell"], *out["cannot_tell"]):
        group["why"] = _why(group["why"], sensor)
    if links.get("drive_after_sensor"):
        out["metadata_note"] = (
            f"The runs say the torque sensor is link-side (torque_sensor: link), so the body link was expected to be "
            f"the rigid body alone; yet the model fits {', '.join(links['drive_after_sensor'])} on it, against the "
            "motion, after the sensor. The data say part of the joint's friction or inertia acts after the sensor "
            "(output bearings, seals) or that the sensor sits before part of the drive; the calibrated model adds it "
            "to the joint's value.")
    return out


# --- the documents ---------------------------------------------------------------------------------------------------

DATA_ONLY = ("notes", "noise_rmse", "noise_floor_factor", "min_explained", "joints")


def diagnosis_section(document: Mapping[str, Any], robot: str) -> dict[str, Any]:
    """gap.json's ``diagnosis`` (or ``actuator.diagnosis``): ladder.json's with its words (one that has them already,
    worded or written by a release before the words moved here, as it is)."""
    if "verdict" in document:
        return copy.deepcopy(dict(document))
    d = Diagnosis.from_document(document)
    out = {key: copy.deepcopy(value) for key, value in document.items() if key not in DATA_ONLY}
    out["verdict"] = verdict(d, robot)
    for candidate in out["candidates"]:
        evidence = candidate["evidence"]
        if "implausible_bodies" in evidence:
            evidence["implausible_bodies"] = [implausible_text(b) for b in evidence["implausible_bodies"]]
    out["skipped"] = [{"effect": n.effect, "reason": skip_reason(n)} for n in d.skipped]
    if d.model_free is not None:
        out["model_free"] = ceiling_section(d.model_free, robot, d.joints)
    for note in d.notes:
        if note.kind in NOTE_KEYS:
            out[NOTE_KEYS[note.kind]] = NOTE_TEXT[note.kind](note, robot).strip()
    return out


def _ladder_section(ladder: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """A side's rungs with their words: each rung's notes and how its inertial prior's weight was chosen."""
    rungs = copy.deepcopy(list(ladder))
    for rung in rungs:
        if "notes" in rung:
            rung["notes"] = [rung_note(note) for note in rung["notes"]]
        prior = (rung.get("consistency") or {}).get("inertia_prior")
        if isinstance(prior, dict) and "chosen_by" in prior:
            prior["chosen_by"] = chosen_by_text(prior["chosen_by"])
    return rungs


def judged_text(sensor: str) -> str:
    """What the actuator link judges, by the sensor's placement."""
    if sensor == SensorPlacement.MOTOR_SIDE:
        return "measured torque (tau) predicted from the commanded torque (tau_cmd); no dynamics"
    return ("link-side measured torque (tau) predicted from the commanded torque (tau_cmd) less the drive's rotor "
            "inertia, damping and friction on the measured motion")


def worded(ladder: Mapping[str, Any], robot: str) -> dict[str, Any]:
    """ladder.json's content with its words: each diagnosis's verdict and notes, each rung's notes, what the sides can
    tell apart (what gap.json holds of it)."""
    out = dict(ladder)
    if "ladder" in out:
        out["ladder"] = _ladder_section(out["ladder"])
    if out.get("diagnosis"):
        out["diagnosis"] = diagnosis_section(out["diagnosis"], robot)
    if out.get("links"):
        out["links"] = sides_section(out["links"])
    if out.get("actuator"):
        sensor = (ladder.get("links") or {}).get("torque_sensor", SensorPlacement.MOTOR_SIDE)
        actuator = {"judged": judged_text(sensor), **out["actuator"]}
        actuator["ladder"] = _ladder_section(actuator["ladder"])
        if actuator.get("diagnosis"):
            actuator["diagnosis"] = diagnosis_section(actuator["diagnosis"], robot)
        out["actuator"] = actuator
    return out


def not_judged_text(not_judged: Mapping[str, Any]) -> str:
    """The joints the fit runs barely move (gap.json's ``not_judged``: sim2real.measurements.motion), in one sentence:
    not judged, what the fit holds of them, and the motion they would need."""
    joints = list(not_judged["joints"])
    one = len(joints) == 1
    ranges = " and ".join(f"{not_judged['joints'][j]['range_rad']:.2g}" for j in joints)
    return (f"Not judged: {', '.join(joints)} barely {'moves' if one else 'move'} in the fit runs ({ranges} rad at most "
            f"within one run): {'its' if one else 'their'} {' and '.join(not_judged['held_at_nominal'])} are held at "
            f"the URDF's rather than fitted on noise, and the figures below judge nothing of "
            f"{'its drive' if one else 'their drives'}; record a fit run that sweeps {'it' if one else 'each'} over "
            f"at least {not_judged['needs_rad']:g} rad.")


# --- the first screen of gap.md --------------------------------------------------------------------------------------
# The verdict in at most three sentences, from gap.json's diagnosis: the status; the line to add, or what kind of thing
# is left (joint by joint in the per-joint table beside it, so named here by kind, never by joint); the worst joint in
# units of its floor. The diagnosis's own verdict, with its reasons, follows further down gap.md.

LEFT_TEXT = {"at_floor": "at its floor", "motion": "a function of the motion the library lacks"}
FOLLOWS_TEXT = {"time": "not the motion: drifts with time", "run": "not the motion: an offset per run",
                "history": "not the motion: follows the history since a reversal", None: "not the motion, nor time"}


def left_text(row: Mapping[str, Any]) -> str:
    """What kind of thing is left on a joint (the model-free ceiling's ``kind`` and ``follows``), in a few words."""
    if row["kind"] == "motion" and row.get("imitated"):  # the motion only imitates what the run's time explains
        return FOLLOWS_TEXT[row["follows"]].replace("not the motion: ", "") + ", which the motion imitates"
    if row["kind"] == "motion":
        with_ = row.get("gains_most_with") or []
        return LEFT_TEXT["motion"] + (f" ({', '.join(with_)})" if with_ else "")
    return LEFT_TEXT.get(row["kind"]) or FOLLOWS_TEXT[row.get("follows")]


def _kinds_left(ceiling: Mapping[str, Any] | None, above: Sequence[str]) -> str:
    """The kinds of thing left above the floors (each with how many joints), in the order met."""
    per_joint = (ceiling or {}).get("per_joint") or {}
    kinds: dict[str, int] = {}
    for joint in above:
        if joint in per_joint and per_joint[joint]["kind"] != "at_floor":
            kind = left_text({**per_joint[joint], "gains_most_with": []})
            kinds[kind] = kinds.get(kind, 0) + 1
    return "; ".join(f"{kind} ({count} joint{'s' if count > 1 else ''})" for kind, count in kinds.items())


def _first_status(diagnosis: Mapping[str, Any], side: str) -> str:
    status, best = diagnosis.get("status"), (diagnosis.get("candidates") or [None])[0]
    if status == Status.ADD_EFFECT and best and best.get("decided_on") == "joints":
        # decided on its own joints (the table's "closest candidate there"), not on the arm-wide share
        return (f"On {side}, the model lacks {best['effect']} on {len(best['joints'])} joint"
                f"{'s' if len(best['joints']) > 1 else ''}, where it removes most of what lies above their floors.")
    if status == Status.ADD_EFFECT and best:
        after = best.get("evidence", {}).get("x_floor_after")
        reach = (f": it removes {best['explained_beyond_noise']:.0%} of what lies above the noise floor"
                 + (f", to {floor_multiple(after)} the floor arm-wide" if after is not None else "")
                 if best.get("explained_beyond_noise") is not None else "")
        return f"On {side}, the model lacks {best['effect']}{reach}."
    if status == Status.NOT_TOLD_APART:
        return (f"On {side}, {' and '.join(diagnosis.get('tied') or [])} each remove part of what is left, but no "
                "line is recommended: these runs do not tell a trustworthy effect.")
    if status == Status.AT_NOISE_FLOOR:
        return f"Nothing to add on {side}: every joint's holdout residual is at its own noise floor."
    return f"No effect in the library explains what is left on {side}."


def _first_action(diagnosis: Mapping[str, Any], robot: str) -> str | None:
    status, best = diagnosis.get("status"), (diagnosis.get("candidates") or [None])[0]
    if status == Status.ADD_EFFECT and best:
        removal = "".join(f" and remove '- {r}'" for r in best.get("replaces") or [])
        caution = "; read its caution in the diagnosis below first" if troubles(best) else ""
        return f"Add the line '{best['add']}' under 'effects:' in configs/{robot}/model.yaml{removal}{caution}."
    tied = list(diagnosis.get("tied") or [])
    if status == Status.NOT_TOLD_APART and len(tied) > 1:
        return (f"The run that would tell them apart: {separating_runs(tied[0], tied[1:], robot)} designs it; record "
                "it and add it to the fit runs.")
    if status == Status.NOT_TOLD_APART:
        return (f"Record a run designed for the model (`snakemake results/{robot}/excitation/identification.csv`) and "
                "add it to the fit runs.")
    if status == Status.UNEXPLAINED:
        kinds = _kinds_left(diagnosis.get("model_free"), diagnosis.get("above_floor") or [])
        return (f"What is left, joint by joint in the table below: {kinds}." if kinds else
                "The worst windows and the residual figures below show where it lies.")
    return None


def first_screen_verdict(diagnosis: Mapping[str, Any], robot: str, x_floor: Mapping[str, float],
                         rmse: Mapping[str, float], floor: Mapping[str, float]) -> list[str]:
    """gap.md's verdict in at most three sentences (gap.json's ``diagnosis``; the current model's ``x_floor``,
    ``rmse`` and noise ``floor`` per joint): the status; the line to add, or the kinds of thing left; the worst
    joint in units of its floor."""
    side = SIDE_TEXT.get(str(diagnosis.get("link")), "the body link").split(" (")[0]
    sentences = [_first_status(diagnosis, side)]
    action = _first_action(diagnosis, robot)
    if action:
        sentences.append(action)
    if x_floor:
        worst = max(x_floor, key=x_floor.get)  # type: ignore[arg-type]
        sentences.append(f"Worst joint: {worst}, {floor_multiple(x_floor[worst])} its noise floor "
                         f"({rmse[worst]:.3g} N m against {floor[worst]:.3g} N m).")
    return sentences


# ---- The noise floor: which floor every "x floor" figure, weight, the ceiling and the stopping rule use
# (sim2real.measurements.noise.measured_noise_floor, gap.json's noise_floor.method and noise_floor.evidence).
FLOOR_METHOD_TEXT = {
    "differences": "the white part of the raw torque (differences of orders 2 to 5 agree)",
    "rounding": "the RMS of the logger's rounding (quantum/sqrt(12): its differences are mostly zero)",
    "updates": "the white part of the joint's own updates (the samples where its torque changes)",
    "spectrum": "the spectrum of the raw torque above the motion's band, up to the sensor chain's cut-off",
    "stated": "the floor the runs' metadata state",
}


def _joint_list(joints: Sequence[str]) -> str:
    return ", ".join(joints)


def floor_sentences(noise_floor: Mapping[str, Any]) -> list[str]:
    """What gap.md says of the noise floor: which floor it is per joint, and, where differences could not measure it,
    the figures that show it (gap.json's ``noise_floor``: ``method`` per joint, ``evidence`` per run)."""
    methods: Mapping[str, str] = noise_floor.get("method") or {}
    by_method: dict[str, list[str]] = {}
    for joint, method in methods.items():
        by_method.setdefault(method, []).append(joint)
    sentences = [f"The noise floor on {_joint_list(joints)} is {FLOOR_METHOD_TEXT.get(m.split('+')[0], m)}."
                 if len(by_method) > 1 else f"The noise floor is {FLOOR_METHOD_TEXT.get(m.split('+')[0], m)}, on every joint."
                 for m, joints in by_method.items()]
    for run in noise_floor.get("evidence") or []:
        sentences += _floor_evidence(run)
    return sentences


def _floor_evidence(run: Mapping[str, Any]) -> list[str]:
    """The figures of one run whose floor is not the differences' white part on every joint."""
    out = []
    figures = run["joints"]
    held = [j for j, f in figures.items() if f["method"] == "updates" or (f["method"] == "spectrum" and f["held"])]
    falling = [j for j, f in figures.items() if f["method"] == "spectrum" and not f["held"]]
    if held:
        shares = ", ".join(f"{j} {figures[j]['equal_steps']:.0%}" for j in held)
        out.append(f"Run {run['run']}: the floor could not be taken from differences on {_joint_list(held)}: most "
                   f"consecutive torque samples are equal ({shares}), so differences give about zero; the torque is held "
                   f"between updates slower than the log.")
    if falling:
        spans = ", ".join(f"{j} {figures[j]['differences'][0]:.3g} -> {figures[j]['differences'][-1]:.3g} N m against "
                          f"{figures[j]['spectrum']:.3g} N m" for j in falling)
        out.append(f"Run {run['run']}: the floor could not be taken from differences on {_joint_list(falling)}: their "
                   f"estimates keep falling with the order (order 2 -> 5), below what the spectrum holds ({spans}); the "
                   f"torque was smoothed, held or upsampled before it was logged.")
    stated = [j for j, f in figures.items() if f["method"] == "stated"]
    if stated:
        out.append(f"Run {run['run']}: the floor on {_joint_list(stated)} is the one its metadata state: "
                   f"{run['stated_reason']}.")
    return out


# ---- No rung raises a joint (sim2real.identification.diagnosis.raises): the candidate set aside for it.

def _raises_joints(note: Note, robot: str) -> str:
    figures = note.figures

    def moves(rows: Mapping[str, Mapping[str, float]]) -> str:
        return ", ".join(f"{j} {floor_multiple(r['from'])} -> {floor_multiple(r['to'])}" for j, r in rows.items())

    lowers = f"lowers {moves(figures['lowers'])} (x each joint's floor) but " if figures["lowers"] else ""
    return (f" {note.effect} {lowers}raises {moves(figures['raises'])} beyond what the noise floor and the holdout's "
            f"blocks can resolve: no rung may raise a joint, so it is not recommended. configs/{robot}/model.yaml has "
            f"no line that keeps an effect on some joints only, so its line '- {note.effect}' is added on none.")


NOTE_TEXT[NoteKind.RAISES_JOINTS] = _raises_joints
