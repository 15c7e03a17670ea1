"""Noise floors: the torque RMS no model can explain, measured once when a run is prepared.

* the body link's (:func:`white_noise_sigma`): the white part of the raw torque, from its second differences;
* the actuator link's (:func:`command_white_noise`): what no short filter of the command explains of the
  measured torque.

:func:`noise_floor_of` and :func:`command_floor_of` read them back from a prepared run.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from sim2real import blas
from sim2real.blas import one_blas_thread

# The longest actuation delay the fit allows (sim2real.identification.effects.actuation_delay): the command floor
# regresses on every lag up to it, so the floor holds any delay the fit may find.
MAX_COMMAND_DELAY_S = 0.1

if TYPE_CHECKING:
    from sim2real.measurements.runs import PreparedRun

def white_noise_sigma(x: np.ndarray) -> np.ndarray:
    """Per-column std of the white part of x from second differences (MAD-based, robust to the signal), and at
    least the RMS error of the column's quantum (:func:`quantum`/sqrt(12)): a torque logged in coarse steps (a CSV
    written with few decimals, a current in ADC counts) has second differences that are mostly zero, yet its
    rounding is noise no model explains."""
    d2 = x[2:] - 2 * x[1:-1] + x[:-2]
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    return np.maximum(1.4826 * mad / np.sqrt(6.0), quantum(x) / np.sqrt(12.0))


def quantum(x: np.ndarray) -> np.ndarray:
    """Per column, the smallest nonzero step between consecutive samples (0 for a constant column): the logger's
    resolution where it rounds, a vanishing number where it does not."""
    steps = np.abs(np.diff(x, axis=0))
    return np.array([np.min(column[column > 0]) if np.any(column > 0) else 0.0 for column in steps.T])


@one_blas_thread  # its products' last digits: the same from the rule and from any caller
def command_white_noise(tau: np.ndarray, tau_cmd: np.ndarray, dt: float) -> np.ndarray:
    """Per joint, the RMS of the measured torque ``tau`` that no actuator model can explain from ``tau_cmd``.

    The second differences of ``tau`` are regressed on the second differences of ``tau_cmd`` at every
    lag up to the longest delay the fit allows (a short FIR filter, per joint); what is left is the
    sensor's white noise, measured robustly as :func:`white_noise_sigma` does. The differences remove
    biases and slow motion; the lags hold any delay and gain, so the floor is the same with or without the
    effects it is meant to expose (:mod:`sim2real.identification.sides`'s noise floor).
    """
    chunk = blas.CHUNK_ROWS
    lags = int(round(MAX_COMMAND_DELAY_S / dt)) + 1
    d2_tau = np.diff(tau, n=2, axis=0)
    d2_cmd = np.diff(tau_cmd, n=2, axis=0)
    rows = len(d2_tau) - lags
    floor = np.empty(tau.shape[1])
    for j in range(tau.shape[1]):
        # Row i holds the command's differences at lags 0..lags-1 before sample lags + i (a view, no copy).
        design = np.lib.stride_tricks.sliding_window_view(d2_cmd[:, j], lags)[1 : rows + 1, ::-1]
        target = d2_tau[lags:, j]
        if rows <= chunk:
            gram, rhs = design.T @ design, design.T @ target
        else:  # a long log: its products summed a chunk of rows at a time (whole, numpy copies the view twice)
            gram, rhs = np.zeros((lags, lags)), np.zeros(lags)
            for start in range(0, rows, chunk):
                part = np.ascontiguousarray(design[start : start + chunk])
                gram += part.T @ part
                rhs += part.T @ target[start : start + chunk]
        coef = np.linalg.lstsq(gram, rhs, rcond=None)[0]
        left = target - design @ coef
        floor[j] = 1.4826 * np.median(np.abs(left - np.median(left))) / np.sqrt(6.0)
    return floor


def noise_floor_of(prepared: PreparedRun) -> np.ndarray:
    """Per-joint torque RMS that no model can explain: the white part of the raw torque, as measured when the run
    was prepared (:func:`white_noise_sigma` of the raw, unfiltered, de-duplicated torque, robust to the motion).
    Because the comparison uses the unfiltered torque, a model that explains everything else has a residual RMS
    of about this value."""
    return np.asarray(prepared.raw_torque_sigma, dtype=float).copy()


def command_floor_of(run: PreparedRun) -> np.ndarray:
    """Per joint, the RMS of the measured torque that no actuator model can explain (:func:`command_white_noise`),
    as computed when the run was prepared (a run prepared by an older version, which did not keep it, has it
    computed here)."""
    assert run.tau_cmd is not None and run.torque_source == "tau"
    if run.command_torque_sigma.size:
        return np.asarray(run.command_torque_sigma, dtype=float).copy()
    return command_white_noise(run.tau, run.tau_cmd, run.dt)
