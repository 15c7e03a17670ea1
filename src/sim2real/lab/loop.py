"""The control loop of a lab run: the desired motion, the controller on the nominal arm, and the real arm with its
hidden effects (:mod:`.spec_effects`, :mod:`.hidden`) stepped sample by sample (:func:`_play`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from sim2real.assets.arm import arm_spec, compile_arm, drop_inert_meshes
from sim2real.lab.config import _per_joint
from sim2real.lab.hidden import (
    _cable_spring, _cogging, _hysteretic_friction, _joint_friction, _load_friction, _torque_drift, _warming_friction,
    cable_spring_torque, cogging_torque, dahl_step, load_friction_level, passive_friction, warming_level,
)
from sim2real.lab.spec_effects import _apply_spec_effects, _gains_and_biases


def fourier_excitation(
    time: np.ndarray, lower: np.ndarray, upper: np.ndarray, velocity_limit: np.ndarray, settings: Mapping[str, Any],
    seed: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Finite Fourier series q(t) = q0 + sum_l a_l/(w l) sin(w l t) - b_l/(w l) cos(w l t), per joint.

    Random coefficients (seeded) scaled so that |q - q0| stays within position_fraction of the half range
    and |qd| within velocity_fraction of the velocity limit. Returns q, qd, qdd, each (N, n).
    """
    rng = np.random.default_rng(seed)
    n = lower.size
    harmonics = int(settings["harmonics"])
    w = float(settings["base_frequency_rad_s"])
    ell = np.arange(1, harmonics + 1)
    a = rng.normal(size=(n, harmonics))
    b = rng.normal(size=(n, harmonics))
    wt = np.outer(time, w * ell)  # (N, L)
    sin, cos = np.sin(wt), np.cos(wt)
    # offsets chosen so the series is zero-mean; scale applied after
    dq = (sin @ (a / (w * ell)).T) - (cos @ (b / (w * ell)).T)
    dqd = cos @ a.T + sin @ b.T
    dqdd = -(sin @ (a * w * ell).T) + cos @ (b * w * ell).T
    q0 = 0.5 * (lower + upper)
    half_range = 0.5 * (upper - lower)
    scale_pos = settings["position_fraction"] * half_range / np.max(np.abs(dq), axis=0)
    scale_vel = settings["velocity_fraction"] * velocity_limit / np.max(np.abs(dqd), axis=0)
    scale = np.minimum(scale_pos, scale_vel)
    return q0 + dq * scale, dqd * scale, dqdd * scale


def _link_side_model(mjcf_path: str | Path, joints: Sequence[str], effects: Mapping[str, Any],
                     path: Path | None) -> mujoco.MjModel:
    """The real arm (hidden effects included) without its drive terms: no armature, damping or
    frictionloss on the measured joints. Its inverse dynamics is the torque transmitted to the links."""
    spec = arm_spec(mjcf_path, joints)
    _apply_spec_effects(spec, joints, effects, path)
    for name in joints:
        joint = spec.joint(name)
        joint.armature = 0.0
        joint.damping = np.zeros_like(np.array(joint.damping, dtype=float).reshape(-1))
        joint.frictionloss = 0.0
    drop_inert_meshes(spec)
    return compile_arm(spec, joints)[0]


def _nominal_torque(model: mujoco.MjModel, data: mujoco.MjData, q: np.ndarray, qd: np.ndarray,
                    qdd: np.ndarray, qadr: np.ndarray, dadr: np.ndarray) -> np.ndarray:
    data.qpos[qadr] = q
    data.qvel[dadr] = qd
    data.qacc[dadr] = qdd
    mujoco.mj_inverse(model, data)
    return data.qfrc_inverse[dadr].copy()


def _friction_now(data: mujoco.MjData, qd: np.ndarray, friction: Mapping[str, Any],
                  dof_of: Mapping[int, int]) -> np.ndarray:
    """Each joint's friction torque at the forward-computed sample, along the velocity: the passive torques
    at the true velocity plus MuJoCo's dry friction (frictionloss rows of the constraint solver)."""
    out = passive_friction(qd, friction)
    out = np.zeros(len(qd)) if out is None else out.copy()
    for row in np.flatnonzero(data.efc_type[:data.nefc] == mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF):
        joint = dof_of.get(int(data.efc_id[row]))
        if joint is not None:
            out[joint] -= data.efc_force[row]  # the constraint force opposes the motion
    return out


@dataclass(frozen=True, eq=False)
class _Arms:
    """The controller's nominal arm and the real arm (hidden effects included), compiled at the substep, with their
    data and the measured joints' addresses; ``truth``: the hidden values, filled in as the effects are resolved."""

    nominal: mujoco.MjModel
    nominal_data: mujoco.MjData
    qadr: np.ndarray
    dadr: np.ndarray
    real: mujoco.MjModel
    real_data: mujoco.MjData
    qadr_r: np.ndarray
    dadr_r: np.ndarray
    ctrl_index: np.ndarray  # the real arm's motors, in joint order
    substeps: int
    truth: dict[str, Any]


@dataclass(frozen=True, eq=False)
class _Hidden:
    """The hidden effects the run plays step by step: passive and position-dependent torques, the drive's delay,
    lag, gain and offset, the sensor's gain, offset and drift. ``friction`` changes as the run goes (a hysteretic
    friction's state, a load friction's level)."""

    friction: dict[str, Any]
    dahl: Any
    load: Any
    warming: Any
    cogging: Any
    spring: Any
    drift: np.ndarray | None
    delay_steps: int
    lag_keep: float
    scales: Mapping[str, np.ndarray]
    passive: bool  # any passive friction torque applied on the real arm
    positional: bool  # any torque the positions decide

    def position_torque(self, q: np.ndarray) -> np.ndarray:
        """The torques the joints' positions decide (a cogging, a cable's pull)."""
        torque = np.zeros(len(q))
        if self.cogging is not None:
            torque = torque + cogging_torque(q, self.cogging)
        if self.spring is not None:
            torque = torque + cable_spring_torque(q, self.spring)
        return torque

    def apply(self, arms: _Arms) -> None:
        """The passive and position-dependent torques at the real arm's state, as its applied forces (when there are
        any: ``passive or positional``)."""
        real_data, dadr_r = arms.real_data, arms.dadr_r
        torque = np.zeros(len(dadr_r)) if not self.passive else -passive_friction(real_data.qvel[dadr_r], self.friction)
        real_data.qfrc_applied[dadr_r] = torque + self.position_torque(real_data.qpos[arms.qadr_r])


@dataclass(frozen=True, eq=False)
class _LinkSide:
    """The real arm without its drive terms (:func:`_link_side_model`): its inverse dynamics is the torque the gear
    transmits to the links, which a link-side sensor measures and a load friction's level follows."""

    model: mujoco.MjModel
    data: mujoco.MjData
    dadr: np.ndarray
    dof_of: Mapping[int, int]  # the real arm's dof -> joint

    def torque(self, arms: _Arms) -> np.ndarray:
        """The transmitted torque at the real arm's state and acceleration."""
        real_data, data = arms.real_data, self.data
        data.qpos[:], data.qvel[:], data.qacc[:] = real_data.qpos, real_data.qvel, real_data.qacc
        mujoco.mj_inverse(self.model, data)
        return data.qfrc_inverse[self.dadr]


@dataclass(frozen=True, eq=False)
class _Controller:
    """The controller on the nominal model and what it measures."""

    kind: str  # computed_torque or pd (plus gravity compensation)
    kp: np.ndarray
    kd: np.ndarray
    resolution: float  # the encoder's, rad (0: exact)
    vel_noise: float  # the velocity's noise, std


def _arms(mjcf_path: str | Path, joints: Sequence[str], effects: Mapping[str, Any], path: Path | None, rate: float,
          substeps: int) -> _Arms:
    """The nominal and the real arm (the spec's hidden effects applied), stepped ``substeps`` times a sample."""
    nominal_spec = arm_spec(mjcf_path, joints)
    real_spec = arm_spec(mjcf_path, joints)
    truth = _apply_spec_effects(real_spec, joints, effects, path)
    for spec in (nominal_spec, real_spec):
        drop_inert_meshes(spec)  # most of each compile, and no number of the motion
    dt = 1.0 / rate
    nominal, qadr, dadr = compile_arm(nominal_spec, joints)
    real, qadr_r, dadr_r = compile_arm(real_spec, joints)
    for model in (nominal, real):
        model.opt.timestep = dt / substeps
    ctrl_index = np.array([real.actuator(f"motor_{j}").id for j in joints])
    return _Arms(nominal, mujoco.MjData(nominal), qadr, dadr, real, mujoco.MjData(real), qadr_r, dadr_r, ctrl_index,
                 substeps, truth)


def _desired_motion(
    nominal: mujoco.MjModel, joints: Sequence[str], scenario: Mapping[str, Any], seed: int, path: Path | None,
    trajectory: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """time, q, qd, qdd of the motion the controller follows: ``trajectory``, or the scenario's random Fourier
    series within the nominal arm's joint range and the scenario's velocity limit."""
    lower = nominal.jnt_range[[nominal.joint(j).id for j in joints], 0]
    upper = nominal.jnt_range[[nominal.joint(j).id for j in joints], 1]
    vel_limit = _per_joint(scenario.get("velocity_limit", 2.0), joints, "velocity_limit", path)
    if trajectory is not None:
        return trajectory
    rate = float(scenario["sample_rate_hz"])
    steps = int(round(float(scenario["duration_s"]) * rate))
    time = np.arange(steps) * (1.0 / rate)
    q_des, qd_des, qdd_des = fourier_excitation(time, lower, upper, vel_limit, scenario["excitation"], seed)
    return time, q_des, qd_des, qdd_des


def _hidden_effects(effects: Mapping[str, Any], joints: Sequence[str], path: Path | None, seed: int,
                    truth: dict[str, Any], time: np.ndarray, rate: float) -> _Hidden:
    """The hidden effects the run plays (their resolved values recorded in ``truth``, in this order)."""
    dt = 1.0 / rate
    friction = _joint_friction(effects, joints, path, truth)
    dahl = _hysteretic_friction(effects, joints, path, truth)
    if dahl is not None:
        friction["dahl"], friction["dahl_state"] = dahl, np.zeros(len(joints))
    load = _load_friction(effects, joints, path, truth)
    if load is not None:
        friction["load_level"] = load[0].copy()
    warming = _warming_friction(effects, joints, path, truth)
    if warming is not None:
        friction["warm_level"] = warming_level(0.0, warming)
    cogging = _cogging(effects, joints, path, truth)
    spring = _cable_spring(effects, joints, path, truth)
    drift = _torque_drift(effects, joints, path, seed, truth, time)
    passive = (friction["gaz"] is not None or friction["stribeck"] is not None or dahl is not None or load is not None
               or warming is not None)
    delay_steps = 0
    if "actuation_delay" in effects:
        delay_steps = int(round(float(effects["actuation_delay"]["delay_s"]) * rate))
        truth["actuation_delay"] = {"delay_s": delay_steps * dt}
    # A drive's current loop: the applied torque follows its target through a first-order low-pass (exact for a
    # target held over the control step, as sim2real.filters.first_order_lag), settled at the first one.
    lag_keep = 0.0
    if "actuation_lag" in effects:
        constant = float(effects["actuation_lag"]["time_constant_s"])
        lag_keep = float(np.exp(-dt / constant)) if constant > 0 else 0.0
        truth["actuation_lag"] = {"time_constant_s": constant}
    scales = _gains_and_biases(effects, joints, path, truth)
    return _Hidden(friction, dahl, load, warming, cogging, spring, drift, delay_steps, lag_keep, scales, passive,
                   cogging is not None or spring is not None)


def _play(arms: _Arms, desired: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], hidden: _Hidden,
          control: _Controller, link: _LinkSide | None, link_side: bool,
          rng: np.random.Generator) -> dict[str, np.ndarray | None]:
    """The control loop: at each sample the measured state, the controller's command, the torque the drive applies
    (delayed, lagged, scaled) and, with a link-side sensor, the torque transmitted to the links; then the real arm's
    substeps. Returns those per sample (``link``: None without a link-side sensor)."""
    nominal, nominal_data, qadr, dadr = arms.nominal, arms.nominal_data, arms.qadr, arms.dadr
    real, real_data, qadr_r, dadr_r = arms.real, arms.real_data, arms.qadr_r, arms.dadr_r
    ctrl_index, substeps = arms.ctrl_index, arms.substeps
    time, q_des, qd_des, qdd_des = desired
    steps, n = len(time), len(qadr_r)
    kp, kd, resolution, vel_noise = control.kp, control.kd, control.resolution, control.vel_noise
    scales, friction, delay_steps, lag_keep = hidden.scales, hidden.friction, hidden.delay_steps, hidden.lag_keep
    motor_gain, motor_bias = scales["actuator_gain"], scales["command_bias"]
    after = friction["after"]
    forced = hidden.passive or hidden.positional
    real_data.qpos[qadr_r] = q_des[0]
    real_data.qvel[dadr_r] = qd_des[0]
    out_q = np.empty((steps, n))
    out_qd = np.empty((steps, n))
    out_cmd = np.empty((steps, n))
    out_applied = np.empty((steps, n))
    out_link = np.empty((steps, n)) if link_side else None
    for k in range(steps):
        q_true = real_data.qpos[qadr_r]
        qd_true = real_data.qvel[dadr_r]
        q_meas = np.round(q_true / resolution) * resolution if resolution > 0 else q_true.copy()
        qd_meas = qd_true + vel_noise * rng.standard_normal(n)
        if control.kind == "computed_torque":
            acc = qdd_des[k] + kp * (q_des[k] - q_meas) + kd * (qd_des[k] - qd_meas)
            cmd = _nominal_torque(nominal, nominal_data, q_meas, qd_meas, acc, qadr, dadr)
        else:  # PD plus gravity compensation on the nominal model
            gravity = _nominal_torque(nominal, nominal_data, q_meas, np.zeros(n), np.zeros(n), qadr, dadr)
            cmd = kp * (q_des[k] - q_meas) + kd * (qd_des[k] - qd_meas) + gravity
        out_cmd[k] = cmd
        # Actuation delay: the motor applies an older command, through its own gain and offset.
        applied = motor_gain * out_cmd[max(k - delay_steps, 0)] + motor_bias
        if lag_keep > 0.0 and k > 0:
            applied = lag_keep * out_applied[k - 1] + (1.0 - lag_keep) * applied
        out_q[k], out_qd[k], out_applied[k] = q_meas, qd_meas, applied
        real_data.ctrl[ctrl_index] = applied
        if hidden.warming is not None:  # the level the joint's warmth sets, held over the control step
            friction["warm_level"] = warming_level(float(time[k] - time[0]), hidden.warming)
        if hidden.load is not None:
            # The level the gear's load sets, held over the control step: the torque transmitted to the link at the
            # last step's acceleration (one step late: what the friction of this step does is not known before it).
            friction["load_level"] = load_friction_level(link.torque(arms), hidden.load)  # type: ignore[union-attr]
        if link_side:
            if forced:
                hidden.apply(arms)
            mujoco.mj_forward(real, real_data)  # the acceleration the step below integrates
            out_link[k] = link.torque(arms)  # type: ignore[index,union-attr]
            if np.any(after > 0):
                # Output bearings and seals sit between the sensor and the link: the sensor transmits the
                # link's inverse dynamics plus their share of the friction (the arm's motion is unchanged).
                out_link[k] += after * _friction_now(real_data, qd_true, friction, link.dof_of)  # type: ignore[index,union-attr]
        for _ in range(substeps):
            before = real_data.qpos[qadr_r].copy()
            if forced:
                hidden.apply(arms)
            mujoco.mj_step(real, real_data)
            if hidden.dahl is not None:  # the friction's memory follows the motion the step made
                friction["dahl_state"] = dahl_step(friction["dahl_state"], real_data.qpos[qadr_r] - before, hidden.dahl[1])
    return {"q": out_q, "qd": out_qd, "cmd": out_cmd, "applied": out_applied, "link": out_link}
