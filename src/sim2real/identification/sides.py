"""The two sides of a joint's torque: the drive (command -> applied torque) and the body (applied torque -> motion).

Every effect declares its side (:attr:`sim2real.identification.effects.base.Effect.side`, a
:class:`~sim2real.identification.records.Side`). What the runs log decides how the sides can be judged
(:func:`side_mode`):

* ``separate``: a joint torque sensor (``tau``) beside the command (``tau_cmd``). The body side is the
  rigid-body ladder on ``tau`` against the motion. The drive side is judged directly, the measured
  torque against the command: no dynamics, so no body error leaks into it. Through the fitting core
  (:mod:`sim2real.identification.fitting`), with the command in the place of the nominal model's prediction
  (:attr:`sim2real.identification.effects.Signals.forward`)::

      tau(t) = g * tau_cmd(t - d) + b + sensor noise

  so ``actuation_delay``, ``actuator_gain`` and ``command_bias`` are the same effect classes as on runs
  without a sensor. The command is known exactly, so the noise is all in the judged torque and the
  least squares are unbiased. The side is fitted on every sample (no decimation): a delay of a few ms
  is a few samples.

  Where the sensor sits (:class:`~sim2real.identification.records.SensorPlacement`) decides where the drive's
  effects go (:func:`effect_side`). A motor-side sensor (run metadata ``torque_sensor: motor``, the default: a
  motor-current estimate) measures the torque before the rotor inertia and the joint friction, which are then the
  body's. A link-side sensor (``torque_sensor: link``: the Panda's tau_J, a KUKA iiwa's) measures after them, so
  they join the drive side, predicted from the motion and not delayed::

      tau(t) = g * tau_cmd(t - d) + b - (I_a * qdd + D * qd + F_c * tanh(qd / v_s))(t) + sensor noise

  and the body side is the rigid body alone (:func:`sim2real.identification.fitting.make_signals`).
* ``commands_only``: no torque sensor (most arms). One ladder on ``tau_cmd`` against the motion holds
  both sides (:attr:`Side.COMBINED`); :func:`separability` says what these data can and cannot tell apart.
* ``sensor_only``: no commands. The body side only; the drive cannot be seen.

The drive side's noise floor is the white part of the measured torque that no linear filter of the
command explains (:func:`sim2real.measurements.command_floor_of`): a controller's command carries white noise of its own
(velocity noise through its gains), which reaches the sensor through the motor, delayed and scaled.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.errors import InputError
from sim2real.identification.effects import EFFECTS, Signals, get_effect
from sim2real.identification.fitting import NominalModel, RunSamples, TorqueData, link_side, stack_runs
from sim2real.identification.records import SensorPlacement, Side
from sim2real.measurements import DEFAULT_TORQUE_SENSOR, PreparedRun, command_floor_of

# What the runs log decides how the sides can be judged (see the module docstring).
SIDE_MODES = ("separate", "commands_only", "sensor_only")

# The drive side is fitted on every sample: a delay of a few ms is a few samples. Its nonlinear refinement
# (the delay, friction slopes) runs on up to two minutes at 1 kHz; a longer log's on 5 s windows spread over it
# at the log's own step (fitting.refine.refinement_rows), so its memory does not grow with the log.
DRIVE_FIT_SETTINGS: dict[str, Any] = {"fit_rate_hz": None, "refine_max_samples": 120_000, "refine_windows_s": 5.0}


def side_mode(runs: Sequence[PreparedRun]) -> str:
    """``separate``, ``commands_only`` or ``sensor_only`` (see the module docstring) for a set of runs."""
    has_sensor = all(run.torque_source == "tau" for run in runs)
    has_commands = all(run.tau_cmd is not None for run in runs)
    if has_sensor and has_commands:
        return "separate"
    return "sensor_only" if has_sensor else "commands_only"


def effect_side(name: str, torque_sensor: SensorPlacement = DEFAULT_TORQUE_SENSOR) -> Side:
    """The side where an effect is expected. The drive's effects (rotor inertia, joint friction and damping)
    sit between the motor and the link: behind a motor-side sensor they are the body's, in front of a
    link-side sensor the drive's. This is a prior that words the report: the data decide
    (:func:`candidates_of_side`, :func:`effects_of_side`)."""
    effect = get_effect(name)
    return Side.DRIVE if effect.drive and torque_sensor == SensorPlacement.LINK_SIDE else effect.side


def effects_of_side(effect_names: Sequence[str], side: Side, torque_sensor: SensorPlacement = DEFAULT_TORQUE_SENSOR,
                    kept_on: Mapping[str, Side] | None = None) -> list[str]:
    """The effects of ``side`` among ``effect_names``, in their order; ``kept_on``: drive effects model.yaml keeps
    on one side (``- asymmetric_friction: actuator``), left off the other.

    A drive effect is fitted on the body side whatever the sensor: behind a link-side sensor the body's
    share is the part after the sensor (output bearings, seals), which a real arm's link-side torque
    shows (Gaz et al. 2019 identify the Panda's friction from tau_J). Behind a link-side sensor it is
    fitted on the drive side too: the part before the sensor."""
    kept_on = kept_on or {}
    return [name for name in effect_names
            if (effect_side(name, torque_sensor) == side or (get_effect(name).drive and side == Side.BODY)
                or get_effect(name).every_side) and kept_on.get(name, side) == side]


def check_kept_on(name: str, side: Side, mode: str, torque_sensor: SensorPlacement, path: str | Path) -> None:
    """Refuse a line of model.yaml (the file ``path``) that keeps the drive effect ``name`` on ``side`` alone where
    these runs cannot: they fit one side only, or that side does not fit it (behind a motor-side sensor the drive side
    fits no drive effect)."""
    if mode != "separate":
        raise InputError(path, f"effects: '- {name}: {side}'", "these runs fit one side only (they do not log both "
                         "the measured torque tau and the command tau_cmd), so there is no other side to keep it off",
                         f"write '- {name}'")
    if name not in effects_of_side([name], side, torque_sensor):
        raise InputError(path, f"effects: '- {name}: {side}'", f"behind a {torque_sensor}-side torque sensor (the "
                         f"runs' torque_sensor) the {side} side does not fit {name}: kept there, it would be fitted "
                         "nowhere", f"write '- {name}'")


def candidates_of_side(side: Side, torque_sensor: SensorPlacement = DEFAULT_TORQUE_SENSOR,
                       kept_on: Mapping[str, Side] | None = None) -> list[str]:
    """The library's effects the diagnosis tries on ``side`` (``COMBINED``: all of them); ``kept_on``: drive effects
    model.yaml keeps on one side, not tried on the other (:func:`effects_of_side`).

    The sensor's placement is a prior, not a veto: every effect the judged signal can show is tried. The
    drive's effects are tried on both sides (the body sees what acts after the sensor; the drive side,
    what acts between the motor and the sensor: nothing, if the sensor really is motor-side)."""
    kept_on = kept_on or {}
    return [name for name in EFFECTS
            if (side == Side.COMBINED or effect_side(name, torque_sensor) == side or get_effect(name).drive)
            and kept_on.get(name, side) == side]


def drive_data(runs: Sequence[PreparedRun], joint_names: Sequence[str]) -> tuple[TorqueData, np.ndarray]:
    """The drive side's data on every sample: the measured torque as the judged torque (``TorqueData``,
    with the side's noise floor) and the command it is predicted from, stacked alike."""
    judged, commands = [], []
    for run in runs:
        assert run.tau_cmd is not None
        floor = command_floor_of(run)
        judged.append(RunSamples.of(run, floor))
        commands.append(RunSamples.of(run, floor, tau=run.tau_cmd))
    rate = DRIVE_FIT_SETTINGS["fit_rate_hz"]
    return stack_runs(judged, joint_names, rate), stack_runs(commands, joint_names, rate).tau


def drive_signals(data: TorqueData, commands: np.ndarray, nominal: NominalModel | None = None) -> Signals:
    """Signals of the drive side: the command stands where the body side has the nominal model.

    Behind a link-side sensor (``nominal`` given) the side also holds the drive: tau = g * tau_cmd(t - d) + b -
    (armature * qdd + damping * qd + friction * sign(qd)), the nominal drive terms undelayed (``Signals.unshifted``)
    and the drive effects' columns negated.
    """
    drive = None
    if link_side(data):
        if nominal is None:
            raise ValueError("a link-side sensor's drive side needs the nominal model (its drive terms)")
        drive = -nominal.dynamics.drive_torque(data.qd, data.qdd)
    return Signals(
        joint_names=list(data.joint_names), time=data.time, q=data.q, qd=data.qd, qdd=data.qdd,
        tau_nominal=commands, segments=data.segments, tau=data.tau, regressor_fn=None,
        nominal=nominal.info if drive is not None and nominal is not None else {}, forward=True, unshifted=drive,
    )


def separability(mode: str, model_effects: Sequence[str], confounded: Sequence[Sequence[str]],
                 sensor: SensorPlacement = DEFAULT_TORQUE_SENSOR) -> dict[str, Any]:
    """What the runs can tell apart (``links`` of ladder.json), as facts: each group of effects with why, a reason's
    kind the report words (:func:`sim2real.report.verdicts.sides_section`).

    ``confounded``: the pairs the diagnosis found predicting the same torque on these data; ``sensor``:
    where ``tau`` is measured.
    """
    out: dict[str, Any] = {"mode": mode, "torque_sensor": str(sensor), "can_tell": [], "cannot_tell": []}

    def told_apart(side: Side) -> list[str]:  # an effect estimated on every run itself is told apart from nothing
        return [name for name in candidates_of_side(side, sensor) if not get_effect(name).per_run]

    if mode == "separate":
        out["can_tell"] = [{"effects": told_apart(Side.DRIVE), "why": "drive_against_command"},
                           {"effects": told_apart(Side.BODY), "why": "body_against_motion"}]
    elif mode == "commands_only":
        out["can_tell"] = [{"effects": ["actuation_delay", "actuation_lag"], "why": "lag_of_whole_torque"},
                           {"effects": ["command_bias"], "why": "constant_torque"}]
        out["cannot_tell"] = [
            {"effects": ["actuator_gain", "link_inertia", "rotor_inertia", "coulomb_friction", "viscous_friction",
                         "asymmetric_friction", "stribeck_friction", "hysteretic_friction", "load_friction",
                         "position_ripple"], "why": "common_gain"},
            {"effects": ["torque_gain", "torque_bias", "sensor_delay", "sensor_lag", "sensor_drift"],
             "why": "no_sensor"},
        ]
    else:
        out["cannot_tell"] = [{"effects": [n for n in candidates_of_side(Side.DRIVE, sensor) if not get_effect(n).drive],
                               "why": "no_command"}]
        dropped = [n for n in model_effects if effect_side(n, sensor) == Side.DRIVE and not get_effect(n).drive]
        if dropped:
            out["cannot_tell"][0]["dropped_from_model"] = dropped
    for pair in confounded:
        out["cannot_tell"].append({"effects": list(pair), "why": "confounded"})
    return out
