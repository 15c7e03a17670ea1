"""The checks of a designed excitation at every sample of the written trajectory.

Constraints imposed on a grid can be missed between its points by a hair; if any check fails, the motion is
scaled towards the start pose (which every check passes) until all pass, and the report says by how much.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim2real.excitation.clearance import Clearance
from sim2real.excitation.config import Limits
from sim2real.excitation.design.program import _closest_of_each_stretch, _Program
from sim2real.excitation.fourier import FourierSeries
from sim2real.identification.fitting import NominalModel


@dataclass
class Trajectory:
    time: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray


def check_trajectory(nominal: NominalModel, trajectory: Trajectory, lim: Limits, clearance: Clearance,
                     margin: float, excited: np.ndarray) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Every limit at every sample: the failures (empty when none), the torques and the clearances."""
    failures = []
    tol = 1e-9
    q, qd, qdd = trajectory.q, trajectory.qd, trajectory.qdd
    for label, bad in (("position", (q < lim.lower - tol) | (q > lim.upper + tol)),
                       ("velocity", np.abs(qd) > lim.velocity + tol),
                       ("acceleration", np.abs(qdd) > lim.acceleration + tol)):
        bad[:, [j for j in range(q.shape[1]) if j not in excited]] = False
        if bad.any():
            failures.append(label)
    torque = nominal.dynamics.inverse_dynamics(q, qd, qdd)
    if np.any(np.abs(torque) > lim.torque + tol):
        failures.append("torque")
    distances = clearance.distances(q)
    if np.any(distances < margin):
        failures.append("collision")
    return failures, torque, distances


@dataclass(frozen=True)
class _Checked:
    """The designed motion at the controller rate that passed the check at every sample."""

    x: np.ndarray  # the coefficients, scaled
    scale: float
    time: np.ndarray
    one_period: np.ndarray  # which samples of ``time`` are the first period's
    trajectory: Trajectory
    torque: np.ndarray
    distances: np.ndarray  # the clearance at every sample of the first period


def _check_every_sample(program: _Program, x: np.ndarray, log: Callable[[str], None]) -> _Checked:
    """The motion at the controller rate, checked at every sample of one period and scaled towards the start pose
    (by 0.97 a step) until every check passes."""
    settings = program.design.settings
    series, margin, clearance = program.series, program.margin, program.clearance
    rate = float(settings["sample_rate_hz"])
    time = np.arange(int(round(float(settings["duration_s"]) * rate))) / rate
    one_period = time < series.period - 0.5 / rate
    scale = 1.0
    closest: list[int] = []  # the closest sample of each stretch short of clearance in the last check of every sample
    for _ in range(40):
        trajectory = _trajectory(series, x * scale, time, program.start, program.excited, program.n)
        head = _head(trajectory, one_period)
        # A stretch short of clearance mostly stays short over the next steps: its closest samples are looked at
        # first (milliseconds), every sample (seconds) only when they pass. The same steps and scale as checking
        # every sample at every step.
        if closest and np.any(clearance.distances(head.q[closest]) < margin):
            failures = ["collision"]
        else:
            failures, tau, distances = check_trajectory(program.nominal, head, program.lim, clearance, margin,
                                                        program.excited)
            if not failures:
                break
            closest = _closest_of_each_stretch(distances, margin)
        log(f"dense check at {rate:g} Hz failed ({', '.join(failures)}); scaling the motion by {scale * 0.97:.3g}")
        scale *= 0.97
    else:
        raise RuntimeError(f"the design '{program.design.name}' violates {failures} even scaled to {scale:.3g}")
    x = x * scale
    tau = program.nominal.dynamics.inverse_dynamics(trajectory.q, trajectory.qd, trajectory.qdd)
    return _Checked(x, scale, time, one_period, trajectory, tau, distances)


def _head(trajectory: Trajectory, keep: np.ndarray) -> Trajectory:
    return Trajectory(trajectory.time[keep], trajectory.q[keep], trajectory.qd[keep], trajectory.qdd[keep])


def _trajectory(series: FourierSeries, x: np.ndarray, time: np.ndarray, start: np.ndarray, excited: np.ndarray,
                n: int) -> Trajectory:
    q = np.tile(start, (len(time), 1))
    qd, qdd = np.zeros_like(q), np.zeros_like(q)
    qe, qde, qdde = series.motion(x, time, start[excited])
    q[:, excited], qd[:, excited], qdd[:, excited] = qe, qde, qdde
    return Trajectory(time, q, qd, qdd)
