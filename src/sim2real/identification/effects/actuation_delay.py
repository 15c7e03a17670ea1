"""Actuation delay: the torque applied at t is the one commanded at t - d (one global d).

An effect of the actuator link. Against the motion it is only observable when the judged torque is
the command (``tau_cmd``): a joint torque sensor measures the applied torque, which the rigid-body
model explains without any delay; with both logged, the actuator link sees it directly (the measured
torque at t is the command at t - d, :attr:`Signals.forward`). Against the motion, the prediction
of the command at t is the model torque at t + d. d is refined by a bounded scalar search around
the linear fit (variable projection), started from a grid at the sampling step.
MJCF holds it as actuator ``delay``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.measurements.noise import MAX_COMMAND_DELAY_S

from sim2real.identification.effects.base import Effect, ParameterSpec, Signals, correlation_per_joint, per_joint_dict

MAX_DELAY = MAX_COMMAND_DELAY_S  # s: the command noise floor regresses on every lag up to it


def shift_prediction(values: np.ndarray, time: np.ndarray, segments: list[slice], delay: float) -> np.ndarray:
    """values(t + delay) by linear interpolation along time within each run (held at run ends).

    ``values`` has samples on axis 0 and any trailing shape.
    """
    if delay == 0.0:
        return values
    out = np.empty_like(values)
    if out.size == 0:  # no columns to shift (a design of the delay alone): the interpolation would be wasted
        return out
    for seg in segments:
        t = time[seg]
        block = values[seg]
        flat = block.reshape(len(t), -1)
        target = np.clip(t + delay, t[0], t[-1])
        # Uniform grid: fractional index shift is cheaper than np.interp per column.
        pos = np.interp(target, t, np.arange(len(t), dtype=float))
        lo = np.floor(pos).astype(np.intp)
        hi = np.minimum(lo + 1, len(t) - 1)
        w = (pos - lo)[:, None]
        # (1 - w) * flat[lo] + w * flat[hi], its products and sum formed in place (np.take: fancy indexing's
        # rows cost several times more)
        shifted = np.take(flat, lo, axis=0)
        shifted *= 1.0 - w
        ahead = np.take(flat, hi, axis=0)
        ahead *= w
        shifted += ahead
        out[seg] = shifted.reshape(block.shape)
    return out


def best_lag(judged: np.ndarray, predicted: np.ndarray, time: np.ndarray, max_lag: float = MAX_DELAY) -> np.ndarray:
    """Per joint, the lag (s) at which predicted(t + lag) best matches judged(t) (cross-correlation)."""
    dt = float(np.median(np.diff(time))) if len(time) > 1 else 1.0
    max_k = max(1, int(round(max_lag / dt)))
    lags = np.zeros(judged.shape[1])
    for j in range(judged.shape[1]):
        a = judged[:, j] - judged[:, j].mean()
        b = predicted[:, j] - predicted[:, j].mean()
        scores = [float(np.dot(a[: len(a) - k], b[k:])) for k in range(max_k + 1)]
        lags[j] = int(np.argmax(scores)) * dt
    return lags


def time_derivative(values: np.ndarray, time: np.ndarray, segments: list[slice]) -> np.ndarray:
    """d(values)/dt along axis 0 within each run (zero on a run of two samples or fewer)."""
    rate = np.zeros_like(values)
    for seg in segments:
        if seg.stop - seg.start > 2:
            rate[seg] = np.gradient(values[seg], time[seg], axis=0)
    return rate


class TimeShift(Effect):
    """A delay of the whole prediction by one global d in [0, MAX_DELAY] s: no columns, one nonlinear parameter,
    refined from a grid at the sampling step (:mod:`sim2real.identification.fitting.refine`)."""

    time_shift = True
    joint_local = False

    def nonlinear_init(self, signals):
        return np.array([0.0])

    def nonlinear_bounds(self, signals):
        return np.array([0.0]), np.array([MAX_DELAY])

    def values(self, theta, nonlinear, signals, state):
        return {"delay": round(float(nonlinear[0]) if len(nonlinear) else 0.0, 6)}


class ActuationDelay(TimeShift):
    name = "actuation_delay"
    summary = "delay between commanded and applied torque"
    signature = "residual proportional to the time derivative of the torque; commanded torque leads the model"
    nonlinear = (ParameterSpec("delay", "s", 0.0, MAX_DELAY, False, "actuation delay"),)
    link = "actuator"
    needs_commands = True

    def evidence(self, residual, signals):
        rate = time_derivative(signals.tau_nominal, signals.time, signals.segments)
        out: dict[str, Any] = {
            "signature": self.signature,
            "statistic": "correlation of residual with d(tau_model)/dt",
            "per_joint": per_joint_dict(signals.joint_names, correlation_per_joint(residual, rate), 3),
        }
        if signals.tau is not None:
            # The command leads: it is the judged torque, or (forward, the actuator link) the prediction.
            leading, lagging = (signals.tau_nominal, signals.tau) if signals.forward else (signals.tau, signals.tau_nominal)
            out["lag_s"] = per_joint_dict(signals.joint_names, best_lag(leading, lagging, signals.time), 4)
        return out

    def apply_to_spec(self, spec, values, context):
        delay = float(values["delay"])
        if delay <= 0:
            return
        timestep = float(spec.option.timestep)
        for actuator in context.get("actuators", {}).values():
            act = spec.actuator(actuator)
            act.delay = delay
            act.nsample = max(int(np.ceil(delay / timestep)) + 1, 2)
