"""Noise floors: the torque RMS no model can explain, measured once when a run is prepared.

* the body link's (:func:`white_noise_sigma`): the white part of the raw torque, from its second differences;
* the actuator link's (:func:`command_white_noise`): what no short filter of the command explains of the
  measured torque.

:func:`noise_floor_of` and :func:`command_floor_of` read them back from a prepared run.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from math import comb
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sim2real import blas
from sim2real.blas import one_blas_thread
from sim2real.measurements.records import DIFFERENCE_ORDERS, NoiseFloorRecord

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
    return command_floor_where_measured(command_white_noise(run.tau, run.tau_cmd, run.dt), run)


# The floor is the differences' (as always) unless the log shows it is not white, by both of: the estimates fall
# with the order (the 5th below this share of the 2nd: a white torque's are within 1.5 % of each other either way
# on the lab's 8 s runs, the lab's 25 Hz smoothing logged at 200 Hz falls by 3-13 %) and the torque's spectrum holds
# more noise than the differences see (above this multiple of the 2nd: 0.98-1.08 on a white torque, 1.4-1.8 at
# 200 Hz, about 3 at 1 kHz). Either alone is no proof: a white torque's orders wander by a percent, and a motion's
# sharp friction puts some torque into the spectrum above its band.
FALLING_ORDERS = 0.99
SPECTRUM_OVER_DIFFERENCES = 1.25
# A column is held when more than this share of its consecutive samples are equal and its steps are no multiples of
# one quantum (a rounded column's are: its floor is its rounding, :func:`white_noise_sigma`).
HELD_SHARE = 0.5
# Steps within this fraction of a whole number of quanta are rounding's.
QUANTUM_TOLERANCE = 0.01
# A rounding logger's steps are a few quanta (its floor is about one quantum); a column whose median step is more
# quanta than this holds a finer signal, its smallest step the file's last printed digit, not a logger's quantum.
MAX_ROUNDED_STEP = 20.0


@dataclass(frozen=True)
class MeasuredFloor:
    """A run's noise floor per joint (N*m RMS) and, where any joint's is not the differences', how it was measured."""

    sigma: np.ndarray
    record: NoiseFloorRecord | None


def difference_sigmas(x: np.ndarray, orders: Sequence[int] = DIFFERENCE_ORDERS) -> np.ndarray:
    """(len(orders), n): per column, the white noise's std estimated from differences of each order (MAD-based, each
    normalised by the order's noise gain sqrt(C(2k, k))). White noise gives the same at every order."""
    out = []
    for order in orders:
        d = np.diff(x, n=order, axis=0)
        mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
        out.append(1.4826 * mad / np.sqrt(float(comb(2 * order, order))))
    return np.array(out)


def spectrum_noise_sigma(x: np.ndarray, rate_hz: float, motion_band_hz: float) -> np.ndarray | None:
    """Per column, the RMS of the noise the log holds, from its spectrum: the torque above the motion's band (a
    zero-phase high-pass at half of it removes the motion's own torque, so no window leaks it), its Welch spectrum
    integrated from ``motion_band_hz`` to the Nyquist frequency (wherever the sensor chain cuts it off), and below
    the band the median level of the octave above it, the noise's plateau the chain's low-pass leaves flat. Survives
    a smoothing, a hold or an upsampling, which all keep the noise's power where differences lose it; None when the
    log is too slow to hold that octave below its Nyquist frequency."""
    from scipy import signal

    nyquist = 0.5 * rate_hz
    if 2.0 * motion_band_hz >= nyquist or len(x) < 8 * rate_hz / motion_band_hz:
        return None
    sos = signal.butter(4, 0.5 * motion_band_hz, btype="high", fs=rate_hz, output="sos")
    above = signal.sosfiltfilt(sos, x, axis=0)
    segment = int(2 ** np.ceil(np.log2(8.0 * rate_hz / motion_band_hz)))  # bins of at most an eighth of the band
    freq, density = signal.welch(above, fs=rate_hz, nperseg=min(segment, len(x)), axis=0, detrend="linear")
    plateau = np.median(density[(freq >= motion_band_hz) & (freq <= 2.0 * motion_band_hz)], axis=0)
    band = freq >= motion_band_hz
    return np.sqrt(plateau * motion_band_hz + np.trapezoid(density[band], freq[band], axis=0))


def _held(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column: the share of consecutive samples that are equal, and whether the column is held (:data:`HELD_SHARE`,
    its steps no multiples of one quantum)."""
    steps = np.abs(np.diff(x, axis=0))
    equal = np.mean(steps == 0, axis=0)
    held = np.zeros(x.shape[1], dtype=bool)
    for j, column in enumerate(steps.T):
        moved = column[column > 0]
        if equal[j] > HELD_SHARE and moved.size:
            ratio = moved / moved.min()
            held[j] = (np.median(ratio) > MAX_ROUNDED_STEP
                       or np.median(np.abs(ratio - np.round(ratio))) > QUANTUM_TOLERANCE)
    return equal, held


def measured_noise_floor(torque: np.ndarray, distinct: np.ndarray, rate_hz: float, motion_band_hz: float,
                         stated: np.ndarray | None = None, stated_reason: str | None = None) -> MeasuredFloor:
    """A run's noise floor per joint from its raw torque (N, n) at ``rate_hz`` (``distinct``: the rows that are not
    a whole repeat of the previous one). Where differences of increasing order agree, the white part
    (:func:`white_noise_sigma` of the distinct rows, exactly as always: ``differences``, or ``rounding`` where the
    logger's quantum sets it); where they fall with the order and the spectrum holds more (:data:`FALLING_ORDERS`,
    :data:`SPECTRUM_OVER_DIFFERENCES`), the spectrum's (:func:`spectrum_noise_sigma`, ``spectrum``); where the
    column is held (:data:`HELD_SHARE`), the same judged on the joint's own updates (``updates``: their white part;
    ``spectrum``: their spectrum, when they are smoothed too); where the run's metadata states one (``stated``,
    with its reason), that."""
    white = white_noise_sigma(torque[distinct])
    orders = difference_sigmas(torque[distinct])
    equal, held = _held(torque)
    rounding = quantum(torque[distinct]) / np.sqrt(12.0) >= white
    spectrum = spectrum_noise_sigma(torque, rate_hz, motion_band_hz)
    method = np.where(rounding, "rounding", "differences").astype(object)
    sigma = white.copy()
    if spectrum is not None:
        smoothed = _smoothed(orders, spectrum) & ~rounding
        method[smoothed], sigma[smoothed] = "spectrum", spectrum[smoothed]
    for j in np.flatnonzero(held):
        method[j], sigma[j] = _held_floor(torque[:, j], rate_hz, motion_band_hz)
    if stated is not None:
        method[:], sigma = "stated", np.asarray(stated, dtype=float).copy()
    if np.all(method == "differences"):
        return MeasuredFloor(sigma, None)
    return MeasuredFloor(sigma, NoiseFloorRecord(
        tuple(str(m) for m in method), tuple(tuple(float(v) for v in row) for row in orders),
        tuple(float(v) for v in equal), None if spectrum is None else tuple(float(v) for v in spectrum),
        float(motion_band_hz), stated_reason))


def _smoothed(orders: np.ndarray, spectrum: np.ndarray) -> np.ndarray:
    """Per column: differences of increasing order fall (:data:`FALLING_ORDERS`) and the spectrum holds more noise
    than they see (:data:`SPECTRUM_OVER_DIFFERENCES`): the log's noise is not white."""
    return (orders[-1] < FALLING_ORDERS * orders[0]) & (spectrum > SPECTRUM_OVER_DIFFERENCES * orders[0])


def _held_floor(column: np.ndarray, rate_hz: float, motion_band_hz: float) -> tuple[str, float]:
    """A held column's floor, from its own updates (the samples where it changes, at their mean rate): their white
    part where their differences agree (``updates``), else their spectrum's (``spectrum``). Judged on every logged
    sample, the hold's steps would count the motion between updates as noise."""
    updates = column[np.concatenate([[True], column[1:] != column[:-1]])][:, None]
    rate = rate_hz * len(updates) / len(column)
    orders = difference_sigmas(updates)
    spectrum = spectrum_noise_sigma(updates, rate, motion_band_hz)
    if spectrum is not None and _smoothed(orders, spectrum)[0]:
        return "spectrum", float(spectrum[0])
    return "updates", float(white_noise_sigma(updates)[0])


def floor_methods(prepared: PreparedRun) -> tuple[str, ...]:
    """Per joint, how the run's noise floor was measured (:class:`NoiseFloorRecord`; ``differences`` where the
    preparation kept no record: every joint's floor is the white part)."""
    record = prepared.filter.noise_floor if prepared.filter is not None else None
    return record.method if record is not None else ("differences",) * len(prepared.joint_names)


def stated_noise_floor(stated: Any, joints: Sequence[str], path: Path | None) -> tuple[np.ndarray | None, str | None]:
    """The floor a run's metadata states (``noise_floor: {torque_nm, reason}``, schemas/measurement.schema.yaml):
    per joint (a number for every joint, or ``{joint: N*m}`` naming each), and its reason; (None, None) without."""
    from sim2real.errors import InputError

    if stated is None:
        return None, None
    value = stated["torque_nm"]
    if isinstance(value, Mapping):
        missing = [j for j in joints if j not in value]
        unknown = [k for k in value if k not in joints]
        if missing or unknown:
            raise InputError(path, "noise_floor/torque_nm", f"names {', '.join(unknown) or 'no'} unknown joint(s) and "
                             f"misses {', '.join(missing) or 'none'}", f"give a floor for each of {', '.join(joints)}")
        return np.array([float(value[j]) for j in joints]), str(stated["reason"])
    return np.full(len(joints), float(value)), str(stated["reason"])


def floor_method_document(prepared: Sequence[PreparedRun], joints: Sequence[str]) -> dict[str, Any]:
    """gap.json's ``noise_floor.method`` (per joint, how its floor was measured: the runs' method, or theirs joined by
    ``+`` where they differ) and ``noise_floor.evidence`` (per run whose floor is not the differences' white part on
    every joint, the figures that chose it: equal consecutive samples, the differences' estimates of orders 2 to 5,
    the spectrum's; absent when there is none)."""
    methods = [floor_methods(p) for p in prepared]
    per_joint = {j: "+".join(sorted({m[i] for m in methods})) for i, j in enumerate(joints)}
    evidence = []
    for run, method in zip(prepared, methods, strict=True):
        record = run.filter.noise_floor if run.filter is not None else None
        if record is None:
            continue
        evidence.append({"run": run.name, "stated_reason": record.stated_reason, "joints": {j: {
            "method": method[i], "floor": float(run.raw_torque_sigma[i]), "equal_steps": record.equal_steps[i],
            "held": record.equal_steps[i] > HELD_SHARE and method[i] in ("updates", "spectrum"),
            "differences": [row[i] for row in record.differences],
            "spectrum": None if record.spectrum is None else record.spectrum[i]} for i, j in enumerate(joints)}})
    return {"method": per_joint, **({"evidence": evidence} if evidence else {})}


def command_floor_where_measured(command_floor: np.ndarray, run: PreparedRun) -> np.ndarray:
    """The actuator link's floor (:func:`command_white_noise`, per joint), but the run's own floor where that was not
    the differences' white part (:func:`floor_methods`: a smoothed or held torque, a stated floor): the command floor
    is taken from the same differences, which do not measure such a log's noise either."""
    methods = floor_methods(run)
    measured = np.array([m not in ("differences", "rounding") for m in methods])
    return np.where(measured, noise_floor_of(run), command_floor)
