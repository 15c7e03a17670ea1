"""Coulomb (dry) joint friction: tau_f = F_c * tanh(qd / v_s) per joint.

The smoothing velocity v_s (per joint) is refined by nonlinear least squares: real joints
(harmonic drives, the Gaz et al. sigmoid model of the Panda) show a soft transition through
zero velocity, which a hard sign() would turn into a residual at every reversal.
MJCF holds F_c as joint ``frictionloss``, URDF as ``<dynamics friction>``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.identification.effects.base import (
    ColumnLabel, Effect, ParameterSpec, Signals, Signature, correlation_per_joint, diagonal_columns, per_joint_dict,
)

DEFAULT_SMOOTHING = 0.02  # rad/s: start value of the refinement


class SmoothedSign:
    """A friction law's sign of the velocity, tanh(qd / v) per joint, its smoothing velocity ``v`` refined (on a log
    scale: smoothing velocities span decades) from :data:`DEFAULT_SMOOTHING`."""

    nonlinear = (ParameterSpec("smoothing_velocity", "rad/s", 1e-3, 0.5, True, "tanh transition width"),)

    def nonlinear_init(self, signals):
        return np.full(signals.n, DEFAULT_SMOOTHING)

    def nonlinear_bounds(self, signals):
        return np.full(signals.n, self.nonlinear[0].lower), np.full(signals.n, self.nonlinear[0].upper)

    def nonlinear_log_scale(self, signals):
        return np.ones(signals.n, dtype=bool)

    def sliding(self, signals, nonlinear: np.ndarray) -> np.ndarray:
        """(N, n) tanh(qd / v) at the smoothing ``nonlinear`` (its start where none is given yet)."""
        return np.tanh(signals.qd / (nonlinear if len(nonlinear) else self.nonlinear_init(signals)))


class CoulombFriction(SmoothedSign, Effect):
    drive = True
    in_urdf = True
    name = "coulomb_friction"
    summary = "Coulomb (dry) joint friction, constant magnitude opposing the motion"
    signature = "residual steps with the sign of joint velocity (jumps at reversals)"
    parameters = (ParameterSpec("friction", "N*m", 0.0, 100.0, True, "Coulomb friction torque (total)"),)

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        return diagonal_columns(self.sliding(signals, nonlinear)), [ColumnLabel("friction", j) for j in signals.joint_names]

    def theta_lower(self, signals, size):
        # The total friction (nominal + fitted) is never negative.
        return -np.asarray(signals.nominal.get("friction", np.zeros(signals.n)), dtype=float)

    values_stacked = True

    def values(self, theta, nonlinear, signals, state):
        total = np.asarray(signals.nominal.get("friction", np.zeros(signals.n))) + theta
        smoothing = nonlinear if len(nonlinear) else self.nonlinear_init(signals)
        return {
            "friction": per_joint_dict(signals.joint_names, total, 6),
            "smoothing_velocity": per_joint_dict(signals.joint_names, smoothing, 5),
        }

    def evidence(self, residual, signals):
        return Signature(
            description=self.signature,
            statistic="correlation of residual with sign(qd)",
            per_joint=per_joint_dict(signals.joint_names, correlation_per_joint(residual, np.sign(signals.qd)), 3),
        )

    def apply_to_spec(self, spec, values, context):
        for joint, value in values["friction"].items():
            spec.joint(joint).frictionloss = float(max(value, 0.0))

    def calibration(self, values, calibration):
        for joint, value in values["friction"].items():
            calibration.setdefault("joints", {}).setdefault(joint, {})["friction"] = float(max(value, 0.0))
