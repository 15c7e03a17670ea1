"""The gap report: how far the model is from the measurements, and where it fails.

* Torque domain: inverse dynamics of the URDF model (Pinocchio, ``RigidBodyModel``) on the prepared
  q, qd, qdd against the prepared torque (measured ``tau``, else ``tau_cmd``): RMSE per joint and
  overall, RMSE relative to the torque's RMS, R^2.
* State domain, where commands exist: the commanded torques are replayed in MuJoCo (the built MJCF
  driven by joint torques, see ``sim2real.assets.arm.arm_spec``) with multiple shooting: every ``horizon_s``
  the simulation restarts from the measured state (``mujoco.rollout``, one segment per batch row).
  Position/velocity RMSE, correlation, spectral divergence and the reality-gap metric of the source
  chapter (P02.5): score = 0.3 min(pos/0.1,1) + 0.2 min(vel/1,1) + 0.15 min(tau/5,1) + 0.15 (1-corr)
  + 0.1 min(spec/1,1) + 0.1 (1-contact F1). ``tau`` is the torque-domain RMSE. Without contact flags
  the contact term is not applicable and the other weights are renormalised to sum to 1 (an arm in
  free space would otherwise be charged 0.1 for contacts that do not exist).
* Where it fails: per joint and regime (slow motion and velocity reversals, hard accelerations,
  gravity-loaded poses, near the limits; defined in ``sim2real.report.regimes``), and the worst time windows
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

import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.cache import FitCache
from sim2real.assets.dynamics import RigidBodyModel
from sim2real.errors import InputError
from sim2real.files import relative_path, validate, write_json
from sim2real.measurements import PreparedRun, measured_after_drive, noise_floor_of, runs_for_model
from sim2real.report.metrics import TorqueComparison, per_joint_dict, torque_metrics
from sim2real.report.regimes import where_it_fails
from sim2real.report.replay import ReplayModels, ladder_position_rmse, model_armature, state_domain
from sim2real.report.verdicts import worded

def read_model_residuals(path: str | Path, model: RigidBodyModel) -> list[TorqueComparison]:
    """The last rung's holdout comparisons from the sysid rule's residuals (:func:`sim2real.identification.sysid.write_model_residuals`):
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
                                   tau_cmd=None, q_cmd=None, filter=None, torque_sensor=header["torque_sensor"])
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
    prepared = runs_for_model(measurement_list, urdf_path, root)
    settings = prepared.settings
    models = ReplayModels(mjcf_path, cache) if mjcf_path is not None else None
    armature = model_armature(mjcf_path, prepared[0].joint_names, models) if mjcf_path is not None else None
    model = RigidBodyModel(urdf_path, prepared[0].joint_names, armature=armature)
    joints = model.joint_names

    floors = np.array([noise_floor_of(p) for p in prepared])
    weights = np.array([p.time.size for p in prepared], dtype=float)
    floor = np.sqrt(np.average(floors**2, axis=0, weights=weights))
    noise_floor = {"torque_rmse": per_joint_dict(floor, joints, float(np.sqrt(np.mean(floor**2)))),
                   "method": "white part of the raw torque from second differences (MAD), per joint; "
                             "a model that explains everything else has about this RMSE"}
    gap: dict[str, Any] = {"robot": robot, "joints": joints, "noise_floor": noise_floor}
    sections = worded(precomputed, robot) if precomputed else {}
    for key in ("ladder", "diagnosis", "actuator", "links"):
        if key in sections:
            gap[key] = json.loads(json.dumps(sections[key]))
    if progress is not None:
        progress(gap, None)

    comparisons = []
    for p in prepared:
        model_tau = model.inverse_dynamics(p.q, p.qd, p.qdd)
        if measured_after_drive(p.torque_source, p.torque_sensor):  # the links alone: no drive terms
            model_tau = model_tau - model.drive_torque(p.qd, p.qdd)
        comparisons.append(TorqueComparison(run=p, role=p.role, model_tau=model_tau, residual=p.tau - model_tau,
                                            gravity=model.gravity(p.q)))
    measured = np.concatenate([c.run.tau for c in comparisons])
    residual = np.concatenate([c.residual for c in comparisons])
    metrics = torque_metrics(measured, residual, joints)

    runs_out = []
    for c in comparisons:
        p = c.run
        per_run = torque_metrics(p.tau, c.residual, joints)
        runs_out.append({
            "name": p.name, "path": Path(p.entry.path).as_posix(), "role": p.role, "torque_source": p.torque_source,
            "samples": int(p.time.size), "duration_s": float(p.time[-1] - p.time[0]),
            "has_commands": p.tau_cmd is not None, "filter": p.filter.as_document(),
            "torque_rmse": per_run["torque_rmse"],
            "noise_floor": per_joint_dict(noise_floor_of(p), joints,
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
    """Write gap.json, gap.md and the figures (keys: :data:`sim2real.report.figures.FIGURES`); the figures
    are drawn on up to ``threads`` processes. ``cache_dir``: where the replays and figures are kept for the
    next report (:class:`sim2real.cache.FitCache`; None: not kept): a round of the loop that adds a
    rung replays that rung and redraws what shows the ladder, and reads the rest back, the same bytes."""
    from sim2real.report.figures import GapFigures
    from sim2real.report.markdown import render_gap_markdown

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
    rel = {k: relative_path(v, md_dir) for k, v in figures.items()}
    from sim2real.files import write_text

    write_text(gap_md, render_gap_markdown(gap, rel))
    write_json(gap_json, gap)
    cache.prune()
    return gap
