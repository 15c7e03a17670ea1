"""Offset between the commanded and the applied torque per joint, on the drive side: applied = cmd + b.

A current-sensor offset in the motor drive, or a gravity compensation the drive adds on its own.
Unlike :mod:`sim2real.identification.effects.torque_bias` (the torque SENSOR's offset, which the simulation never
sees) it changes the motion, so the calibrated MJCF carries it: the actuator's affine bias
``biasprm[0]`` (divided by the actuator's gear, since MuJoCo applies gear * (gain * ctrl + bias)).
On the drive side (:attr:`Signals.forward`) the coefficient of its constant column is b itself. On
runs without a torque sensor the command is judged: ``tau_cmd = k * (tau_applied - b)``, the coefficient
is ``-k * b``, and with a gain k in the model the joint-local coefficients are divided by k afterwards.
"""

from __future__ import annotations

import numpy as np

from sim2real.identification.records import Side
from sim2real.identification.effects.base import per_joint_dict
from sim2real.identification.effects.torque_bias import TorqueBias


class CommandBias(TorqueBias):
    name = "command_bias"
    summary = "constant offset between commanded and applied torque"
    signature = "residual with a nonzero mean between command and applied torque, independent of the motion"
    side = Side.DRIVE
    needs_commands = True
    sensor_side = False

    values_stacked = True

    def values(self, theta, nonlinear, signals, state):
        sign = 1.0 if signals.forward else -1.0
        return {"bias": per_joint_dict(signals.joint_names, sign * np.asarray(theta, dtype=float), 6)}

    def apply_to_spec(self, spec, values, context):
        import mujoco

        for joint, bias in values["bias"].items():
            actuator = context.get("actuators", {}).get(joint)
            if actuator is None or bias == 0:
                continue
            act = spec.actuator(actuator)
            gear = float(act.gear[0]) or 1.0
            biasprm = list(act.biasprm)
            biasprm[0] = float(biasprm[0]) + float(bias) / gear
            act.biasprm = biasprm
            if act.biastype == mujoco.mjtBias.mjBIAS_NONE:
                act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
