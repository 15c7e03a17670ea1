"""Virtual lab: a simulated robot with hidden physical effects that writes measurement runs.

The lab stands in for the real arm. Its "reality" is the built MJCF plus hidden effects that the
lab implements ITSELF (it never imports the fit-side effect code), so a diagnosis that finds them
has learnt them from the data alone.

Hidden effect vocabulary (``configs/{robot}/lab.yaml``, per-joint values as a scalar, a list in
joint order or a ``{joint: value}`` map):

* ``viscous_friction`` ``{coefficient}`` N*m*s/rad: added to the joint damping (implicit in MuJoCo).
* ``coulomb_friction`` ``{coefficient}`` N*m: MuJoCo ``frictionloss`` (sticks at reversals like real
  dry friction); or ``{model: gaz_sigmoid, phi1, phi2, phi3}`` (Gaz et al. 2019):
  tau_f = phi1/(1+exp(-phi2*(qd+phi3))) - phi1/(1+exp(-phi2*phi3)), applied as a passive torque.
  Options of either model: ``stribeck: {peak, velocity}`` adds a Stribeck hump
  peak*exp(-(qd/velocity)^2)*tanh(qd/0.005) opposing the motion (a passive torque; not the fit library's
  tanh/viscous forms); ``after_sensor`` (0..1 per joint) is the share of the joint's friction acting
  between a link-side torque sensor and the link (output bearings, seals): the motion is unchanged, but
  that sensor then sees the share (see ``tau`` below).
* ``rotor_inertia`` ``{armature}`` kg*m^2: added to the joint armature.
* ``actuation_delay`` ``{delay_s}``: the applied torque is the command delayed by delay_s.
* ``actuation_lag`` ``{time_constant_s}``: the applied torque follows the (delayed) command through a
  first-order low-pass of that time constant, as a drive's current loop of finite bandwidth does.
* ``actuator_gain`` ``{gain}`` and ``command_bias`` ``{bias}`` N*m: the motor applies
  gain * (delayed command) + bias, as a motor constant off by some percent or a drive's current offset
  would; a motor-side torque sensor measures that applied torque (a link-side one what reaches the link).
* ``payload`` ``{mass, com?, body?}``: a point-ish mass at the flange (last body), added with MjSpec.
* ``link_inertia`` ``{scale?, mass_scale?, com_offset?}``: the body moved by each joint made heavier or
  lighter (``scale``/``mass_scale``: mass and inertia about the COM multiplied, as a denser or larger
  part would be) and its centre of mass moved (``com_offset``: ``{joint: [x, y, z]}`` m in the body
  frame), as a real arm's links differ from their CAD values.
* ``torque_bias`` ``{bias}`` N*m and ``torque_gain`` ``{gain}``: sensor side, see below.
* ``hysteretic_friction`` ``{level, presliding_rad}``: Dahl friction in the drive, level * z with
  z' = (1 - z sign(dq)) dq / presliding_rad, a passive torque whose state is integrated along the simulated
  motion (:func:`dahl_step`): hysteresis around every reversal, which no static friction law follows.
* ``load_friction`` ``{static, load_coefficient}``: a harmonic drive's friction, whose dry (Coulomb) level grows with
  the torque the gear carries: a passive torque level * tanh(qd / 0.02), the level set at every control step to
  static + load_coefficient * |torque transmitted to the link| (:func:`load_friction_level`: the real arm's rigid-body
  inverse dynamics without the drive's terms, at the last step's acceleration).
* ``cogging`` ``{amplitude, period_rad?}``: a detent torque amplitude * sin(2 pi q / period_rad), a function of
  the joint's position that the fit library has no effect for.
* ``cable_spring`` ``{stiffness, rest_rad?, width_rad?}``: a cable harness pulling each joint towards a rest
  posture, -stiffness * width * tanh((q - rest) / width): a function of the position outside the fit library
  (not periodic, not a link's gravity), which free link inertias would bend to soak up.
* ``torque_drift`` ``{amplitude, time_constant_s?}``: the torque sensor warms up, its offset drifting as
  level * (1 - exp(-t / time_constant_s)) with a level drawn anew in every run (0.5 to 1.5 x amplitude, either
  sign): nothing of the motion explains it.

Column semantics of the written runs:

* ``q.<j>``: joint position from the encoder, quantized to ``sensors.encoder_resolution_rad``.
* ``qd.<j>``: the velocity the controller uses: true velocity plus ``sensors.velocity_noise_std``.
* ``tau_cmd.<j>``: the controller's command at that stamp (PD + gravity or computed torque, both on
  the NOMINAL model, fed by the noisy sensors).
* ``tau.<j>``: the joint torque sensor: the torque it sees times ``torque_gain`` plus ``torque_bias``
  plus white noise ``sensors.torque_noise_std``, after the sensor's own first-order low-pass of
  ``sensors.torque_time_constant_s`` (its electronics' filter; none by default). Where it sits is ``sensors.torque_sensor``:

  - ``motor`` (the default, every scenario but the ``link_side_*`` ones): at the motor output, it sees the
    applied torque (the command after any delay, through the motor's gain and offset), before the
    joint's rotor inertia, damping and friction (a motor-current estimate).
  - ``link`` (``link_side_sensor``, ``link_side_tau_only``; the Panda's ``tau_J``, a KUKA iiwa's sensors):
    after the gearbox, it sees the torque transmitted to the link, the rigid-body inverse dynamics of the
    real arm (its hidden link inertias and payload included) at the true state and acceleration of the
    sample, without the drive terms: the applied torque minus armature * qdd, damping * qd and the joint's
    friction (frictionloss, Gaz, Stribeck). Rotor inertia and joint friction then lie between ``tau_cmd``
    and ``tau``, but for ``coulomb_friction``'s ``after_sensor`` share: tau = inverse dynamics +
    after_sensor * the joint's friction torque (passive ones at the sample's true velocity, frictionloss
    as the solver's force), as a real Panda's tau_J shows friction.

  The run's metadata says which (``torque_sensor: motor|link``) whenever it logs ``tau``.
  Between the sensor and the log, ``sensors.chain`` (:mod:`sim2real.lab.sensor_chain`, any arm) adds a per-run
  offset, a first-order low-pass the reading passes noise included (``low_pass_hz``), and a hold of each joint's
  reading between updates slower than the log (``hold_s``, the joints polled in turn); ``position_hold_s`` holds
  the logged positions likewise. truth.yaml's ``sensor_noise.as_logged`` is then the noise the log holds.
* ``time``: the logger's stamps: the sample instants plus Gaussian ``sensors.stamp_jitter_s`` (kept
  increasing), like a real log whose stamps wander around the control period; ``sensors.dropouts`` removes
  stretches of rows, as a logger that loses samples does, ``sensors.glitches`` and
  ``sensors.encoder_glitches`` put lone samples of ``tau`` and ``q`` far off, as a bus error does, and ``sensors.log_rate_hz`` keeps every k-th control
  step, as a logger slower than the controller does (a 30 Hz recording of a 1 kHz arm).
* ``q_cmd.<j>``: the desired trajectory.

A scenario lists the columns it writes (e.g. a delay scenario writes only ``tau_cmd``, like an arm
without torque sensors). Contacts are disabled: lab runs are free-space identification motions.
The excitation is a finite Fourier series (Swevers et al.): 5 harmonics of base 0.15*pi rad/s by
default, scaled to stay inside the position and velocity limits.

Its modules: :mod:`~sim2real.lab.config` (lab.yaml, its scenarios and runs, a designed excitation),
:mod:`~sim2real.lab.spec_effects` (the hidden effects that live in the model, written into the torque-driven arm of
:mod:`sim2real.assets.arm`, which the gap report's replay shares), :mod:`~sim2real.lab.hidden` (the hidden effects
that act as torques or on the sensor: friction laws, Dahl's memory, cogging, drift), :mod:`~sim2real.lab.loop`
(the controller and the loop), :mod:`~sim2real.lab.logger` (what the logger writes of the sensors) and
:mod:`~sim2real.lab.simulate` (one run put together, and the files it writes).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

# The package's names, each imported from its module when first asked for: Snakemake's input functions read
# lab.yaml (config) at every start, which need not load MuJoCo (simulate) with it.
_MODULE_OF = {
    **dict.fromkeys(["EFFECTS", "excitation_designs", "lab_scenario", "load_lab_config", "read_excitation",
                     "scenario_runs"], "config"),
    **dict.fromkeys(["cogging_torque", "dahl_step", "gaz_friction", "load_friction_level", "passive_friction",
                     "stribeck_friction"], "hidden"),
    "fourier_excitation": "loop",
    **dict.fromkeys(["run_lab_scenario_run", "simulate_run", "write_truth"], "simulate"),
}
__all__ = sorted(_MODULE_OF)

if TYPE_CHECKING:
    from sim2real.lab.config import (EFFECTS, excitation_designs, lab_scenario, load_lab_config, read_excitation,
                                     scenario_runs)
    from sim2real.lab.hidden import (cogging_torque, dahl_step, gaz_friction, load_friction_level, passive_friction,
                                     stribeck_friction)
    from sim2real.lab.loop import fourier_excitation
    from sim2real.lab.simulate import run_lab_scenario_run, simulate_run, write_truth


def __getattr__(name: str) -> Any:
    if name not in _MODULE_OF:
        raise AttributeError(f"module 'sim2real.lab' has no attribute {name!r}")
    return getattr(importlib.import_module(f"sim2real.lab.{_MODULE_OF[name]}"), name)
