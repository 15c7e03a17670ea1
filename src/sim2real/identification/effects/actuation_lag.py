"""Actuation lag: the torque applied is the command through a first-order low-pass of time constant T (one
global T): a drive's current loop, whose bandwidth is finite.

actuation_delay's lag with a filter's shape (:mod:`sim2real.identification.effects.timing`): the same lag at a motion's
frequencies, and unlike a delay it attenuates what the command changes within T (a controller's noise at 1 kHz), which
is where the drive side (the measured torque against the command) tells the two apart. Against the motion, with
commands alone, the command predicted is what the low-pass turns into the model's torque (its inverse). MJCF holds it
exactly: actuator ``dyntype="filterexact"``, ``dynprm`` T, ``actearly`` (the force follows the filtered command of the
same step, as a drive's does), on the identified joints' actuators, each keyframe's filter settled at its control. On
a position servo the filter acts on its target, as MuJoCo's actuator ``delay`` does.
"""

from __future__ import annotations

from typing import Any

from sim2real.identification.effects.actuation_delay import ActuationDelay
from sim2real.identification.effects.base import ParameterSpec, identified_actuators
from sim2real.identification.effects.timing import MAX_DELAY


class ActuationLag(ActuationDelay):
    name = "actuation_lag"
    summary = "the applied torque follows the command through a low-pass (a drive's current loop)"
    signature = ("residual proportional to the time derivative of the torque; the commanded torque leads the model and "
                 "its fast changes are not applied")
    nonlinear = (ParameterSpec("time_constant", "s", 0.0, MAX_DELAY, False, "time constant of the drive's low-pass"),)
    lowpass = True
    # fitted only where a lag could matter: beside the delay, which every diagnosis of its side tries, where the
    # delay's trial removes enough (sim2real.identification.diagnosis.candidates)
    lag_screened = True

    def apply_to_spec(self, spec: Any, values: Any, context: Any) -> None:
        import mujoco

        time_constant = float(values["time_constant"])
        if time_constant <= 0:
            return
        for _, actuator in identified_actuators(context):
            act = spec.actuator(actuator)
            act.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
            act.dynprm[0] = time_constant
            act.actearly = True
        # A keyframe starts each filter settled at its control (a filter's state would otherwise start at zero).
        stateful = [k for k, act in enumerate(spec.actuators) if act.dyntype != mujoco.mjtDyn.mjDYN_NONE]
        for key in spec.keys:
            if len(key.ctrl) == len(spec.actuators):
                key.act = [float(key.ctrl[k]) for k in stateful]
