"""The notes a verdict carries, one renderer per :class:`~sim2real.identification.records.NoteKind` in
:data:`NOTE_TEXT`: ties, confounded and relabelled candidates, cautions, failed trials, what the other side says, and
the decisions that take the conservative side; with the words of a candidate's troubles."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from sim2real.identification.records import Note, NoteKind, Side
from sim2real.report.verdicts.names import SIDE_NAME, bounds_text, separating_runs
from sim2real.stats import floor_multiple

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
    "raised_x_floor": "the joint's residual after it, x its floor, a rise counted beyond the noise",
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


# --- no recommended rung raises a joint (diagnosis.raises) -----------------------------------------------------------

RAISE_OUTCOME_TEXT = {
    "not_per_joint": "its parameters act on every joint together, so no line keeps it off {raised}: it is not "
                     "recommended",
    "helps_none": "it helps no joint it does not raise beyond the noise: it is not recommended",
    "kept_to_raises": "kept on the joints it helps ({joints}), its trial still raises {again}: it is not recommended",
    "kept_to_not_decisive": "kept on the joints it helps ({joints}), its trial removes too little to be named "
                            "({after} the floors arm-wide): it is not recommended",
    "kept_to_not_tried": "it is not tried on fewer joints (a candidate that removes more was): it is not recommended",
}


def _rises(raised: Mapping[str, Sequence[float]]) -> str:
    return ", ".join(f"{j} from {floor_multiple(before)} to {floor_multiple(after)}"
                     for j, (before, after) in raised.items())


def _raise_text(effect: str, figures: Mapping[str, Any]) -> str:
    rises = _rises(figures["raised"])
    if figures["outcome"] == "kept_to":
        return (f"fitted on every joint, {effect} raises {rises} its floor; its line keeps it on the joints it "
                f"helps ({', '.join(figures['joints'])}), where its rung, fitted as the next round fits it, raises none")
    trial = figures.get("kept_to_trial") or {}
    because = RAISE_OUTCOME_TEXT[figures["outcome"]].format(
        raised=", ".join(figures["raised"]), joints=", ".join(trial.get("joints") or ()),
        again=_rises(trial.get("raised") or {}) + " its floor", after=floor_multiple(trial.get("x_floor_after") or 0.0))
    return f"{effect} raises {rises} its floor; {because}"


def _raises(note: Note, robot: str) -> str:
    parts = [_raise_text(effect, figures) for effect, figures in sorted(note.figures["candidates"].items())]
    return (" No recommended line raises a joint beyond the noise (more than "
            f"{note.figures['tolerance']:g}x its floor above both where it was and the floor factor, a rise the "
            "holdout's blocks resolve): " + "; ".join(parts) + ".")


NOTE_TEXT: dict[NoteKind, Callable[[Note, str], str]] = {
    NoteKind.RAISES: _raises,
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
