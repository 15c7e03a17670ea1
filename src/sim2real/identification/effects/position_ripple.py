"""A position ripple: a torque periodic in the joint's own position, per joint

    tau_r = a * sin(2 pi q / p) + b * cos(2 pi q / p)  =  A * sin(2 pi q / p + phi)

a motor's cogging (its magnets' detents, seen through the gear) or a gear's ripple (a harmonic drive's
flexspline), one harmonic. ``a`` and ``b`` are linear; the period ``p`` (rad of the joint) is refined, and
because a period has a local minimum at every other one, its start is searched: the period at which one
sinusoid of the joint's position removes most of what the model without it leaves (:func:`best_periods`, a
least-squares periodogram in the position domain). The search covers what the motion resolves: at least two
periods over the joint's excursion, and a period no shorter than :data:`SAMPLES_PER_PERIOD` of the motion's
usual steps between samples (a cogging of a few milliradians needs a fast log and a slow joint).

It sits in the drive (before a link-side torque sensor). MJCF: MuJoCo has no torque periodic in a joint's
position (a spring is linear), so :meth:`PositionRipple.apply_to_spec` writes NOTHING: the simulated joint
lacks the ripple (an honest gap, not an oversight). URDF has no place for it either.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.identification.effects.base import ColumnLabel, Effect, ParameterSpec, Signals, Signature, per_joint_dict

MIN_PERIOD = 0.01  # rad: shorter ripples need more than any arm's log resolves
MAX_PERIOD = 2 * np.pi  # rad: one period per turn of the joint
DEFAULT_PERIOD = 0.5  # rad: where a period starts without a search (never used by a fit: it searches)
SAMPLES_PER_PERIOD = 4  # a searched period spans at least this many of the motion's usual steps
MIN_PERIODS_SEEN = 2  # ... and at least this many periods fit in the joint's excursion
OVERSAMPLING = 5  # frequencies per peak width (1 / excursion) of the search's grid
SEARCH_ROWS = 4000  # the search runs on at most this many samples, evenly spaced (a statement about shape)
GRID_CHUNK = 512  # frequencies turned at once (a full turn's grid is thousands: its rotations are not held whole)


def search_frequencies(q: np.ndarray) -> np.ndarray:
    """The grid of spatial frequencies (cycles per rad) one joint's positions ``q`` resolve, consecutive samples of a
    log (module docstring); empty when the joint hardly moves."""
    q = np.asarray(q, dtype=float)
    if q.size < 8:
        return np.zeros(0)
    excursion = float(np.ptp(q))
    step = float(np.percentile(np.abs(np.diff(q)), 90))  # what the log resolves, whatever the search then uses
    lowest = max(MIN_PERIODS_SEEN / excursion if excursion > 0 else np.inf, 1.0 / MAX_PERIOD)
    highest = min(1.0 / (SAMPLES_PER_PERIOD * step) if step > 0 else np.inf, 1.0 / MIN_PERIOD)
    if not lowest < highest:
        return np.zeros(0)
    return np.arange(lowest, highest, 1.0 / (OVERSAMPLING * excursion))


def position_periodogram(q: np.ndarray, y: np.ndarray, frequencies: np.ndarray) -> np.ndarray:
    """The energy of ``y`` (its mean removed) that one sinusoid of ``q`` at each frequency of an evenly spaced grid
    (cycles per rad) removes,
    by least squares with the sinusoid's mean removed too (the generalised Lomb-Scargle periodogram, on positions
    instead of times: the samples fall anywhere in the period)."""
    frequencies = np.asarray(frequencies, dtype=float)
    if frequencies.size > GRID_CHUNK:
        return np.concatenate([position_periodogram(q, y, frequencies[k:k + GRID_CHUNK])
                               for k in range(0, frequencies.size, GRID_CHUNK)])
    q = np.asarray(q, dtype=float)
    y = np.asarray(y, dtype=float) - float(np.mean(y))
    count = q.size
    if frequencies.size == 0:
        return np.zeros(0)
    # cos + i sin, (N, F): the grid is even, so each frequency's is the last one's turned by one step (a product, not
    # an exponential: a quarter of the time, within 1e-13 over a chunk of the grid)
    rotation = np.empty((count, frequencies.size), dtype=complex)
    rotation[:, 0] = np.exp(2j * np.pi * q * frequencies[0])
    if frequencies.size > 1:
        rotation[:, 1:] = np.exp(2j * np.pi * q * (frequencies[1] - frequencies[0]))[:, None]
        np.cumprod(rotation, axis=1, out=rotation)
    total = rotation.sum(axis=0)
    doubled = (rotation * rotation).sum(axis=0)  # cos(2x) + i sin(2x)
    weighted = y @ rotation
    mean_c, mean_s = total.real / count, total.imag / count
    cc = (count + doubled.real) / 2 - count * mean_c**2
    ss = (count - doubled.real) / 2 - count * mean_s**2
    cs = doubled.imag / 2 - count * mean_c * mean_s
    yc, ys = weighted.real, weighted.imag
    det = cc * ss - cs**2
    with np.errstate(invalid="ignore", divide="ignore"):
        gain = np.where(det > 1e-12 * np.maximum(cc * ss, 1e-300),
                        (ss * yc**2 - 2 * cs * yc * ys + cc * ys**2) / det, 0.0)
    return np.clip(gain, 0.0, None)


def best_periods(q: np.ndarray, residual: np.ndarray, max_rows: int = SEARCH_ROWS) -> tuple[np.ndarray, np.ndarray]:
    """Per joint (columns of ``q`` and ``residual``, (N, n)): the period (rad) at which one sinusoid of the joint's
    position removes most of its residual, and the energy it removes (the residual's units squared, summed over
    the samples used, scaled to all ``N``). A joint whose motion resolves no period keeps :data:`DEFAULT_PERIOD`
    and removes nothing. The periods searched are those the log resolves (:func:`search_frequencies` on every
    sample); a long log is searched on ``max_rows`` of its samples, evenly spaced: in the position domain they fall
    anywhere in a period, so fewer of them resolve the same periods."""
    q, residual = np.asarray(q, dtype=float), np.asarray(residual, dtype=float)
    rows = np.arange(0, q.shape[0], max(1, -(-q.shape[0] // max_rows)))
    periods, gains = np.full(q.shape[1], DEFAULT_PERIOD), np.zeros(q.shape[1])
    for j in range(q.shape[1]):
        frequencies = search_frequencies(q[:, j])
        if frequencies.size == 0:
            continue
        removed = position_periodogram(q[rows, j], residual[rows, j], frequencies)
        best = int(np.argmax(removed))
        periods[j] = 1.0 / frequencies[best]
        gains[j] = float(removed[best]) * q.shape[0] / rows.size
    return periods, gains


class PositionRipple(Effect):
    drive = True
    in_urdf = False
    in_design = False
    searched = True
    name = "position_ripple"
    summary = "a torque periodic in the joint's own position (a motor's cogging, a gear's ripple), one harmonic"
    signature = "residual that repeats with the joint's own position, the same wherever and however fast the joint passes"
    parameters = (
        ParameterSpec("ripple_sin", "N*m", -100.0, 100.0, True, "a: the sine's coefficient"),
        ParameterSpec("ripple_cos", "N*m", -100.0, 100.0, True, "b: the cosine's coefficient"),
    )
    nonlinear = (ParameterSpec("period", "rad", MIN_PERIOD, MAX_PERIOD, True, "p: the ripple's period in the joint's position"),)
    values_stacked = True

    def nonlinear_init(self, signals):
        return np.full(signals.n, DEFAULT_PERIOD)

    def nonlinear_bounds(self, signals):
        return np.full(signals.n, MIN_PERIOD), np.full(signals.n, MAX_PERIOD)

    def nonlinear_log_scale(self, signals):
        return np.ones(signals.n, dtype=bool)

    def search_start(self, signals: Signals, residual: np.ndarray) -> np.ndarray:
        """The periods to refine from, given what the model without the ripple leaves (:func:`best_periods`)."""
        return best_periods(signals.q, residual)[0]

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        period = nonlinear if len(nonlinear) else self.nonlinear_init(signals)
        angle = 2 * np.pi * signals.q / period
        samples, n = signals.q.shape
        cols = np.zeros((samples, n, 2 * n))
        joints = np.arange(n)
        cols[:, joints, joints] = np.sin(angle)
        cols[:, joints, n + joints] = np.cos(angle)
        labels = ([ColumnLabel("ripple_sin", j) for j in signals.joint_names]
                  + [ColumnLabel("ripple_cos", j) for j in signals.joint_names])
        return cols, labels

    def values(self, theta, nonlinear, signals, state):
        period = nonlinear if len(nonlinear) else self.nonlinear_init(signals)
        theta = np.asarray(theta, dtype=float)
        a, b = theta[..., : signals.n], theta[..., signals.n :]
        return {
            "amplitude": per_joint_dict(signals.joint_names, np.hypot(a, b), 6),
            "phase": per_joint_dict(signals.joint_names, np.arctan2(b, a), 4),
            "period": per_joint_dict(signals.joint_names, period, 5),
        }

    def evidence(self, residual, signals):
        _, removed = best_periods(signals.q, residual)
        energy = np.sum((residual - residual.mean(axis=0)) ** 2, axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            share = np.where(energy > 0, removed / energy, 0.0)
        return Signature(
            description=self.signature,
            statistic="share of the residual one sinusoid of the joint's own position removes, at the period that "
            "removes most (a least-squares periodogram over the periods the motion resolves)",
            per_joint=per_joint_dict(signals.joint_names, np.clip(share, 0.0, 1.0), 3),
        )

    def apply_to_spec(self, spec, values, context):
        """MuJoCo has no torque periodic in a joint's position: nothing is written (the simulation lacks it)."""

    def calibration(self, values, calibration):
        """URDF has no position ripple: nothing is written."""
