"""The two links of the model: the actuator (command -> applied torque) and the body (applied torque -> motion).

Every effect declares its link (:attr:`sim2real.identification.effects.base.Effect.link`). What the runs log decides
how the links can be judged (:func:`link_mode`):

* ``separate``: a joint torque sensor (``tau``) beside the command (``tau_cmd``). The body link is the
  rigid-body ladder on ``tau`` against the motion. The actuator link is judged directly, the measured
  torque against the command: no dynamics, so no body error leaks into it. Through the fitting core
  (:mod:`sim2real.identification.fitting`), with the command in the place of the nominal model's prediction
  (:attr:`sim2real.identification.effects.Signals.forward`)::

      tau(t) = g * tau_cmd(t - d) + b + sensor noise

  so ``actuation_delay``, ``actuator_gain`` and ``command_bias`` are the same effect classes as on runs
  without a sensor. The command is known exactly, so the noise is all in the judged torque and the
  least squares are unbiased. The link is fitted on every sample (no decimation): a delay of a few ms
  is a few samples.

  Where the sensor sits decides where the drive's effects go (:func:`effect_link`). A motor-side
  sensor (run metadata ``torque_sensor: motor``, the default: a motor-current estimate) measures the
  torque before the rotor inertia and the joint friction, which are then the body's. A link-side
  sensor (``torque_sensor: link``: the Panda's tau_J, a KUKA iiwa's) measures after them, so they
  join the actuator link, predicted from the motion and not delayed::

      tau(t) = g * tau_cmd(t - d) + b - (I_a * qdd + D * qd + F_c * tanh(qd / v_s))(t) + sensor noise

  and the body link is the rigid body alone (:func:`sim2real.identification.fitting.make_signals`).
* ``commands_only``: no torque sensor (most arms). One ladder on ``tau_cmd`` against the motion holds
  both links; :func:`separability` says what these data can and cannot tell apart.
* ``sensor_only``: no commands. The body link only; the actuator cannot be seen.

The actuator link's noise floor is the white part of the measured torque that no linear filter of the
command explains (:func:`sim2real.measurements.command_floor_of`): a controller's command carries white noise of its own
(velocity noise through its gains), which reaches the sensor through the motor, delayed and scaled.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.identification.effects import EFFECTS, Signals, get_effect
from sim2real.identification.fitting import NominalModel, RunSamples, TorqueData, link_side, stack_runs
from sim2real.measurements import DEFAULT_TORQUE_SENSOR, PreparedRun, TorqueSensor, command_floor_of

LINK_MODES: dict[str, str] = {
    "separate": "the runs log the measured torque (tau) and the command (tau_cmd): the actuator link is judged "
    "on tau against tau_cmd, the body link on tau against the motion",
    "commands_only": "the runs log only the command (tau_cmd): the actuator and the body are judged together, "
    "on tau_cmd against the motion",
    "sensor_only": "the runs log only the measured torque (tau): the body link is judged on tau against the "
    "motion; the actuator (command -> applied torque) cannot be seen",
}

# The actuator link is fitted on every sample: a delay of a few ms is a few samples. Its nonlinear refinement
# (the delay, friction slopes) runs on up to two minutes at 1 kHz; a longer log's on 5 s windows spread over it
# at the log's own step (fitting.problem.refinement_rows), so its memory does not grow with the log.
ACTUATOR_FIT_SETTINGS: dict[str, Any] = {"fit_rate_hz": None, "refine_max_samples": 120_000, "refine_windows_s": 5.0}


def link_mode(runs: Sequence[PreparedRun]) -> str:
    """``separate``, ``commands_only`` or ``sensor_only`` (see the module docstring) for a set of runs."""
    has_sensor = all(run.torque_source == "tau" for run in runs)
    has_commands = all(run.tau_cmd is not None for run in runs)
    if has_sensor and has_commands:
        return "separate"
    return "sensor_only" if has_sensor else "commands_only"


def effect_link(name: str, torque_sensor: TorqueSensor = DEFAULT_TORQUE_SENSOR) -> str:
    """The link where an effect is expected. The drive's effects (rotor inertia, joint friction and damping)
    sit between the motor and the link: behind a motor-side sensor they are the body's, in front of a
    link-side sensor (``torque_sensor: link``) the actuator's. This is a prior that words the report:
    the data decide (:func:`candidates_of_link`, :func:`effects_of_link`)."""
    effect = get_effect(name)
    return "actuator" if effect.drive and torque_sensor == "link" else effect.link


def effects_of_link(effect_names: Sequence[str], link: str, torque_sensor: TorqueSensor = DEFAULT_TORQUE_SENSOR,
                    kept_on: Mapping[str, str] | None = None) -> list[str]:
    """The effects of ``link`` among ``effect_names``, in their order; ``kept_on``: drive effects model.yaml keeps
    on one link (``- asymmetric_friction: actuator``), left off the other.

    A drive effect is fitted on the body link whatever the sensor: behind a link-side sensor the body's
    share is the part after the sensor (output bearings, seals), which a real arm's link-side torque
    shows (Gaz et al. 2019 identify the Panda's friction from tau_J). Behind a link-side sensor it is
    fitted on the actuator link too: the part before the sensor."""
    kept_on = kept_on or {}
    return [name for name in effect_names
            if (effect_link(name, torque_sensor) == link or (get_effect(name).drive and link == "body")
                or get_effect(name).every_link) and kept_on.get(name, link) == link]


def kept_on_problem(name: str, link: str, mode: str, torque_sensor: TorqueSensor) -> str | None:
    """Why model.yaml cannot keep the drive effect ``name`` on ``link`` alone with these runs (None: it can): the runs
    fit one link only, or that link does not fit it (behind a motor-side sensor the actuator link fits no drive
    effect)."""
    if mode != "separate":
        return ("these runs fit one link only (they do not log both the measured torque tau and the command tau_cmd), "
                "so there is no other link to keep it off")
    if name not in effects_of_link([name], link, torque_sensor):
        return (f"behind a {torque_sensor}-side torque sensor (the runs' torque_sensor) the {link} link does not fit "
                f"{name}: kept there, it would be fitted nowhere")
    return None


def candidates_of_link(link: str, torque_sensor: TorqueSensor = DEFAULT_TORQUE_SENSOR,
                       kept_on: Mapping[str, str] | None = None) -> list[str]:
    """The library's effects the diagnosis tries on ``link`` (``combined``: all of them); ``kept_on``: drive effects
    model.yaml keeps on one link, not tried on the other (:func:`effects_of_link`).

    The sensor's position is a prior, not a veto: every effect the judged signal can show is tried. The
    drive's effects are tried on both links (the body sees what acts after the sensor; the actuator link,
    what acts between the motor and the sensor: nothing, if the sensor really is motor-side)."""
    kept_on = kept_on or {}
    return [name for name in EFFECTS
            if (link == "combined" or effect_link(name, torque_sensor) == link or get_effect(name).drive)
            and kept_on.get(name, link) == link]


def drive_verdict_note(link: str, effect: str, torque_sensor: str) -> str:
    """What a drive effect found on ``link`` means behind this sensor ('' when it is where it was expected)."""
    if not get_effect(effect).drive:
        return ""
    if link == "body" and torque_sensor == "link":
        return (f" The runs say the torque sensor is link-side, and yet the measured torque against the motion "
                f"shows {effect}: behind this sensor that is friction after it (output bearings, seals) or a "
                "sensor that sits before part of the drive. It is fitted on the body link; the calibrated model "
                "adds it to the joint's value.")
    if link == "actuator" and torque_sensor == "motor":
        return (f" The runs' metadata say the torque sensor is motor-side (torque_sensor: motor), but the measured "
                f"torque against the command shows {effect}, which lies between the motor and a link-side sensor: "
                "the data contradict the metadata. If the sensor measures after the gearbox, set "
                "`torque_sensor: link` in the runs' metadata YAML.")
    return ""


def actuator_data(runs: Sequence[PreparedRun], joint_names: Sequence[str]) -> tuple[TorqueData, np.ndarray]:
    """The actuator link's data on every sample: the measured torque as the judged torque (``TorqueData``,
    with the link's noise floor) and the command it is predicted from, stacked alike."""
    judged, commands = [], []
    for run in runs:
        assert run.tau_cmd is not None
        floor = command_floor_of(run)
        judged.append(RunSamples.of(run, floor))
        commands.append(RunSamples.of(run, floor, tau=run.tau_cmd))
    rate = ACTUATOR_FIT_SETTINGS["fit_rate_hz"]
    return stack_runs(judged, joint_names, rate), stack_runs(commands, joint_names, rate).tau


def actuator_signals(data: TorqueData, commands: np.ndarray, nominal: NominalModel | None = None) -> Signals:
    """Signals of the actuator link: the command stands where the body link has the nominal model.

    Behind a link-side sensor (``data.torque_sensor == "link"``, ``nominal`` given) the link also holds
    the drive: tau = g * tau_cmd(t - d) + b - (armature * qdd + damping * qd + friction * sign(qd)), the
    nominal drive terms undelayed (``Signals.unshifted``) and the drive effects' columns negated.
    """
    drive = None
    if link_side(data):
        if nominal is None:
            raise ValueError("a link-side sensor's actuator link needs the nominal model (its drive terms)")
        drive = -nominal.dynamics.drive_torque(data.qd, data.qdd)
    return Signals(
        joint_names=list(data.joint_names), time=data.time, q=data.q, qd=data.qd, qdd=data.qdd,
        tau_nominal=commands, segments=data.segments, tau=data.tau, regressor_fn=None,
        nominal=nominal.info if drive is not None and nominal is not None else {}, forward=True, unshifted=drive,
    )


def separability(mode: str, model_effects: Sequence[str], confounded: Sequence[Sequence[str]],
                 sensor: TorqueSensor = DEFAULT_TORQUE_SENSOR) -> dict[str, Any]:
    """What the runs can tell apart (``links`` of ladder.json): the mode in words, then the facts.

    ``confounded``: the pairs the diagnosis found predicting the same torque on these data; ``sensor``:
    where ``tau`` is measured (:func:`torque_sensor`).
    """
    out: dict[str, Any] = {"mode": mode, "text": LINK_MODES[mode], "torque_sensor": sensor,
                           "can_tell": [], "cannot_tell": []}

    def told_apart(link: str) -> list[str]:  # an effect estimated on every run itself is told apart from nothing
        return [name for name in candidates_of_link(link, sensor) if not get_effect(name).per_run]

    if mode == "separate":
        out["can_tell"] = [
            {"effects": told_apart("actuator"),
             "why": "judged on the measured torque against the command: no body effect enters that link"
             + (" (the sensor is link-side: the drive's rotor inertia and friction lie before it)"
                if sensor == "link" else "")
             + "; the sensor's own lag does (its reading lags the command too): the calibrated actuation lag is "
             "what this link finds beyond the body link's (sensor_delay, sensor_lag)"},
            {"effects": told_apart("body"),
             "why": "judged on the measured torque against the motion: no actuator effect enters that link"
             + (" (the sensor is motor-side: the drive's rotor inertia and friction lie after it)"
                if sensor == "motor" else "")},
        ]
    elif mode == "commands_only":
        out["can_tell"] = [
            {"effects": ["actuation_delay", "actuation_lag"],
             "why": "a lag of the whole torque (a delay, or a filter's), which no body effect makes; the replay of each rung "
             "(replay position RMSE) shows it in the state domain too"},
            {"effects": ["command_bias"],
             "why": "a constant torque per joint; no body effect of the library is constant"},
        ]
        out["cannot_tell"] = [
            {"effects": ["actuator_gain", "link_inertia", "rotor_inertia", "coulomb_friction", "viscous_friction",
                         "asymmetric_friction", "stribeck_friction", "hysteretic_friction", "load_friction",
                         "position_ripple"],
             "why": "a motor gain g common to all joints moves the arm exactly as the body with every torque "
             "scaled by 1/g (masses, inertias, armature and friction together): in the torque domain and in "
             "the replay alike. Only per-joint differences of the gain show. A joint torque sensor (tau) "
             "separates them"},
            {"effects": ["torque_gain", "torque_bias", "sensor_delay", "sensor_lag", "sensor_drift"],
             "why": "errors of a torque sensor, and these runs have none: not tried"},
        ]
    else:
        out["cannot_tell"] = [
            {"effects": [n for n in candidates_of_link("actuator", sensor) if not get_effect(n).drive],
             "why": "the runs log no command (tau_cmd), so the actuator link is not seen: not fitted, not tried"
             + ("; the drive's effects are tried on the body link, where the measured torque shows what acts "
                "after the sensor" if sensor == "link" else "")},
        ]
        dropped = [n for n in model_effects if effect_link(n, sensor) == "actuator" and not get_effect(n).drive]
        if dropped:
            out["cannot_tell"][0]["dropped_from_model"] = dropped
    for pair in confounded:
        out["cannot_tell"].append({
            "effects": list(pair),
            "why": "on these runs their fitted models predict the same torque (within a tenth of the noise floor)",
        })
    return out
