"""Sensor lag: the torque sensor reads the torque through a first-order low-pass of time constant T (one global T).

sensor_delay's lag with a filter's shape (:mod:`sim2real.identification.effects.timing`): the same lag T wherever the
torque changes slowly against T, and unlike a delay it attenuates what changes within T. Against a smooth motion the
two are a tie; they part where the judged torque holds fast changes. An error of the sensor: tried where a
sensor's torque is judged against the motion, never on commands. The calibrated MJCF reads each identified joint's
torque through a ``jointactuatorfrc`` sensor delayed by T (MuJoCo's sensors have a delay and no filter: the same lag
at a motion's frequencies), and the calibrated actuation lag is what the drive side finds beyond it.
"""

from __future__ import annotations

from typing import Any

from sim2real.identification.effects.base import ParameterSpec
from sim2real.identification.effects.sensor_delay import SensorDelay, delay_torque_sensors
from sim2real.identification.effects.timing import MAX_DELAY


class SensorLag(SensorDelay):
    name = "sensor_lag"
    summary = "the torque sensor reads through a low-pass (its electronics' or a drive's current filter)"
    signature = ("residual proportional to minus the time derivative of the torque; the measured torque lags the model "
                 "and is smoother than it")
    nonlinear = (ParameterSpec("time_constant", "s", 0.0, MAX_DELAY, False, "time constant of the sensor's low-pass"),)
    lowpass = True

    def prediction_lag(self, time_constant: float, forward: bool) -> float:
        return time_constant  # the reading is the torque through the low-pass

    def apply_to_spec(self, spec: Any, values: Any, context: Any) -> None:
        delay_torque_sensors(spec, float(values["time_constant"]), context)
