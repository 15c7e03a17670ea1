"""Rotor (reflected motor) inertia: tau = I_a * qdd per joint (MJCF joint ``armature``; URDF cannot hold it)."""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.identification.effects.base import (
    ColumnLabel, Effect, ParameterSpec, Signals, correlation_per_joint, diagonal_columns, per_joint_dict,
)


class RotorInertia(Effect):
    drive = True
    name = "rotor_inertia"
    summary = "reflected rotor inertia (armature), torque proportional to joint acceleration"
    signature = "residual proportional to joint acceleration"
    parameters = (ParameterSpec("armature", "kg*m^2", 0.0, 10.0, True, "rotor inertia at the joint (total)"),)

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        return diagonal_columns(signals.qdd), [ColumnLabel("armature", j) for j in signals.joint_names]

    def theta_lower(self, signals, size):
        # The total armature (nominal + fitted) is never negative.
        return -np.asarray(signals.nominal.get("armature", np.zeros(signals.n)), dtype=float)

    values_stacked = True

    def values(self, theta, nonlinear, signals, state):
        total = np.asarray(signals.nominal.get("armature", np.zeros(signals.n))) + theta
        return {"armature": per_joint_dict(signals.joint_names, total, 6)}

    def evidence(self, residual, signals):
        return {
            "signature": self.signature,
            "statistic": "correlation of residual with qdd",
            "per_joint": per_joint_dict(signals.joint_names, correlation_per_joint(residual, signals.qdd), 3),
        }

    def apply_to_spec(self, spec, values, context):
        for joint, value in values["armature"].items():
            spec.joint(joint).armature = float(max(value, 0.0))
