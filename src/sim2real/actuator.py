"""The two links of the model: the actuator (command -> applied torque) and the body (applied torque -> motion).

Every effect declares its link (:attr:`sim2real.effects.base.Effect.link`). What the runs log decides
how the links can be judged (:func:`link_mode`):

* ``separate``: a joint torque sensor (``tau``) beside the command (``tau_cmd``). The body link is the
  rigid-body ladder on ``tau`` against the motion. The actuator link is judged directly, the measured
  torque against the command: no dynamics, so no body error leaks into it. Through the fitting core
  (:mod:`sim2real.fitting`), with the command in the place of the nominal model's prediction
  (:attr:`sim2real.effects.Signals.forward`)::

      tau(t) = g * tau_cmd(t - d) + b + sensor noise

  so ``actuation_delay``, ``actuator_gain`` and ``command_bias`` are the same effect classes as on runs
  without a sensor. The command is known exactly, so the noise is all in the judged torque and the
  least squares are unbiased. The link is fitted on every sample (no decimation): a delay of a few ms
  is a few samples.
* ``commands_only``: no torque sensor (most arms). One ladder on ``tau_cmd`` against the motion holds
  both links; :func:`separability` says what these data can and cannot tell apart.
* ``sensor_only``: no commands. The body link only; the actuator cannot be seen.

The actuator link's noise floor is the white part of the measured torque that no linear filter of the
command explains (:func:`command_noise_floor`): a controller's command carries white noise of its own
(velocity noise through its gains), which reaches the sensor through the motor, delayed and scaled.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from sim2real.effects import EFFECTS, Signals, get_effect
from sim2real.effects.actuation_delay import MAX_DELAY
from sim2real.fitting import TorqueData, run_from_prepared, stack_runs
from sim2real.measurements import PreparedRun

LINK_MODES: dict[str, str] = {
    "separate": "the runs log the measured torque (tau) and the command (tau_cmd): the actuator link is judged "
    "on tau against tau_cmd, the body link on tau against the motion",
    "commands_only": "the runs log only the command (tau_cmd): the actuator and the body are judged together, "
    "on tau_cmd against the motion",
    "sensor_only": "the runs log only the measured torque (tau): the body link is judged on tau against the "
    "motion; the actuator (command -> applied torque) cannot be seen",
}

# The actuator link is fitted on every sample: a delay of a few ms is a few samples.
ACTUATOR_FIT_SETTINGS: dict[str, Any] = {"fit_rate_hz": None, "refine_max_samples": 10**9}


def link_mode(runs: Sequence[PreparedRun]) -> str:
    """``separate``, ``commands_only`` or ``sensor_only`` (see the module docstring) for a set of runs."""
    has_sensor = all(run.torque_source == "tau" for run in runs)
    has_commands = all(run.tau_cmd is not None for run in runs)
    if has_sensor and has_commands:
        return "separate"
    return "sensor_only" if has_sensor else "commands_only"


def effects_of_link(effect_names: Sequence[str], link: str) -> list[str]:
    """The effects of ``link`` among ``effect_names``, in their order."""
    return [name for name in effect_names if get_effect(name).link == link]


def candidates_of_link(link: str) -> list[str]:
    """The library's effects the diagnosis tries on ``link`` (``combined``: all of them)."""
    return [name for name, effect in EFFECTS.items() if link == "combined" or effect.link == link]


def command_noise_floor(run: PreparedRun) -> np.ndarray:
    """Per joint, the RMS of the measured torque that no actuator model can explain.

    The second differences of ``tau`` are regressed on the second differences of ``tau_cmd`` at every
    lag up to the longest delay the fit allows (a short FIR filter, per joint); what is left is the
    sensor's white noise, measured robustly as :func:`sim2real.measurements.white_noise_sigma` does.
    The differences remove biases and slow motion; the lags hold any delay and gain, so the floor is the
    same with or without the effects it is meant to expose.
    """
    assert run.tau_cmd is not None and run.torque_source == "tau"
    lags = int(round(MAX_DELAY / run.dt)) + 1
    d2_tau = np.diff(run.tau, n=2, axis=0)
    d2_cmd = np.diff(run.tau_cmd, n=2, axis=0)
    rows = len(d2_tau) - lags
    floor = np.empty(run.tau.shape[1])
    for j in range(run.tau.shape[1]):
        # Row i holds the command's differences at lags 0..lags-1 before sample lags + i (a view, no copy).
        design = np.lib.stride_tricks.sliding_window_view(d2_cmd[:, j], lags)[1 : rows + 1, ::-1]
        target = d2_tau[lags:, j]
        coef = np.linalg.lstsq(design.T @ design, design.T @ target, rcond=None)[0]
        left = target - design @ coef
        floor[j] = 1.4826 * np.median(np.abs(left - np.median(left))) / np.sqrt(6.0)
    return floor


def actuator_data(runs: Sequence[PreparedRun], joint_names: Sequence[str]) -> tuple[TorqueData, np.ndarray]:
    """The actuator link's data on every sample: the measured torque as the judged torque (``TorqueData``,
    with the link's noise floor) and the command it is predicted from, stacked alike."""
    judged, commands = [], []
    for run in runs:
        assert run.tau_cmd is not None
        record = run_from_prepared(run, command_noise_floor(run))
        judged.append(record)
        commands.append({**record, "tau": run.tau_cmd})
    rate = ACTUATOR_FIT_SETTINGS["fit_rate_hz"]
    return stack_runs(judged, joint_names, rate), stack_runs(commands, joint_names, rate).tau


def actuator_signals(data: TorqueData, commands: np.ndarray) -> Signals:
    """Signals of the actuator link: the command stands where the body link has the nominal model."""
    return Signals(
        joint_names=list(data.joint_names), time=data.time, q=data.q, qd=data.qd, qdd=data.qdd,
        tau_nominal=commands, segments=data.segments, tau=data.tau, regressor_fn=None, nominal={}, forward=True,
    )


def separability(mode: str, model_effects: Sequence[str], confounded: Sequence[Sequence[str]]) -> dict[str, Any]:
    """What the runs can tell apart (``links`` of ladder.json): the mode in words, then the facts.

    ``confounded``: the pairs the diagnosis found predicting the same torque on these data.
    """
    out: dict[str, Any] = {"mode": mode, "text": LINK_MODES[mode], "can_tell": [], "cannot_tell": []}
    if mode == "separate":
        out["can_tell"] = [
            {"effects": ["actuation_delay", "actuator_gain", "command_bias"],
             "why": "judged on the measured torque against the command: no body effect enters that link"},
            {"effects": [n for n, e in EFFECTS.items() if e.link == "body"],
             "why": "judged on the measured torque against the motion: no actuator effect enters that link"},
        ]
    elif mode == "commands_only":
        out["can_tell"] = [
            {"effects": ["actuation_delay"],
             "why": "a time shift of the whole torque, which no body effect makes; the replay of each rung "
             "(replay position RMSE) shows it in the state domain too"},
            {"effects": ["command_bias"],
             "why": "a constant torque per joint; no body effect of the library is constant"},
        ]
        out["cannot_tell"] = [
            {"effects": ["actuator_gain", "link_inertia", "rotor_inertia", "coulomb_friction", "viscous_friction"],
             "why": "a motor gain g common to all joints moves the arm exactly as the body with every torque "
             "scaled by 1/g (masses, inertias, armature and friction together): in the torque domain and in "
             "the replay alike. Only per-joint differences of the gain show. A joint torque sensor (tau) "
             "separates them"},
            {"effects": ["torque_gain", "torque_bias"],
             "why": "errors of a torque sensor, and these runs have none: not tried"},
        ]
    else:
        out["cannot_tell"] = [
            {"effects": [n for n, e in EFFECTS.items() if e.link == "actuator"],
             "why": "the runs log no command (tau_cmd), so the actuator link is not seen: not fitted, not tried"},
        ]
        dropped = [n for n in model_effects if get_effect(n).link == "actuator"]
        if dropped:
            out["cannot_tell"][0]["dropped_from_model"] = dropped
    for pair in confounded:
        out["cannot_tell"].append({
            "effects": list(pair),
            "why": "on these runs their fitted models predict the same torque (within a tenth of the noise floor)",
        })
    return out
