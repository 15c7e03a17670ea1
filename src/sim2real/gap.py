"""The gap report: how far the model is from the measurements, and where it fails.

* Torque domain: inverse dynamics of the URDF model (Pinocchio, ``RigidBodyModel``) on the prepared
  q, qd, qdd against the prepared torque (measured ``tau``, else ``tau_cmd``): RMSE per joint and
  overall, RMSE relative to the torque's RMS, R^2.
* State domain, where commands exist: the commanded torques are replayed in MuJoCo (the built MJCF
  driven by joint torques, see ``sim2real.lab.arm_spec``) with multiple shooting: every ``horizon_s``
  the simulation restarts from the measured state (``mujoco.rollout``, one segment per batch row).
  Position/velocity RMSE, correlation, spectral divergence and the reality-gap metric of the source
  chapter (P02.5): score = 0.3 min(pos/0.1,1) + 0.2 min(vel/1,1) + 0.15 min(tau/5,1) + 0.15 (1-corr)
  + 0.1 min(spec/1,1) + 0.1 (1-contact F1). ``tau`` is the torque-domain RMSE. Without contact flags
  the contact term is not applicable and the other weights are renormalised to sum to 1 (an arm in
  free space would otherwise be charged 0.1 for contacts that do not exist).
* Where it fails: per joint and regime (slow motion and velocity reversals, hard accelerations,
  gravity-loaded poses, near the limits; defined in ``sim2real.regimes``), and the worst time windows
  with their stamps.
* The noise floor: the torque RMS that no model can explain (``noise_floor_of``).

The runs come prepared by the rule ``prepare_runs`` (``sim2real.measurements.write_prepared_runs``),
shared with the sysid rule; given a measurement list instead, they are read and prepared here
(``sim2real.measurements.runs_for_model``).

``compute_gap`` returns the gap.json content; ``build_gap_report`` writes gap.json, gap.md and the
figures. An optional precomputed section (``ladder``, ``diagnosis``, ``actuator``, ``links``, from the
sysid rule) is merged in; each rung of either link is replayed with its fitted effects.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from mujoco import rollout

from sim2real.dynamics import RigidBodyModel
from sim2real.cache import FitCache
from sim2real.errors import InputError
from sim2real.files import validate, write_json
from sim2real.measurements import PreparedRun, noise_floor_of, runs_for_model
from sim2real.metrics import rmse
from sim2real.regimes import REGIME_DEFINITIONS, REGIME_LABELS, REGIMES, regime_masks

GAP_WEIGHTS = {"position": 0.3, "velocity": 0.2, "torque": 0.15, "correlation": 0.15, "spectral": 0.1, "contact": 0.1}
WINDOW_S = 0.5
N_WORST_WINDOWS = 5


@dataclass(frozen=True)
class TorqueComparison:
    run: PreparedRun
    role: str
    model_tau: np.ndarray
    residual: np.ndarray  # measured - model
    gravity: np.ndarray


def _per_joint_dict(values: np.ndarray, joints: Sequence[str], overall: float) -> dict[str, Any]:
    return {"overall": float(overall), "per_joint": {j: float(v) for j, v in zip(joints, values)}}


def torque_metrics(measured: np.ndarray, residual: np.ndarray, joints: Sequence[str]) -> dict[str, Any]:
    """RMSE, relative RMSE (to the measured RMS) and R^2, each {overall, per_joint}."""
    err = rmse(residual, joints)
    rms = np.sqrt(np.mean(measured**2, axis=0))
    rms_all = float(np.sqrt(np.mean(measured**2)))
    rel = np.asarray([err["per_joint"][j] for j in joints]) / np.maximum(rms, 1e-12)
    ss_res = np.sum(residual**2, axis=0)
    ss_tot = np.sum((measured - measured.mean(axis=0)) ** 2, axis=0)
    r2 = 1.0 - ss_res / np.maximum(ss_tot, 1e-12)
    r2_all = 1.0 - ss_res.sum() / max(float(ss_tot.sum()), 1e-12)
    return {
        "torque_rmse": err,
        "torque_relative_rmse": _per_joint_dict(rel, joints, err["overall"] / max(rms_all, 1e-12)),
        "torque_r2": _per_joint_dict(r2, joints, r2_all),
    }


# ---------------------------------------------------------------------------------------------
# state domain


def _meshes_inert(spec: mujoco.MjSpec) -> bool:
    """Whether the mesh geoms of bodies with an explicit inertia change no number of the replay.

    They do not when contacts are off (``arm_spec``), fluid forces are off (the ellipsoid model reads geoms),
    sleeping is off (it reads ``dof_length``, which the compiler takes from the geoms) and the compiler keeps
    explicit inertias (it then ignores the geoms' masses).
    """
    return bool(spec.option.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
                and not spec.option.enableflags & mujoco.mjtEnableBit.mjENBL_SLEEP
                and not spec.option.density and not spec.option.viscosity
                and spec.compiler.inertiafromgeom != mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE)


def _drop_inert_meshes(spec: mujoco.MjSpec) -> None:
    """Delete the mesh geoms (and their meshes) that cannot change a number of the replay (``_meshes_inert``).

    Loading and processing the meshes is most of a compile (about 1.2 s of 1.3 s on the Panda).
    """
    if not _meshes_inert(spec):
        return
    for geom in list(spec.geoms):
        if geom.type == mujoco.mjtGeom.mjGEOM_MESH and geom.parent.explicitinertial:
            spec.delete(geom)
    used = {geom.meshname for geom in spec.geoms}
    for mesh in list(spec.meshes):
        if mesh.name not in used:
            spec.delete(mesh)


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
        from sim2real.effects import apply_to_spec
        from sim2real.lab import arm_spec

        if not strip:
            spec = arm_spec(self.mjcf_path, joints)
        else:
            if tuple(joints) not in self._bases:
                base = arm_spec(self.mjcf_path, joints)
                _drop_inert_meshes(base)
                self._bases[tuple(joints)] = base
            spec = self._bases[tuple(joints)].copy()
        if identified:
            apply_to_spec(spec, dict(identified), include_urdf_effects=True)
        return spec

    def get(self, joints: Sequence[str], identified: Mapping[str, Any] | None = None,
            ) -> tuple[mujoco.MjModel, np.ndarray, np.ndarray]:
        """(model, qpos addresses, dof addresses) of the arm with ``identified`` written in (None: as built)."""
        from sim2real.lab import compile_arm

        key = (tuple(joints), json.dumps(identified or None, sort_keys=True))
        if key not in self._models:
            spec = self._spec(joints, identified, strip=True)
            if not _meshes_inert(spec):  # an effect switched on something that reads the geoms: keep them all
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
        mujoco.mj_getState(model, data, initial[b], spec)
        control[b][:, ctrl_cols] = prepared.tau_cmd[start:start + seg]
    state, _ = rollout.rollout(model, [mujoco.MjData(model) for _ in range(2)], initial, control)
    # state[b, i] is the state after step i, i.e. at sample start + i + 1
    qpos_off = 1  # FULLPHYSICS state = [time, qpos, qvel, act, ...]
    q_sim = state[:, :, qpos_off + qadr].reshape(-1, len(joints))
    qd_sim = state[:, :, qpos_off + model.nq + dadr].reshape(-1, len(joints))
    index = (starts[:, None] + 1 + np.arange(seg)[None, :]).reshape(-1)
    return q_sim, qd_sim, index


def spectral_divergence(sim: np.ndarray, real: np.ndarray) -> float:
    """KL divergence of normalised magnitude spectra of the positions (source chapter P02.5), mean over joints."""
    divs = []
    for j in range(min(sim.shape[1], 7)):
        s = np.abs(np.fft.rfft(sim[:, j]))
        r = np.abs(np.fft.rfft(real[:, j]))
        s = s / (s.sum() + 1e-10)
        r = r / (r.sum() + 1e-10)
        divs.append(float(np.sum(r * np.log((r + 1e-10) / (s + 1e-10)))))
    return float(np.mean(divs))


def reality_gap(pos_rmse: float, vel_rmse: float, tau_rmse: float, corr: float, spectral: float,
                contact_f1: float | None) -> dict[str, Any]:
    """Overall gap score, grade and recommendation of the source chapter's reality-gap metric."""
    terms = {
        "position": min(pos_rmse / 0.1, 1.0),
        "velocity": min(vel_rmse / 1.0, 1.0),
        "torque": min(tau_rmse / 5.0, 1.0),
        "correlation": 1.0 - corr,
        "spectral": min(spectral / 1.0, 1.0),
    }
    weights = dict(GAP_WEIGHTS)
    if contact_f1 is None:
        weights.pop("contact")
        total = sum(weights.values())
        weights = {k: v / total for k, v in weights.items()}
    else:
        terms["contact"] = 1.0 - contact_f1
    score = float(sum(weights[k] * terms[k] for k in weights))
    if score < 0.15:
        grade, rec = "low", "low gap: transfer directly, light domain randomization is enough"
    elif score < 0.35:
        grade, rec = "medium", "medium gap: calibrate with system identification, then moderate domain randomization"
    elif score < 0.6:
        grade, rec = "high", "high gap: re-identify the physical parameters and check the contact model"
    else:
        grade, rec = "very_high", "very high gap: the model is probably fundamentally wrong; re-check the URDF"
    return {"score": score, "grade": grade, "recommendation": rec,
            "weights": {k: float(v) for k, v in weights.items()}, "terms": {k: float(v) for k, v in terms.items()}}


def fidelity_grade(mean_abs_position_error: float) -> str:
    if mean_abs_position_error < 0.02:
        return "high"
    if mean_abs_position_error <= 0.1:
        return "medium"
    return "low"


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
        "correlation": _per_joint_dict(corr, joints, float(corr.mean())),
        "spectral_divergence": spectral,
        "contact_f1": None,
        "contact_note": "no contact flags compared (free-space motion); the contact term is left out of the score",
        "mean_abs_position_error": mean_abs,
        "fidelity": fidelity_grade(mean_abs),
        "reality_gap": gap,
    }


def ladder_position_rmse(
    mjcf_path: str | Path, comparisons: Sequence[TorqueComparison], horizon_s: float,
    ladder: Sequence[Mapping[str, Any]], torque_source: str | None, models: ReplayModels | None = None,
) -> list[dict[str, Any] | None]:
    """Position RMSE of each rung's replay on the holdout runs with commands (None where there is none)."""
    holdout = [c for c in comparisons if c.role == "holdout" and c.run.tau_cmd is not None]
    if not holdout:
        return [None for _ in ladder]
    joints = holdout[0].run.joint_names
    models = models if models is not None else ReplayModels(mjcf_path)
    out: list[dict[str, Any] | None] = []
    for rung in ladder:
        identified = {"effects": rung.get("params") or {}, "torque_source": torque_source}
        errors = []
        for c in holdout:
            q_sim, _, idx = replay(mjcf_path, c.run, horizon_s, identified, models)
            error = q_sim - c.run.q[idx]
            errors.append(error[np.all(np.isfinite(error), axis=1)])
        out.append(rmse(np.concatenate(errors), joints))
    return out


# ---------------------------------------------------------------------------------------------
# where it fails


def _stratified_step(r: np.ndarray, pos: np.ndarray, neg: np.ndarray, strata: np.ndarray) -> float:
    """|mean(r | pos) - mean(r | neg)| within each stratum, averaged with the stratum sizes."""
    total, weight = 0.0, 0
    for value in (-1.0, 1.0):
        a, b = pos & (strata == value), neg & (strata == value)
        if a.sum() > 10 and b.sum() > 10:
            n = int(a.sum() + b.sum())
            total += n * float(r[a].mean() - r[b].mean())
            weight += n
    return abs(total / weight) if weight else 0.0


def where_it_fails(
    comparisons: Sequence[TorqueComparison], lower: np.ndarray, upper: np.ndarray, noise_floor: np.ndarray,
) -> dict[str, Any]:
    joints = comparisons[0].run.joint_names
    masks = [regime_masks(c.run, c.gravity, lower, upper) for c in comparisons]
    residual = np.concatenate([c.residual for c in comparisons])
    overall = np.sqrt(np.mean(residual**2, axis=0))
    per_joint: dict[str, Any] = {}
    findings = []
    for jj, joint in enumerate(joints):
        entry: dict[str, Any] = {"rmse": float(overall[jj]), "noise_floor": float(noise_floor[jj]), "regimes": {}}
        for regime in REGIMES:
            inside = np.concatenate([m[regime][0][:, jj] for m in masks])
            side = np.concatenate([m[regime][1][:, jj] for m in masks])
            r = residual[:, jj]
            n_in = int(inside.sum())
            if n_in < 20 or n_in == inside.size:
                entry["regimes"][regime] = {"fraction": n_in / inside.size, "applicable": False}
                continue
            rin = r[inside]
            pos, neg = inside & (side > 0), inside & (side < 0)
            strata = np.concatenate([m[regime][2][:, jj] for m in masks])
            step = _stratified_step(r, pos, neg, strata)
            p = pos.sum() / max(n_in, 1)
            # share of the in-regime residual power that the two-sided step explains
            explained = float(min(1.0, step**2 * p * (1 - p) / max(np.mean(rin**2), 1e-18)))
            rmse_in = float(np.sqrt(np.mean(rin**2)))
            rmse_out = float(np.sqrt(np.mean(r[~inside] ** 2)))
            entry["regimes"][regime] = {
                "applicable": True, "fraction": float(n_in / inside.size), "rmse": rmse_in, "rmse_outside": rmse_out,
                "step": step, "explained": explained,
            }
            systematic = step > 3.0 * noise_floor[jj] and step > 0.5 * overall[jj]
            if systematic and explained > 0.2:
                findings.append({"joint": joint, "regime": regime, "step": step, "explained": explained,
                                 "rmse_in_regime": rmse_in, "label": REGIME_LABELS[regime]})
        per_joint[joint] = entry
    # keep, per joint, the regimes whose step is comparable to that joint's strongest one
    strongest = {}
    for f in findings:
        strongest[f["joint"]] = max(strongest.get(f["joint"], 0.0), f["step"] * f["explained"])
    findings = [f for f in findings if f["step"] * f["explained"] >= 0.5 * strongest[f["joint"]]]
    findings.sort(key=lambda f: (-f["step"] * f["explained"], f["joint"], f["regime"]))
    regime_counts: dict[str, int] = {}
    for f in findings:
        regime_counts[f["regime"]] = regime_counts.get(f["regime"], 0) + 1
    return {
        "per_joint": per_joint,
        "findings": findings,
        "summary": {
            "joints": sorted({f["joint"] for f in findings}, key=joints.index),
            "regimes": sorted(regime_counts, key=lambda r: (-regime_counts[r], r)),
        },
        "worst_windows": worst_windows(comparisons, masks),
        "definitions": {
            **REGIME_DEFINITIONS,
            "step": "|mean residual on one side - on the other| in N*m: an error that lives in the regime",
            "explained": "share of the in-regime residual power explained by that step (0..1)",
            "finding": "step > 3x noise floor and > 0.5x the joint RMSE and explained > 0.2",
        },
    }


def worst_windows(comparisons: Sequence[TorqueComparison], masks: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The N worst non-overlapping windows (by residual RMSE over all joints), with stamps."""
    candidates = []
    for c, m in zip(comparisons, masks):
        w = max(1, int(round(WINDOW_S / c.run.dt)))
        n_win = c.residual.shape[0] // w
        for k in range(n_win):
            block = c.residual[k * w:(k + 1) * w]
            per_joint = np.sqrt(np.mean(block**2, axis=0))
            jj = int(np.argmax(per_joint))
            shares = {r: float(m[r][0][k * w:(k + 1) * w, jj].mean()) for r in REGIMES}
            candidates.append({
                "run": c.run.name,
                "t_start": float(c.run.time[k * w]),
                "t_end": float(c.run.time[min((k + 1) * w, c.run.time.size - 1)]),
                "rmse": float(np.sqrt(np.mean(block**2))),
                "worst_joint": c.run.joint_names[jj],
                "worst_joint_rmse": float(per_joint[jj]),
                "regime_share": shares,
            })
    candidates.sort(key=lambda x: (-x["rmse"], x["run"], x["t_start"]))
    return candidates[:N_WORST_WINDOWS]


# ---------------------------------------------------------------------------------------------
# assembly


def model_armature(mjcf_path: str | Path, joints: Sequence[str], models: ReplayModels | None = None,
                   ) -> dict[str, float]:
    """Rotor inertia (armature) of the measured joints as the built MJCF has it.

    The URDF cannot hold armature; the MJCF gets it from configs/{robot}/robot.yaml. Reading it back
    from the MJCF keeps the Pinocchio model and the MuJoCo replay the same model.
    """
    models = models if models is not None else ReplayModels(mjcf_path)
    model, _, dadr = models.get(joints)
    return {j: float(model.dof_armature[d]) for j, d in zip(joints, dadr)}


def read_model_residuals(path: str | Path, model: RigidBodyModel) -> list[TorqueComparison]:
    """The last rung's holdout comparisons from the sysid rule's residuals (:func:`sim2real.sysid.write_model_residuals`):
    each holdout run at the fit's rate, its judged torque, the current model's prediction and residual."""
    import zipfile

    from sim2real.files import read_array_archive

    try:
        header, arrays = read_array_archive(path, lambda name: name.startswith("holdout/"))
        joints = list(header["joints"])
        out = []
        for run in header["roles"]["holdout"]["runs"]:
            rows = slice(int(run["start"]), int(run["stop"]))
            part = {name: arrays[f"holdout/{name}"][rows] for name in ("time", "q", "qd", "qdd", "tau", "residual")}
            dt = float(np.median(np.diff(part["time"]))) if part["time"].size > 1 else 0.0
            prepared = PreparedRun(name=run["name"], joint_names=joints, time=part["time"], dt=dt, q=part["q"],
                                   qd=part["qd"], qdd=part["qdd"], tau=part["tau"], torque_source=header["torque_source"],
                                   tau_cmd=None, q_cmd=None, filter={}, torque_sensor=header["torque_sensor"])
            out.append(TorqueComparison(run=prepared, role="holdout", model_tau=part["tau"] - part["residual"],
                                        residual=part["residual"], gravity=model.gravity(part["q"])))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise InputError(path, None, f"not a file of the model's residuals ({exc})",
                         "rebuild it: snakemake --forcerun sysid") from exc
    return out


def current_model(precomputed: Mapping[str, Any]) -> dict[str, Any]:
    """What the report judges: the last rung of the body link's ladder (and of the actuator link's, which the
    replay drives), as ``identified`` for :func:`replay`, and its name."""
    body = precomputed["ladder"][-1]
    params = dict(body.get("params") or {})
    if precomputed.get("actuator"):
        params.update(precomputed["actuator"]["ladder"][-1].get("params") or {})
    return {"effects": list(body["effects"]), "rung": len(precomputed["ladder"]) - 1,
            "identified": {"effects": params, "torque_source": precomputed.get("torque_source")}}


def compute_gap(
    robot: str, urdf_path: str | Path, mjcf_path: str | Path | None, measurement_list: str | Path,
    root: str | Path = ".", precomputed: Mapping[str, Any] | None = None, cache: FitCache | None = None,
    progress: Callable[[dict[str, Any], list[TorqueComparison] | None], Any] | None = None,
    residuals_path: str | Path | None = None,
) -> tuple[dict[str, Any], list[TorqueComparison]]:
    """The gap.json content (validated) and the per-run comparisons (for figures).

    ``measurement_list``: the measurement list, or the runs prepared from it (``.npz``); ``cache``: replays of
    an earlier report kept there (:class:`ReplayModels`); ``progress``: called with the part of the content
    known so far, twice: the joints, the noise floor and the precomputed sections (no comparisons yet), then
    with the torque domain (the runs, the torque metrics, where it fails) and the comparisons, before the
    commands are replayed (the report draws each figure as soon as what it shows is known).

    With a ladder (``precomputed``) and its residuals (``residuals_path``, the sysid rule's), the report
    describes the model being calibrated, the ladder's last rung: the top-level ``metrics`` (on the holdout
    runs, as the ladder judges) and ``where`` are its, and the returned comparisons too; the nominal URDF's
    (every run, at the log's rate) move under ``nominal``, for reference."""
    # joints come from the first run, the model locks everything else
    entries, prepared, settings = runs_for_model(measurement_list, urdf_path, root)
    models = ReplayModels(mjcf_path, cache) if mjcf_path is not None else None
    armature = model_armature(mjcf_path, prepared[0].joint_names, models) if mjcf_path is not None else None
    model = RigidBodyModel(urdf_path, prepared[0].joint_names, armature=armature)
    joints = model.joint_names

    floors = np.array([noise_floor_of(p) for p in prepared])
    weights = np.array([p.time.size for p in prepared], dtype=float)
    floor = np.sqrt(np.average(floors**2, axis=0, weights=weights))
    noise_floor = {"torque_rmse": _per_joint_dict(floor, joints, float(np.sqrt(np.mean(floor**2)))),
                   "method": "white part of the raw torque from second differences (MAD), per joint; "
                             "a model that explains everything else has about this RMSE"}
    gap: dict[str, Any] = {"robot": robot, "joints": joints, "noise_floor": noise_floor}
    for key in ("ladder", "diagnosis", "actuator", "links"):
        if precomputed and key in precomputed:
            gap[key] = json.loads(json.dumps(precomputed[key]))
    if progress is not None:
        progress(gap, None)

    comparisons = []
    for e, p in zip(entries, prepared):
        model_tau = model.inverse_dynamics(p.q, p.qd, p.qdd)
        if p.torque_source == "tau" and p.torque_sensor == "link":  # measured after the drive: the links alone
            model_tau = model_tau - model.drive_torque(p.qd, p.qdd)
        comparisons.append(TorqueComparison(run=p, role=e.role, model_tau=model_tau, residual=p.tau - model_tau,
                                            gravity=model.gravity(p.q)))
    measured = np.concatenate([c.run.tau for c in comparisons])
    residual = np.concatenate([c.residual for c in comparisons])
    metrics = torque_metrics(measured, residual, joints)

    runs_out = []
    for e, c in zip(entries, comparisons):
        p = c.run
        per_run = torque_metrics(p.tau, c.residual, joints)
        runs_out.append({
            "name": e.name, "path": Path(e.path).as_posix(), "role": e.role, "torque_source": p.torque_source,
            "samples": int(p.time.size), "duration_s": float(p.time[-1] - p.time[0]),
            "has_commands": p.tau_cmd is not None, "filter": p.filter,
            "torque_rmse": per_run["torque_rmse"],
            "noise_floor": _per_joint_dict(noise_floor_of(p), joints,
                                           float(np.sqrt(np.mean(noise_floor_of(p) ** 2)))),
        })

    nominal = {"metrics": metrics, "where": where_it_fails(comparisons, model.lower, model.upper, floor)}
    current = current_model(precomputed) if precomputed and "ladder" in gap and residuals_path is not None else None
    judged = comparisons
    if current is None:
        gap.update({"runs": runs_out, "metrics": metrics, "where": nominal["where"]})
    else:
        judged = read_model_residuals(residuals_path, model)
        last = torque_metrics(np.concatenate([c.run.tau for c in judged]),
                              np.concatenate([c.residual for c in judged]), joints)
        last["model"] = {
            "rung": current["rung"], "effects": current["effects"],
            "judged_on": "the holdout runs at the fit's rate, as the ladder judges each rung (the nominal URDF's "
            "metrics under nominal: every run at the log's rate)"}
        gap.update({"runs": runs_out, "metrics": last, "where": where_it_fails(judged, model.lower, model.upper, floor),
                    "nominal": nominal})
    if progress is not None:
        progress(gap, judged)

    # The current model is replayed on the holdout runs, where it is judged (the ladder's last rung replays the
    # same: one replay for both); the nominal MJCF on every run.
    holdout = [c for c in comparisons if c.role == "holdout"]
    sections = ([(metrics, None, comparisons)] if current is None
                else [(metrics, None, comparisons), (gap["metrics"], current["identified"], holdout)])
    for section, identified, replayed in sections:
        if mjcf_path is None:
            section["state_domain"] = {"status": "skipped", "reason": "no MJCF given to replay the commands in"}
        else:
            section["state_domain"] = state_domain(mjcf_path, replayed, settings["horizon_s"],
                                                   section["torque_rmse"]["overall"], models, identified)
        if section["state_domain"]["status"] == "computed":
            section["position_rmse"] = section["state_domain"]["position_rmse"]
            section["velocity_rmse"] = section["state_domain"]["velocity_rmse"]
    if precomputed and "ladder" in gap and mjcf_path is not None and metrics["state_domain"]["status"] == "computed":
        # Each rung replayed with its fitted effects written into the MJCF: the state-domain view of the ladder.
        positions = ladder_position_rmse(mjcf_path, comparisons, settings["horizon_s"], gap["ladder"],
                                         precomputed.get("torque_source"), models)
        for rung, position in zip(gap["ladder"], positions):
            if position is not None:
                rung["metrics"]["position_rmse"] = position
        if "actuator" in gap:
            # The actuator's rungs replayed on the body link's last rung: the commands reach that body.
            body = gap["ladder"][-1].get("params") or {}
            rungs = [{**rung, "params": {**body, **(rung.get("params") or {})}} for rung in gap["actuator"]["ladder"]]
            positions = ladder_position_rmse(mjcf_path, comparisons, settings["horizon_s"], rungs,
                                             precomputed.get("torque_source"), models)
            for rung, position in zip(gap["actuator"]["ladder"], positions):
                if position is not None:
                    rung["metrics"]["position_rmse"] = position
    gap = json.loads(json.dumps(gap))  # plain JSON types only
    validate(gap, "gap.schema.json", "gap.json")
    return gap, judged


def build_gap_report(
    robot: str, urdf_path: str | Path, mjcf_path: str | Path | None, measurement_list: str | Path,
    gap_json: str | Path, gap_md: str | Path, figures: Mapping[str, str | Path],
    precomputed_path: str | Path | None = None, root: str | Path = ".", threads: int = 1,
    cache_dir: str | Path | None = None, residuals_path: str | Path | None = None,
) -> dict[str, Any]:
    """Write gap.json, gap.md and the figures (keys: :data:`sim2real.report.FIGURES`); the figures
    are drawn on up to ``threads`` processes. ``cache_dir``: where the replays and figures are kept for the
    next report (:class:`sim2real.cache.FitCache`; None: not kept): a round of the loop that adds a
    rung replays that rung and redraws what shows the ladder, and reads the rest back, the same bytes."""
    from sim2real.report import GapFigures, render_gap_markdown

    precomputed = None
    if precomputed_path is not None and Path(precomputed_path).exists():
        precomputed = json.loads(Path(precomputed_path).read_text(encoding="utf-8"))
    cache = FitCache(cache_dir)
    drawing = GapFigures(figures, threads, cache)  # each figure drawn as soon as what it shows is known
    if precomputed is None or residuals_path is None or not Path(residuals_path).exists():
        residuals_path = None
    gap, comparisons = compute_gap(robot, urdf_path, mjcf_path, measurement_list, root, precomputed, cache,
                                   drawing.show, residuals_path)
    drawing.finish()
    md_dir = Path(gap_md).parent
    rel = {k: Path(os_relpath(v, md_dir)).as_posix() for k, v in figures.items()}
    from sim2real.files import write_text

    write_text(gap_md, render_gap_markdown(gap, rel))
    write_json(gap_json, gap)
    cache.prune()
    return gap


def os_relpath(path: str | Path, start: str | Path) -> str:
    import os

    return os.path.relpath(Path(path), Path(start))
