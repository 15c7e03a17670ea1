"""Viscous joint friction: tau_f = d * qd per joint (MJCF joint ``damping``, URDF ``<dynamics damping>``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.identification.effects.base import (
    ColumnLabel, Effect, ParameterSpec, Signals, correlation_per_joint, diagonal_columns, per_joint_dict,
)


class ViscousFriction(Effect):
    drive = True
    in_urdf = True
    name = "viscous_friction"
    summary = "viscous joint friction, torque proportional to joint velocity"
    signature = "residual proportional to joint velocity"
    parameters = (ParameterSpec("damping", "N*m*s/rad", 0.0, 100.0, True, "joint damping (total)"),)

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        return diagonal_columns(signals.qd), [ColumnLabel("damping", j) for j in signals.joint_names]

    def theta_lower(self, signals, size):
        # The total damping (nominal + fitted) is never negative.
        return -np.asarray(signals.nominal.get("damping", np.zeros(signals.n)), dtype=float)

    values_stacked = True

    def values(self, theta, nonlinear, signals, state):
        total = np.asarray(signals.nominal.get("damping", np.zeros(signals.n))) + theta
        return {"damping": per_joint_dict(signals.joint_names, total, 6)}

    def evidence(self, residual, signals):
        return {
            "signature": self.signature,
            "statistic": "correlation of residual with qd",
            "per_joint": per_joint_dict(signals.joint_names, correlation_per_joint(residual, signals.qd), 3),
        }

    def apply_to_spec(self, spec, values, context):
        for joint, value in values["damping"].items():
            # MuJoCo 4 joint damping is a polynomial in velocity (3 coefficients): set the linear one.
            damping = np.array(spec.joint(joint).damping, dtype=float).reshape(-1)
            damping[0] = float(value)
            spec.joint(joint).damping = damping

    def calibration(self, values, calibration):
        for joint, value in values["damping"].items():
            calibration.setdefault("joints", {}).setdefault(joint, {})["damping"] = float(value)
