"""The commands replayed in MuJoCo: the built MJCF driven by joint torques (:func:`sim2real.assets.arm.arm_spec`)
with multiple shooting, every ``horizon_s`` restarted from the measured state (``mujoco.rollout``, one segment per
batch row); the state domain's metrics, and each rung of the ladder replayed with its fitted effects.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from mujoco import rollout

from sim2real.cache import FitCache
from sim2real.identification.ladder_rows import Rung
from sim2real.measurements import PreparedRun
from sim2real.report.metrics import TorqueComparison, fidelity_grade, per_joint_dict, reality_gap, spectral_divergence
from sim2real.stats import rmse


class ReplayModels:
    """The compiled arm of each distinct model of one report, each compiled once.

    The state domain, the armature and every rung's replay (the actuator link's first rung is the body
    link's last) would otherwise each parse and compile the same MJCF again. The MJCF is parsed and
    stripped of its inert meshes once; each model is a copy of that spec with its effects written in.
    ``cache``: replays of an earlier report with the same compiled model and run are read back from it
    (:func:`replay`; a round of the loop that adds one rung replays that rung, not the ladder).
    """

    def __init__(self, mjcf_path: str | Path, cache: FitCache | None = None) -> None:
        self.mjcf_path = mjcf_path
        self.cache = cache or FitCache(None)
        self._bases: dict[tuple[str, ...], mujoco.MjSpec] = {}
        self._models: dict[tuple[tuple[str, ...], str], tuple[mujoco.MjModel, np.ndarray, np.ndarray]] = {}

    def _spec(self, joints: Sequence[str], identified: Mapping[str, Any] | None, strip: bool) -> mujoco.MjSpec:
        from sim2real.identification.effects import apply_to_spec
        from sim2real.assets.arm import arm_spec, drop_inert_meshes

        if not strip:
            spec = arm_spec(self.mjcf_path, joints)
        else:
            if tuple(joints) not in self._bases:
                base = arm_spec(self.mjcf_path, joints)
                drop_inert_meshes(base)
                self._bases[tuple(joints)] = base
            spec = self._bases[tuple(joints)].copy()
        if identified:
            apply_to_spec(spec, dict(identified), include_urdf_effects=True)
        return spec

    def get(self, joints: Sequence[str], identified: Mapping[str, Any] | None = None,
            ) -> tuple[mujoco.MjModel, np.ndarray, np.ndarray]:
        """(model, qpos addresses, dof addresses) of the arm with ``identified`` written in (None: as built)."""
        from sim2real.assets.arm import compile_arm, meshes_inert

        key = (tuple(joints), json.dumps(identified or None, sort_keys=True))
        if key not in self._models:
            spec = self._spec(joints, identified, strip=True)
            if not meshes_inert(spec):  # an effect switched on something that reads the geoms: keep them all
                spec = self._spec(joints, identified, strip=False)
            self._models[key] = compile_arm(spec, joints)
        return self._models[key]


def replay(
    mjcf_path: str | Path, prepared: PreparedRun, horizon_s: float,
    identified: Mapping[str, Any] | None = None, models: ReplayModels | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Multiple-shooting replay of tau_cmd: (simulated q, simulated qd, index of the compared samples).

    ``identified``: fitted effects in the shape of params.yaml (``effects``, ``torque_source``) to write
    into the model first, so that a rung of the model ladder is replayed as it was fitted.
    ``models``: compiled models of ``mjcf_path`` to reuse (one report replays the same model several times).
    """
    assert prepared.tau_cmd is not None
    joints = prepared.joint_names
    models = models if models is not None else ReplayModels(mjcf_path)
    model, qadr, dadr = models.get(joints, identified)
    model.opt.timestep = prepared.dt  # set on every call: a shared model may have replayed a run of another rate
    seg = max(2, int(round(horizon_s / prepared.dt)))
    if (prepared.time.size - 1) // seg < 1:
        raise ValueError("run shorter than one replay horizon")
    # The replay depends on the compiled model (its bytes hold every fitted effect) and the run's motion and
    # commands, nothing else: a replay of an earlier report with the same is the same to the last bit.
    saved = np.zeros(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, saved)
    key = models.cache.key(saved, list(joints), prepared.time, prepared.q, prepared.qd, prepared.tau_cmd, seg)
    return models.cache.get_or_compute("replay", key, functools.partial(
        _multiple_shooting, model, qadr, dadr, prepared, seg))


def _multiple_shooting(model: mujoco.MjModel, qadr: np.ndarray, dadr: np.ndarray, prepared: PreparedRun, seg: int,
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`replay`'s rollout: every ``seg`` samples the simulation restarts from the measured state."""
    assert prepared.tau_cmd is not None
    joints = prepared.joint_names
    n_seg = (prepared.time.size - 1) // seg
    data = mujoco.MjData(model)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    nstate = mujoco.mj_stateSize(model, spec)
    initial = np.empty((n_seg, nstate))
    control = np.zeros((n_seg, seg, model.nu))
    ctrl_cols = np.array([model.actuator(f"motor_{j}").id for j in joints])
    starts = np.arange(n_seg) * seg
    filtered = _filtered_commands(model, ctrl_cols, prepared)
    for b, start in enumerate(starts):
        mujoco.mj_resetData(model, data)
        data.time = prepared.time[start]
        data.qpos[qadr] = prepared.q[start]
        data.qvel[dadr] = prepared.qd[start]
        for index, actuator in enumerate(ctrl_cols):
            # A delayed actuator starts each segment with the commands logged before it (held before the log).
            nsample = int(model.actuator_history[actuator, 0])
            if nsample > 0:
                rows = start - nsample + np.arange(nsample)
                mujoco.mj_initCtrlHistory(model, data, int(actuator), prepared.time[0] + prepared.dt * rows,
                                          prepared.tau_cmd[np.clip(rows, 0, None), index])
        for actuator, commands in filtered.items():
            # A filtered actuator (a drive's low-pass) starts each segment where the commands before it left it.
            data.act[model.actuator_actadr[actuator]] = commands[max(start - 1, 0)]
        mujoco.mj_getState(model, data, initial[b], spec)
        control[b][:, ctrl_cols] = prepared.tau_cmd[start:start + seg]
    state, _ = rollout.rollout(model, [mujoco.MjData(model) for _ in range(2)], initial, control)
    # state[b, i] is the state after step i, i.e. at sample start + i + 1
    qpos_off = 1  # FULLPHYSICS state = [time, qpos, qvel, act, ...]
    q_sim = state[:, :, qpos_off + qadr].reshape(-1, len(joints))
    qd_sim = state[:, :, qpos_off + model.nq + dadr].reshape(-1, len(joints))
    index = (starts[:, None] + 1 + np.arange(seg)[None, :]).reshape(-1)
    return q_sim, qd_sim, index


def _filtered_commands(model: mujoco.MjModel, ctrl_cols: np.ndarray, prepared: PreparedRun) -> dict[int, np.ndarray]:
    """Each first-order filtered actuator's activation after every sample of the run: its logged commands (delayed by
    its actuator delay, held before the log) through its filter, settled at the first (:func:`first_order_lag`,
    as MuJoCo's ``filterexact`` holds the control over a step)."""
    from sim2real.filters import first_order_lag

    out = {}
    for index, actuator in enumerate(ctrl_cols):
        if model.actuator_dyntype[actuator] not in (mujoco.mjtDyn.mjDYN_FILTER, mujoco.mjtDyn.mjDYN_FILTEREXACT):
            continue
        commands = prepared.tau_cmd[:, index]
        delay = float(model.actuator_delay[actuator])
        if delay > 0:
            commands = np.interp(prepared.time - delay, prepared.time, commands)
        out[int(actuator)] = first_order_lag(commands, prepared.dt, float(model.actuator_dynprm[actuator, 0]))
    return out


def state_domain(mjcf_path: str | Path, runs: Sequence[TorqueComparison], horizon_s: float,
                 tau_rmse: float, models: ReplayModels | None = None,
                 identified: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """State-domain metrics over all runs with commands, or a plain 'skipped' with the reason; ``identified``:
    fitted effects written into the model first (:func:`replay`; None: the MJCF as built)."""
    usable = [c for c in runs if c.run.tau_cmd is not None]
    if not usable:
        return {"status": "skipped",
                "reason": "no run logs commanded torques (tau_cmd.<joint>), so there is nothing to replay"}
    joints = usable[0].run.joint_names
    sims, reals, simv, realv, contacts = [], [], [], [], []
    for c in usable:
        try:
            q_sim, qd_sim, idx = replay(mjcf_path, c.run, horizon_s, identified, models=models)
        except ValueError as exc:
            return {"status": "skipped", "reason": f"run '{c.run.name}': {exc} (horizon {horizon_s} s)"}
        sims.append(q_sim)
        reals.append(c.run.q[idx])
        simv.append(qd_sim)
        realv.append(c.run.qd[idx])
        contacts.append(c.run.contact)
    q_sim, q_real = np.concatenate(sims), np.concatenate(reals)
    qd_sim, qd_real = np.concatenate(simv), np.concatenate(realv)
    finite = np.all(np.isfinite(q_sim), axis=1) & np.all(np.isfinite(qd_sim), axis=1)
    q_sim, q_real, qd_sim, qd_real = q_sim[finite], q_real[finite], qd_sim[finite], qd_real[finite]
    pos = rmse(q_sim - q_real, joints)
    vel = rmse(qd_sim - qd_real, joints)
    corr = np.array([np.corrcoef(q_sim[:, j], q_real[:, j])[0, 1] for j in range(len(joints))])
    corr = np.nan_to_num(corr, nan=0.0)
    spectral = spectral_divergence(q_sim, q_real)
    mean_abs = float(np.mean(np.abs(q_sim - q_real)))
    contact_f1 = None  # the replay model has contacts disabled; flags alone cannot be compared
    gap = reality_gap(pos["overall"], vel["overall"], tau_rmse, float(corr.mean()), spectral, contact_f1)
    return {
        "status": "computed",
        "horizon_s": float(horizon_s),
        "runs": [c.run.name for c in usable],
        "position_rmse": pos,
        "velocity_rmse": vel,
        "correlation": per_joint_dict(corr, joints, float(corr.mean())),
        "spectral_divergence": spectral,
        "contact_f1": None,
        "contact_note": "no contact flags compared (free-space motion); the contact term is left out of the score",
        "mean_abs_position_error": mean_abs,
        "fidelity": fidelity_grade(mean_abs),
        "reality_gap": gap,
    }


def ladder_position_rmse(
    mjcf_path: str | Path, comparisons: Sequence[TorqueComparison], horizon_s: float,
    ladder: Sequence[Rung], torque_source: str | None, models: ReplayModels | None = None,
) -> list[dict[str, Any] | None]:
    """Position RMSE of each rung's replay on the holdout runs with commands (None where there is none)."""
    holdout = [c for c in comparisons if c.role == "holdout" and c.run.tau_cmd is not None]
    if not holdout:
        return [None for _ in ladder]
    joints = holdout[0].run.joint_names
    models = models if models is not None else ReplayModels(mjcf_path)
    out: list[dict[str, Any] | None] = []
    for rung in ladder:
        identified = {"effects": rung.values, "torque_source": torque_source}
        errors = []
        for c in holdout:
            q_sim, _, idx = replay(mjcf_path, c.run, horizon_s, identified, models)
            error = q_sim - c.run.q[idx]
            errors.append(error[np.all(np.isfinite(error), axis=1)])
        out.append(rmse(np.concatenate(errors), joints))
    return out


def model_armature(mjcf_path: str | Path, joints: Sequence[str], models: ReplayModels | None = None,
                   ) -> dict[str, float]:
    """Rotor inertia (armature) of the measured joints as the built MJCF has it.

    The URDF cannot hold armature; the MJCF gets it from configs/{robot}/robot.yaml. Reading it back
    from the MJCF keeps the Pinocchio model and the MuJoCo replay the same model.
    """
    models = models if models is not None else ReplayModels(mjcf_path)
    model, _, dadr = models.get(joints)
    return {j: float(model.dof_armature[d]) for j, d in zip(joints, dadr)}
