"""Sensor delay: the torque sensor's reading at t is the torque at t - d (one global d).

A sensor's own dynamics: its electronics' filter, a drive's filtered current estimate, a bus that stamps the
torque later than the encoder. Against the motion the measured torque lags what the motion needs, so the
prediction of the reading at t is the model torque at t - d (a first-order low-pass of time constant T is
such a lag of T at frequencies well below 1/T, where an identification motion lives). An error of the
sensor, like its gain and bias: tried where a sensor's torque is judged against the motion, never on
commands. It is removed from the judged torque and moves nothing of the simulated motion: the calibrated MJCF reads
each actuated joint's torque through a ``jointactuatorfrc`` sensor (``<joint>_torque``) delayed by it (MuJoCo's
sensor ``delay``), as the real sensor reads the applied torque, so a policy observes it as late. On the drive side the
measured torque lags the command by the sensor's delay plus the actuation's, so the calibrated model's
actuation delay is what the drive side finds beyond this one (:func:`actuation_beyond_sensor`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.identification.effects.timing import MAX_DELAY, TimeShift, best_lag, time_derivative
from sim2real.identification.effects.base import (
    ParameterSpec, Signature, correlation_per_joint, identified_actuators, per_joint_dict,
)


def actuation_beyond_sensor(actuator_lag: float, sensor_delay: float) -> float:
    """The actuation's own delay (s): the measured torque lags the command by ``actuator_lag`` (the actuator
    side's actuation_delay), of which ``sensor_delay`` is the sensor's lag behind what was applied."""
    return max(0.0, float(actuator_lag) - float(sensor_delay))


def delay_torque_sensors(spec: Any, delay: float, context: dict[str, Any]) -> None:
    """Each identified actuated joint's torque read through a ``jointactuatorfrc`` sensor ``<joint>_torque``
    (added where missing) that MuJoCo delays by ``delay`` more (sensor ``delay``, ``nsample``: its history)."""
    import mujoco

    if delay <= 0:
        return
    timestep = float(spec.option.timestep)
    existing = {sensor.name: sensor for sensor in spec.sensors}
    for joint, _ in identified_actuators(context):
        sensor = existing.get(f"{joint}_torque")
        if sensor is None:
            sensor = spec.add_sensor()
            sensor.name = f"{joint}_torque"
            sensor.type = mujoco.mjtSensor.mjSENS_JOINTACTFRC
            sensor.objtype = mujoco.mjtObj.mjOBJ_JOINT
            sensor.objname = joint
        sensor.delay = float(sensor.delay) + delay  # a sensor_lag's as well, in either order
        sensor.nsample = max(int(np.ceil(sensor.delay / timestep)) + 1, 2)


class SensorDelay(TimeShift):
    name = "sensor_delay"
    summary = "the torque sensor's reading lags the torque (its filter, a late stamp)"
    signature = "residual proportional to minus the time derivative of the torque; the measured torque lags the model"
    nonlinear = (ParameterSpec("delay", "s", 0.0, MAX_DELAY, False, "lag of the measured torque"),)
    sensor_side = True
    lag_screened = True

    def prediction_shift(self, delay: float, forward: bool) -> float:
        return -delay  # the reading at t is the torque at t - d

    def apply_to_spec(self, spec, values, context):
        delay_torque_sensors(spec, float(values["delay"]), context)

    def evidence(self, residual, signals):
        rate = -time_derivative(signals.tau_nominal, signals.time, signals.segments)
        lag = None
        if signals.tau is not None:
            lag = per_joint_dict(signals.joint_names, best_lag(signals.tau_nominal, signals.tau, signals.time), 4)
        return Signature(
            description=self.signature,
            statistic="correlation of residual with -d(tau_model)/dt",
            per_joint=per_joint_dict(signals.joint_names, correlation_per_joint(residual, rate), 3),
            lag_s=lag,
        )
