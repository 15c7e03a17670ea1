"""Signal filters shared by the lab (a sensor's and a drive's own dynamics) and the fit (the shape of a lag,
:mod:`sim2real.identification.effects.timing`)."""

from __future__ import annotations

import numpy as np


def first_order_lag(values: np.ndarray, dt: float, time_constant: float, between: str = "held") -> np.ndarray:
    """``values`` (samples on axis 0, any trailing shape) at steps of ``dt`` through a first-order low-pass of
    ``time_constant`` s, starting settled at the first value; unchanged at 0. Exact for an input ``between`` samples
    ``"held"`` (a torque a controller holds over its step, as the lab's drives and sensors see it) or ``"linear"``
    (a smooth signal sampled, whatever the step: the fit's prediction on a decimated grid, where a held input's
    discretisation would lag by half a step less than the filter)."""
    if time_constant <= 0.0 or len(values) == 0:
        return values
    from scipy.signal import lfilter, lfilter_zi

    a = float(np.exp(-dt / time_constant))
    if between == "held":
        b = [1.0 - a]
    elif between == "linear":
        c = time_constant / dt * (1.0 - a)
        b = [1.0 - c, c - a]
    else:
        raise ValueError(f"between must be 'held' or 'linear', not {between!r}")
    den = [1.0, -a]
    flat = values.reshape(len(values), -1)
    out = lfilter(b, den, flat, axis=0, zi=lfilter_zi(b, den)[:, None] * flat[:1])[0]
    return out.reshape(values.shape)
