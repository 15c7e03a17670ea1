"""The shapes of a lag in time, shared by the effects that move the whole prediction in time instead of adding columns
(:class:`TimeShift`): a pure delay (:func:`shift_prediction`; actuation_delay, sensor_delay) and a first-order lag
(:func:`lag_prediction`; actuation_lag, sensor_lag), with the time derivative their evidence and the diagnosis's lag
score use, and the lag between two signals by cross-correlation (:func:`best_lag`).

A delay and a first-order lag of time constant T are the same lag T at frequencies well below 1/T, where an
identification motion lives; they differ where a signal changes within T: a command's noise at 1 kHz passes a delay
whole and a filter attenuated. Both are linear and time-invariant, so the prediction is filtered, then shifted.
"""

from __future__ import annotations

import numpy as np

from sim2real.filters import first_order_lag
from sim2real.identification.effects.base import Effect
from sim2real.measurements.noise import MAX_COMMAND_DELAY_S

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


def lag_prediction(values: np.ndarray, time: np.ndarray, segments: list[slice], time_constant: float) -> np.ndarray:
    """``values`` (samples on axis 0) through a first-order low-pass of ``time_constant`` within each run, each
    starting settled (:func:`sim2real.filters.first_order_lag`, the samples joined linearly: the fit's grid may be
    coarser than the lag); a negative ``time_constant`` applies its inverse, a lead: values + |T| d(values)/dt."""
    if time_constant == 0.0:
        return values
    if time_constant < 0.0:
        return values - time_constant * time_derivative(values, time, segments)
    out = np.empty_like(values)
    for seg in segments:
        t = time[seg]
        dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
        out[seg] = first_order_lag(values[seg], dt, time_constant, between="linear")
    return out


def retime(values: np.ndarray, time: np.ndarray, segments: list[slice], delay: float, time_constant: float,
           ) -> np.ndarray:
    """``values`` as a lag moves them: through the first-order lag (:func:`lag_prediction`), then shifted by
    ``delay`` (:func:`shift_prediction`: values(t + delay))."""
    return shift_prediction(lag_prediction(values, time, segments, time_constant), time, segments, delay)


class TimeShift(Effect):
    """A lag of the whole prediction, one global value in [0, MAX_DELAY] s: a delay, or with ``lowpass`` a
    first-order lag's time constant; no columns, one nonlinear parameter, refined from a grid at the sampling step
    (:mod:`sim2real.identification.fitting.refine`)."""

    time_shift = True
    joint_local = False

    def nonlinear_init(self, signals):
        return np.array([0.0])

    def nonlinear_bounds(self, signals):
        return np.array([0.0]), np.array([MAX_DELAY])

    def values(self, theta, nonlinear, signals, state):
        return {self.nonlinear[0].name: round(float(nonlinear[0]) if len(nonlinear) else 0.0, 6)}
