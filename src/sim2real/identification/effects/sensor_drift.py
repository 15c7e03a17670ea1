"""A torque sensor whose offset drifts within each run: a warm-up, an offset that wanders, a sensor zeroed anew
whenever the arm starts. Per joint and run, a quadratic and two settling exponentials in the time within the run

    tau_judged = tau + c0 + c1 P1(s) + c2 P2(s) + c3 exp(-t'/(T/16)) + c4 exp(-t'/(T/4))

(s the run's time scaled to [-1, 1], Legendre polynomials; t' the time since the run began, T its length) with
coefficients of each run's own. A sensor warming up settles as an exponential: over a run several of its time
constants long, a quadratic alone leaves the first seconds' settling, which a later candidate then takes for a
property of the robot (a hysteretic friction on the lab's ``drift`` arm, which settles in 6 s of a 20 s run); the
two exponentials, a sixteenth and a quarter of the run, hold a fast and a slow settling whatever the run's length,
and being monotone they take less of the motion than more powers of time would.

They are no property of the robot and cannot carry over from one run to
another, so they are not fitted on the fit runs and applied to the holdout: **every run's are estimated on that
run itself**, the holdout runs included, by projecting them out of the judged torque and of every column of the
model (:func:`remove_runs`, which :class:`sim2real.identification.fitting.problem._Problem` applies: the fit then
solves for the robot's parameters with each run's drift profiled out). No held-out run can therefore judge this effect, and the diagnosis never proposes it as a candidate: the
model-free ceiling says when each run's offsets call for it, and the user declares it. Nothing is written into
MJCF or URDF (a measurement effect), and the excitation design leaves it out.

A drift of this shape also takes the slowest part of what the motion explains when a run is short
(one period of a slow excitation): declared without a drift, it flatters the model a little; the gap report's
replay, in the state domain, never uses it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sim2real.identification.effects.base import Effect, Signals, Signature, per_joint_dict

DEGREE = 2  # an offset, a slope and a bend per joint and run
SETTLING = (1 / 16, 1 / 4)  # the settling exponentials' time constants, as fractions of the run's length
SHAPE = "a quadratic and two settling exponentials in the run's time, per joint"


def run_bases(time: np.ndarray, segments: Sequence[slice], degree: int = DEGREE,
              settling: Sequence[float] = SETTLING) -> list[tuple[slice, np.ndarray]]:
    """Per run (segment), an orthonormal basis (rows of the run x functions) of the drift's shapes in its time: the
    Legendre polynomials of ``degree`` of the run's time scaled to [-1, 1] and the exponentials settling with time
    constants ``settling`` x the run's length, orthonormalised (QR); a run of too few samples for all of them keeps
    the polynomials."""
    bases = []
    for segment in segments:
        t = np.asarray(time[segment], dtype=float)
        if t.size == 0:
            continue
        span = max(float(t[-1] - t[0]), 1e-12)
        shapes = np.polynomial.legendre.legvander(2.0 * (t - t[0]) / span - 1.0, min(degree, t.size - 1))
        if t.size > shapes.shape[1] + len(settling):
            shapes = np.column_stack([shapes, *(np.exp(-(t - t[0]) / (fraction * span)) for fraction in settling)])
        basis, _ = np.linalg.qr(shapes)
        bases.append((segment, basis))
    return bases


def remove_runs(values: np.ndarray, bases: Sequence[tuple[slice, np.ndarray]],
                rows: np.ndarray | None = None) -> np.ndarray:
    """``values`` (samples first: (N, n) or (N, n, k)) less their least-squares polynomial in each run's time, for
    every joint and column apart (:func:`run_bases`); ``rows``: only those joints' (a line kept on some joints,
    ``- sensor_drift: {joints: [...]}``; None: every joint's)."""
    out = np.array(values, dtype=float)
    if rows is not None and not len(rows):
        return out
    for segment, basis in bases:
        block = out[segment] if rows is None else out[segment][:, rows]
        flat = block.reshape(block.shape[0], -1)
        flat -= basis @ (basis.T @ flat)
        if rows is None:
            out[segment] = flat.reshape(block.shape)
        else:
            out[segment, rows] = flat.reshape(block.shape)
    return out


class SensorDrift(Effect):
    name = "sensor_drift"
    summary = "the torque sensor's offset drifting within each run (a warm-up), estimated on every run itself"
    signature = "a residual that settles or wanders with time within each run, to a level of each run's own"
    sensor_side = True
    in_design = False
    # Estimated on every run itself (holdout runs too) instead of fitted and carried over: no held-out judgement.
    per_run = True
    # Whichever side is judged, its judged torque is the drifting sensor's reading.
    every_side = True

    @property
    def per_joint_line(self) -> bool:
        """Each joint's drift is its own sensor's: a line may keep it on some joints (``- sensor_drift: {joints:
        [...]}``), the others' readings then taken as they are."""
        return True

    def values(self, theta, nonlinear, signals, state):
        # Words, not numbers: each run's coefficients are that run's alone, nothing an asset or another run can use
        # (and nothing the bootstrap gives an interval).
        return {"shape": SHAPE,
                "estimated_on": "every run itself, the holdout runs included"}

    def evidence(self, residual: np.ndarray, signals: Signals) -> Signature:
        residual = np.asarray(residual, dtype=float)
        after = remove_runs(residual, run_bases(signals.time, signals.segments))
        energy = np.sum(residual**2, axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            share = np.where(energy > 0, 1.0 - np.sum(after**2, axis=0) / energy, 0.0)
        return Signature(
            description=self.signature,
            statistic=f"share of the residual's energy removed by {SHAPE} of each run's own",
            per_joint=per_joint_dict(signals.joint_names, share, 3),
        )
