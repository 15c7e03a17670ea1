"""The rules of the diagnosis that look across the two sides of a joint's torque (:mod:`sim2real.identification.sides`).

Each side is diagnosed on its own (:func:`sim2real.identification.diagnosis.diagnose`); what one side's verdict must
add because of the other is here, each rule a :class:`~sim2real.identification.records.Note` (:func:`across_sides`):

* the sensor's placement (:func:`drive_placement`): a drive effect named where the placement did not expect it;
* lags (:func:`sensor_lag`): the drive side judges the sensor's reading against the command, so a lag of the sensor
  shows there as actuation lag; the body side tells the two apart;
* the other side's trial of a line (:func:`other_side`): the line one side names sits on the other side too, which
  it may leave worse;
* a line kept on one side (:func:`held_on_other_side`): a line one side names that a line kept on the other side
  already holds.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from sim2real.identification.diagnosis.candidates import DEFAULT_DIAGNOSIS, HARM_TOLERANCE
from sim2real.identification.diagnosis.caveats import NESTED_IN
from sim2real.identification.diagnosis.result import Candidate, Diagnosis, candidate_named
from sim2real.identification.effects import get_effect
from sim2real.identification.fitting import FitResult
from sim2real.identification.records import Note, NoteKind, SensorPlacement, Side, Status
from sim2real.identification.sides import effects_of_side

AGREEING_LAGS = (0.5, 1.5)  # the body side's lag over the drive side's: the same lag, seen from both sides


def across_sides(body: Diagnosis | None, drive: Diagnosis | None, body_result: FitResult,
                 drive_result: FitResult | None, sensor: SensorPlacement,
                 ) -> tuple[Diagnosis | None, Diagnosis | None]:
    """Both sides' diagnoses with the notes each takes from the other (``drive``: None on runs that judge one side;
    ``body`` on the ``COMBINED`` side then gets none)."""
    if body is not None and body.side == Side.BODY:
        body = body.with_notes(drive_placement(body, sensor))
    if drive is None or drive_result is None:
        return body, drive
    drive = drive.with_notes(drive_placement(drive, sensor), sensor_lag(drive, drive_result, body_result, body))
    body, drive = (body.with_notes(other_side(body, drive, sensor)) if body else None,
                   drive.with_notes(other_side(drive, body, sensor)))
    if body is not None:
        body = body.with_notes(held_on_other_side(body, drive_result.effects, Side.DRIVE, sensor))
    return body, drive.with_notes(held_on_other_side(drive, body_result.effects, body.side if body else Side.BODY,
                                                     sensor))


def drive_placement(diagnosis: Diagnosis, sensor: SensorPlacement) -> Note | None:
    """A drive effect named where the sensor's placement did not expect it: after a link-side sensor (the body side),
    or between the motor and a motor-side sensor (the drive side: the metadata are contradicted)."""
    named = candidate_named(diagnosis)
    if named is None or not get_effect(named.effect).drive:
        return None
    if (diagnosis.side == Side.BODY and sensor == SensorPlacement.LINK_SIDE) or (
            diagnosis.side == Side.DRIVE and sensor == SensorPlacement.MOTOR_SIDE):
        return Note(NoteKind.DRIVE_PLACEMENT, effect=named.effect, side=diagnosis.side,
                    figures={"sensor": str(sensor)})
    return None


def _actuation_lag(name: str) -> bool:
    return get_effect(name).time_shift and get_effect(name).side == Side.DRIVE


def _sensor_lag(name: str) -> bool:
    return get_effect(name).time_shift and get_effect(name).sensor_side


def _lag_value(name: str, values: Mapping[str, Any]) -> float:
    return float(values.get(get_effect(name).nonlinear[0].name) or 0.0)


def sensor_lag(drive: Diagnosis, drive_result: FitResult, body_result: FitResult,
               body: Diagnosis | None = None) -> Note | None:
    """The drive side judges the sensor's reading against the command, so a lag of the sensor shows there as an
    actuation lag (a delay, a first-order lag); only the body side (the reading against the motion) tells the two
    apart. Where the drive side holds or names an actuation lag, its verdict says what the body side finds: the
    sensor lag of its model (sensor_delay, sensor_lag), or its trial of one (``body``)."""
    top = drive.best
    named = drive.status == Status.ADD_EFFECT and top is not None and _actuation_lag(top.effect)
    held = [name for name in drive_result.effects if _actuation_lag(name)]
    sensor = [name for name in body_result.effects if _sensor_lag(name)]
    lag = sum(_lag_value(name, body_result.values.get(name) or {}) for name in sensor)
    if lag > 0 and (held or named or drive.status != Status.AT_NOISE_FLOOR):
        return Note(NoteKind.SENSOR_LAG, side=Side.DRIVE, figures={
            "lag_s": lag, "effects": sensor, "unexplained": drive.status == Status.UNEXPLAINED})
    if not (held or named) or sensor:
        return None
    trial = _body_lag_trial(body)
    own = (sum(_lag_value(name, drive_result.values.get(name) or {}) for name in held) if held
           else _lag_value(top.effect, top.evidence.fitted) if top is not None else 0.0)
    found = _lag_value(trial.effect, trial.evidence.fitted) if trial else 0.0
    # The body side's lag must be this one, and show above the body's noise, to say whose it is.
    if not own or not AGREEING_LAGS[0] <= found / float(own) <= AGREEING_LAGS[1] \
            or trial is None or trial.explained_beyond_noise < DEFAULT_DIAGNOSIS["joint_min_explained"]:
        return None
    return Note(NoteKind.SENSOR_LAG_TRIAL, effect=trial.effect, side=Side.DRIVE, figures={
        "found_s": found, "own_s": float(own), "share": trial.explained_beyond_noise})


def _body_lag_trial(body: Diagnosis | None) -> Candidate | None:
    """Of the body side's trials of a sensor lag, the shape its ranking would name: the delay where the filter does no
    better than the data can tell (sim2real.identification.diagnosis.candidates._rank)."""
    trials = [c for c in (body.candidates if body else ()) if _sensor_lag(c.effect)]
    reach = min((c.evidence.x_floor_after for c in trials), default=0.0)
    return min((c for c in trials if c.evidence.x_floor_after
                <= reach + float(DEFAULT_DIAGNOSIS["parsimony_noise_fraction"])),
               key=lambda c: (get_effect(c.effect).lowpass, c.evidence.x_floor_after), default=None)


def other_side(named: Diagnosis, other: Diagnosis | None, sensor: SensorPlacement) -> Note | None:
    """A line one side names sits on the other side too (a drive's friction behind a link-side sensor): where the
    other side's own trial of it leaves a joint worse than now, above the floor factor or by more than the harm
    tolerance, the verdict says so; the user weighs the two sides. Only where the other side asks for nothing itself:
    then its next rung is its model with this line, which its trial fitted."""
    best = candidate_named(named)
    if best is None or other is None or other.status in (Status.ADD_EFFECT, Status.NOT_TOLD_APART):
        return None
    trial = other.candidate(best.effect)
    if trial is None or not effects_of_side([best.effect], other.side, sensor):
        return None
    factor = float(DEFAULT_DIAGNOSIS["noise_floor_factor"])
    now = {j: row.x_floor for j, row in other.per_joint.items()}
    after = trial.evidence.per_joint_x_floor_after
    worse = [j for j, a in now.items() if j in after and after[j] > a
             and (after[j] > factor or after[j] > a + HARM_TOLERANCE)]
    if not worse:
        return None
    return Note(NoteKind.OTHER_SIDE, effect=best.effect, side=other.side, joints=tuple(worse), figures={
        "explained": trial.explained, "after": {j: after[j] for j in worse}, "now": {j: now[j] for j in worse},
        "keep_on": str(_opposite(other.side))})


def held_on_other_side(diagnosis: Diagnosis, other_effects: Sequence[str], other: Side,
                       sensor: SensorPlacement) -> Note | None:
    """A line one side names that a line kept on the other side alone holds (coulomb_friction, where
    '- asymmetric_friction: actuator' is kept there): added as it is, it would sit on the other side beside its more
    general shape, which that side's own diagnosis never proposes. The verdict says to keep the new line on the side
    that named it."""
    best = candidate_named(diagnosis)
    if best is None:
        return None
    holder = next((held for held in other_effects if best.effect in NESTED_IN.get(held, ())), None)
    if holder is None or not get_effect(best.effect).drive or not effects_of_side([best.effect], other, sensor):
        return None
    return Note(NoteKind.HELD_ON_OTHER_SIDE, effect=best.effect, side=other,
                figures={"holder": holder, "keep_on": str(_opposite(other))})


def _opposite(side: Side) -> Side:
    return Side.BODY if side == Side.DRIVE else Side.DRIVE
