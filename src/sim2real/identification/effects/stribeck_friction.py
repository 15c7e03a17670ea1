"""Stribeck friction: static friction above the Coulomb level at low speed, per joint

    tau_f = (F_s - F_c) * exp(-(qd / v_st)^2) * tanh(qd / v_tanh)

a hump of height ``F_s - F_c`` (the peak above Coulomb friction, ``>= 0``) that decays over the
Stribeck velocity ``v_st`` (refined in log scale). ``v_tanh`` is fixed at
:data:`SIGN_SMOOTHING` (a smoothed sign: the hump is zero at rest). It sits on top of the Coulomb
(``coulomb_friction``) and viscous terms; actuator studies find it wherever load varied.

MJCF: MuJoCo has no Stribeck friction (joint ``frictionloss`` is a constant dry friction), so
:meth:`StribeckFriction.apply_to_spec` writes NOTHING: the simulated joint lacks the hump (an honest
gap, not an oversight). URDF has no place for it either (``in_urdf = False``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.identification.effects.base import (
    ColumnLabel, Effect, ParameterSpec, Signals, Signature, correlation_per_joint, diagonal_columns, per_joint_dict,
)

SIGN_SMOOTHING = 0.005  # rad/s: v_tanh, the smoothed sign of the hump
DEFAULT_STRIBECK_VELOCITY = 0.05  # rad/s: start value of the refinement


def stribeck_hump(qd: np.ndarray, stribeck_velocity: np.ndarray) -> np.ndarray:
    """exp(-(qd/v_st)^2) * tanh(qd/v_tanh), (N, n)."""
    return np.exp(-((qd / stribeck_velocity) ** 2)) * np.tanh(qd / SIGN_SMOOTHING)


class StribeckFriction(Effect):
    drive = True
    in_urdf = False
    name = "stribeck_friction"
    summary = "Stribeck friction, static friction above the Coulomb level that decays with speed"
    signature = "residual humps with the sign of joint velocity at low speed (breakaway), gone at higher speed"
    parameters = (
        ParameterSpec("stribeck_peak", "N*m", 0.0, 100.0, True, "F_s - F_c: static minus Coulomb friction"),
    )
    nonlinear = (
        ParameterSpec("stribeck_velocity", "rad/s", 0.005, 0.5, True, "v_st: decay velocity of the hump"),
    )

    def nonlinear_init(self, signals):
        return np.full(signals.n, DEFAULT_STRIBECK_VELOCITY)

    def nonlinear_bounds(self, signals):
        return np.full(signals.n, self.nonlinear[0].lower), np.full(signals.n, self.nonlinear[0].upper)

    def nonlinear_log_scale(self, signals):
        return np.ones(signals.n, dtype=bool)

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        velocity = nonlinear if len(nonlinear) else self.nonlinear_init(signals)
        return (
            diagonal_columns(stribeck_hump(signals.qd, velocity)),
            [ColumnLabel("stribeck_peak", j) for j in signals.joint_names],
        )

    def theta_lower(self, signals, size):
        return np.zeros(size)  # static friction is not below the Coulomb level

    values_stacked = True

    def values(self, theta, nonlinear, signals, state):
        velocity = nonlinear if len(nonlinear) else self.nonlinear_init(signals)
        return {
            "stribeck_peak": per_joint_dict(signals.joint_names, theta, 6),
            "stribeck_velocity": per_joint_dict(signals.joint_names, velocity, 5),
        }

    def evidence(self, residual, signals):
        feature = stribeck_hump(signals.qd, np.full(signals.n, DEFAULT_STRIBECK_VELOCITY))
        return Signature(
            description=self.signature,
            statistic=(f"correlation of residual with exp(-(qd/{DEFAULT_STRIBECK_VELOCITY})^2) "
                       f"tanh(qd/{SIGN_SMOOTHING})"),
            per_joint=per_joint_dict(signals.joint_names, correlation_per_joint(residual, feature), 3),
        )

    def apply_to_spec(self, spec, values, context):
        """MuJoCo has no Stribeck friction: nothing is written (the simulation lacks the hump)."""

    def calibration(self, values, calibration):
        """URDF has no Stribeck friction: nothing is written."""
