"""Torque scale error per joint: tau_judged = g * tau_applied (sensor gain, or motor constant error).

Linear in the torque domain: tau_judged = tau_nominal + (g - 1) * tau_nominal + g * (other effects),
so the column is the nominal torque and the other joint-local effects are divided by g afterwards.
When the judged torque is the command, the actuator applies cmd / g: MJCF ``gear`` = 1 / g.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.identification.effects.base import (
    ColumnLabel, Effect, ParameterSpec, Signals, Signature, correlation_per_joint, diagonal_columns, per_joint_dict,
)


class TorqueGain(Effect):
    name = "torque_gain"
    summary = "scale error between judged and applied torque"
    signature = "residual proportional to the nominal torque itself"
    parameters = (ParameterSpec("gain", "1", 0.2, 5.0, True, "judged torque / applied torque"),)
    sensor_side = True
    scales_judged = True

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        return diagonal_columns(signals.tau_nominal), [ColumnLabel("gain", j) for j in signals.joint_names]

    def theta_lower(self, signals, size):
        return np.full(size, self.parameters[0].lower - 1.0)  # gain >= its lower bound

    values_stacked = True

    def values(self, theta, nonlinear, signals, state):
        return {"gain": per_joint_dict(signals.joint_names, 1.0 + theta, 6)}

    def evidence(self, residual, signals):
        return Signature(
            description=self.signature,
            statistic="correlation of residual with nominal torque",
            per_joint=per_joint_dict(
                signals.joint_names, correlation_per_joint(residual, signals.tau_nominal), 3
            ),
        )

    def apply_to_spec(self, spec, values, context):
        # Only an actuator gain changes the simulation; a sensor gain does not.
        if context.get("torque_source") != "tau_cmd":
            return
        for joint, gain in values["gain"].items():
            actuator = context.get("actuators", {}).get(joint)
            if actuator is not None and gain > 0:
                act = spec.actuator(actuator)
                gear = list(act.gear)
                gear[0] = float(gear[0]) / float(gain)
                act.gear = gear
