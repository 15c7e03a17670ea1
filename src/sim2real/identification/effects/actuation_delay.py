"""Actuation delay: the torque applied at t is the one commanded at t - d (one global d).

An effect of the drive side. Against the motion it is only observable when the judged torque is
the command (``tau_cmd``): a joint torque sensor measures the applied torque, which the rigid-body
model explains without any delay; with both logged, the drive side sees it directly (the measured
torque at t is the command at t - d, :attr:`Signals.forward`). Against the motion, the prediction
of the command at t is the model torque at t + d. d is refined by a bounded scalar search around
the linear fit (variable projection), started from a grid at the sampling step.
MJCF holds it as actuator ``delay``, on the identified joints' actuators.
"""

from __future__ import annotations

import numpy as np

from sim2real.identification.records import Side
from sim2real.identification.effects.base import (
    ParameterSpec, Signature, correlation_per_joint, identified_actuators, per_joint_dict,
)
from sim2real.identification.effects.timing import MAX_DELAY, TimeShift, best_lag, time_derivative


class ActuationDelay(TimeShift):
    name = "actuation_delay"
    summary = "delay between commanded and applied torque"
    signature = "residual proportional to the time derivative of the torque; commanded torque leads the model"
    nonlinear = (ParameterSpec("delay", "s", 0.0, MAX_DELAY, False, "actuation delay"),)
    side = Side.DRIVE
    needs_commands = True

    def evidence(self, residual, signals):
        rate = time_derivative(signals.tau_nominal, signals.time, signals.segments)
        lag = None
        if signals.tau is not None:
            # The command leads: it is the judged torque, or (forward, the drive side) the prediction.
            leading, lagging = (signals.tau_nominal, signals.tau) if signals.forward else (signals.tau, signals.tau_nominal)
            lag = per_joint_dict(signals.joint_names, best_lag(leading, lagging, signals.time), 4)
        return Signature(
            description=self.signature,
            statistic="correlation of residual with d(tau_model)/dt",
            per_joint=per_joint_dict(signals.joint_names, correlation_per_joint(residual, rate), 3),
            lag_s=lag,
        )

    def apply_to_spec(self, spec, values, context):
        delay = float(values["delay"])
        if delay <= 0:
            return
        timestep = float(spec.option.timestep)
        for _, actuator in identified_actuators(context):
            act = spec.actuator(actuator)
            act.delay = delay
            act.nsample = max(int(np.ceil(delay / timestep)) + 1, 2)
