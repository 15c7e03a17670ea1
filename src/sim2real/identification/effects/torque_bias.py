"""Torque offset per joint (sensor or current-measurement bias): tau_judged = tau + b.

A measurement effect: it is removed from the judged torque, not written into the simulation.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.identification.effects.base import (
    ColumnLabel, Effect, ParameterSpec, Signals, Signature, diagonal_columns, per_joint_dict,
)


class TorqueBias(Effect):
    name = "torque_bias"
    summary = "constant offset of the measured torque"
    signature = "residual with a nonzero mean, independent of the motion"
    parameters = (ParameterSpec("bias", "N*m", -100.0, 100.0, True, "offset of the judged torque"),)
    sensor_side = True

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        return diagonal_columns(np.ones_like(signals.q)), [ColumnLabel("bias", j) for j in signals.joint_names]

    values_stacked = True

    def values(self, theta, nonlinear, signals, state):
        return {"bias": per_joint_dict(signals.joint_names, theta, 6)}

    def evidence(self, residual, signals):
        std = residual.std(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.where(std > 0, residual.mean(axis=0) / np.sqrt(np.mean(residual**2, axis=0)), 0.0)
        return Signature(
            description=self.signature,
            statistic="mean of residual / RMS of residual",
            per_joint=per_joint_dict(signals.joint_names, ratio, 3),
        )
