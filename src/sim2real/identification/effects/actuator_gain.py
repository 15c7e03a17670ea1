"""Motor gain error per joint, on the drive side: applied torque = g * commanded torque.

A motor constant or current-loop gain other than the controller assumes. On the drive side the
column is the command and the coefficient g - 1 (:attr:`Signals.forward`). On runs without a torque
sensor the command is judged against the nominal model's torque: ``tau_cmd = k * tau_applied`` with
k = 1/g, and the other joint-local effects are divided by k afterwards
(``sim2real.identification.fitting.problem._values``).
MJCF holds it as the actuator's ``gainprm[0]`` (scaled by g, with a servo's feedback terms
``biasprm[1:3]``), which domain randomization's ``kp`` channel randomizes.
"""

from __future__ import annotations

import numpy as np

from sim2real.identification.records import Side
from sim2real.identification.effects.base import per_joint_dict
from sim2real.identification.effects.torque_gain import TorqueGain


class ActuatorGain(TorqueGain):
    name = "actuator_gain"
    summary = "motor gain error: the applied torque is the command scaled"
    signature = "residual proportional to the commanded torque itself"
    side = Side.DRIVE
    needs_commands = True
    sensor_side = False  # inherits the gain column (and scales_judged) of the sensor's gain

    def values(self, theta, nonlinear, signals, state):
        ratio = 1.0 + np.asarray(theta, dtype=float)  # judged / predicted torque
        if signals.forward:
            gain = ratio
        else:  # commanded / applied
            gain = np.divide(1.0, ratio, out=np.full_like(ratio, np.inf), where=np.abs(ratio) > 1e-9)
        return {"gain": per_joint_dict(signals.joint_names, gain, 6)}

    def apply_to_spec(self, spec, values, context):
        for joint, gain in values["gain"].items():
            actuator = context.get("actuators", {}).get(joint)
            if actuator is not None and np.isfinite(gain) and gain > 0:
                act = spec.actuator(actuator)
                gainprm = list(act.gainprm)
                gainprm[0] = float(gainprm[0]) * float(gain)
                act.gainprm = gainprm
                # A servo's position and velocity feedback (biasprm[1:3]) passes through the same motor;
                # biasprm[0] is a constant torque (command_bias), not scaled.
                biasprm = list(act.biasprm)
                biasprm[1:3] = [float(v) * float(gain) for v in biasprm[1:3]]
                act.biasprm = biasprm
