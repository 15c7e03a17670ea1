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

``compute_gap`` returns the gap.json content of a :class:`GapInputs` (the robot, its model files, its runs,
the sysid rule's ladder and residuals); ``build_gap_report`` writes gap.json, gap.md and the figures. An
optional precomputed section (``ladder``, ``diagnosis``, ``actuator``, ``links``, from the sysid rule) is
merged in; each rung of either link is replayed with its fitted effects.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.cache import FitCache
from sim2real.assets.dynamics import RigidBodyModel
from sim2real.errors import InputError
from sim2real.files import relative_path, validate, write_json
from sim2real.identification.formats import read_ladder, read_model_residuals
from sim2real.identification.ladder_rows import LadderDocument, Rung
from sim2real.measurements import PreparedRun, RunSet, measured_after_drive, noise_floor_of, runs_for_model
from sim2real.measurements.motion import not_judged_document
from sim2real.measurements.noise import floor_method_document
from sim2real.report.gap_document import GapReport, nominal_section
from sim2real.report.metrics import TorqueComparison, per_joint_dict, torque_metrics
from sim2real.report.regimes import where_it_fails
from sim2real.report.replay import ReplayModels, ladder_position_rmse, model_armature, state_domain
from sim2real.report.verdicts import worded

def holdout_comparisons(path: str | Path, model: RigidBodyModel) -> list[TorqueComparison]:
    """The last rung's holdout comparisons from the sysid rule's residuals (:func:`sim2real.identification.formats.
    read_model_residuals`): each holdout run at the fit's rate, its judged torque, the current model's prediction
    and residual."""
    import zipfile

    try:
        residuals = read_model_residuals(path, roles=("holdout",))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise InputError(path, None, f"not a file of the model's residuals ({exc})",
                         "rebuild it: snakemake --forcerun sysid") from exc
    out = []
    for name, part in residuals.roles["holdout"].by_run():
        dt = float(np.median(np.diff(part["time"]))) if part["time"].size > 1 else 0.0
        prepared = PreparedRun(name=name, joint_names=list(residuals.joints), time=part["time"], dt=dt, q=part["q"],
                               qd=part["qd"], qdd=part["qdd"], tau=part["tau"], torque_source=residuals.torque_source,
                               tau_cmd=None, q_cmd=None, filter=None, torque_sensor=residuals.torque_sensor)
        out.append(TorqueComparison(run=prepared, role="holdout", model_tau=part["tau"] - part["residual"],
                                    residual=part["residual"], gravity=model.gravity(part["q"])))
    return out


def current_model(precomputed: Mapping[str, Any]) -> dict[str, Any]:
    """What the report judges: the last rung of the body link's ladder (and of the actuator link's, which the
    replay drives), as ``identified`` for :func:`replay`, and its name."""
    read = LadderDocument.from_document(precomputed)
    ladder = read.body.rungs
    params = dict(ladder[-1].values)
    if read.actuator is not None:
        params.update(read.actuator.rungs[-1].values)
    return {"effects": list(ladder[-1].effects), "rung": len(ladder) - 1,
            "identified": {"effects": params, "torque_source": read.torque_source}}


@dataclass(frozen=True)
class GapInputs:
    """What a gap report is made from: the robot's name, its URDF and MJCF (None: the commands are not replayed),
    its runs (the measurement list, or the runs prepared from it, ``.npz``; paths in the list are relative to
    ``root``), and the sysid rule's ladder (``ladder.json``) and the last rung's residuals (``residuals.npz``),
    where the robot has a model ladder."""

    robot: str
    urdf: str | Path
    mjcf: str | Path | None
    measurements: str | Path
    root: str | Path = "."
    ladder: str | Path | None = None
    residuals: str | Path | None = None

    def read_ladder(self) -> dict[str, Any] | None:
        """The ladder's sections (``ladder``, ``diagnosis``, ``actuator``, ``links``), None without a ladder file."""
        if self.ladder is None or not Path(self.ladder).exists():
            return None
        return read_ladder(self.ladder)


def compute_gap(
    inputs: GapInputs, precomputed: Mapping[str, Any] | None = None, cache: FitCache | None = None,
    progress: Callable[[GapReport, list[TorqueComparison] | None], Any] | None = None,
) -> tuple[dict[str, Any], list[TorqueComparison]]:
    """The gap.json content (validated) and the per-run comparisons (for figures).

    ``precomputed``: the ladder's sections (default: read from ``inputs.ladder``, none without it); ``cache``:
    replays of an earlier report kept there (:class:`ReplayModels`); ``progress``: called with the part of the
    report known so far (a :class:`~sim2real.report.gap_document.GapReport`), twice: the joints, the noise floor and
    the precomputed sections (no comparisons yet), then with the torque domain (the runs, the torque metrics, where
    it fails) and the comparisons, before the commands are replayed (the report draws each figure as soon as what
    it shows is known).

    With a ladder (``precomputed``) and its residuals (``inputs.residuals``, the sysid rule's), the report
    describes the model being calibrated, the ladder's last rung: the top-level ``metrics`` (on the holdout
    runs, as the ladder judges) and ``where`` are its, and the returned comparisons too; the nominal URDF's
    (every run, at the log's rate) move under ``nominal``, for reference.

    Parameters
    ----------
    inputs : GapInputs
        The robot's name, URDF, MJCF (None: no replay), measurement list and root, ladder and residuals.
    precomputed : mapping, optional
        The ladder's sections; default: read from ``inputs.ladder``.
    cache : FitCache, optional
        Where replays of an earlier report are kept.
    progress : callable, optional
        Called twice with the content known so far (see above).

    Returns
    -------
    tuple of (dict, list of TorqueComparison)
        The gap.json content, validated against ``schemas/gap.schema.json``, and each run's comparison.

    Raises
    ------
    InputError
        A run, the measurement list or the URDF is bad (naming the file, the column and the fix).

    Examples
    --------
    The nominal URDF against two runs, without a ladder and without replaying the commands:

    >>> inputs = GapInputs("panda", urdf, None, example_dir / "measurements.yaml", root=example_dir)
    >>> gap, comparisons = compute_gap(inputs)
    >>> gap["joints"][:2], [run["name"] for run in gap["runs"]], len(comparisons)
    (['panda_joint1', 'panda_joint2'], ['fit', 'holdout'], 2)
    >>> sorted(gap["metrics"])
    ['state_domain', 'torque_r2', 'torque_relative_rmse', 'torque_rmse']
    """
    if precomputed is None:
        precomputed = inputs.read_ladder()
    prepared = runs_for_model(inputs.measurements, inputs.urdf, inputs.root)
    torque_source = LadderDocument.from_document(precomputed).torque_source if precomputed else None
    replay = _Replay(inputs.mjcf, ReplayModels(inputs.mjcf, cache) if inputs.mjcf is not None else None,
                     prepared.settings, torque_source)
    model = _rigid_body_model(inputs.urdf, prepared, replay)
    floor, report = _gap_head(inputs.robot, model.joint_names, prepared, precomputed)
    if progress is not None:
        progress(report, None)

    comparisons = _torque_comparisons(prepared, model)
    laddered = bool(precomputed) and report.ladder is not None
    current = current_model(precomputed) if laddered and inputs.residuals is not None else None
    report, judged = _torque_domain(report, comparisons, model, floor, current, inputs.residuals)
    if progress is not None:
        progress(report, judged)

    nominal = report.nominal_metrics if current is not None else report.metrics
    _replay_models(report, nominal, comparisons, current, replay)
    if laddered and replay.mjcf is not None and nominal["state_domain"]["status"] == "computed":
        report = _replay_ladders(report, comparisons, replay)
    gap = json.loads(json.dumps(report.as_document()))  # plain JSON types only
    validate(gap, "gap.schema.json", "gap.json")
    return gap, judged


@dataclass(frozen=True)
class _Replay:
    """How the report replays the commands: in the MJCF (None: not replayed) through its compiled models, with
    multiple shooting every ``settings["horizon_s"]`` (the runs' settings); ``torque_source``: the ladder's, for its
    rungs' replays."""

    mjcf: str | Path | None
    models: ReplayModels | None
    settings: Mapping[str, Any]
    torque_source: str | None


def _rigid_body_model(urdf: str | Path, prepared: RunSet[PreparedRun], replay: _Replay) -> RigidBodyModel:
    """The URDF's inverse dynamics on the first run's joints (the model locks everything else), with the MJCF's
    armature where there is one."""
    joints = prepared[0].joint_names
    armature = model_armature(replay.mjcf, joints, replay.models) if replay.mjcf is not None else None
    return RigidBodyModel(urdf, joints, armature=armature)


def _gap_head(robot: str, joints: list[str], prepared: RunSet[PreparedRun],
              precomputed: Mapping[str, Any] | None) -> tuple[np.ndarray, GapReport]:
    """The arm-wide noise floor per joint (the runs' floors weighed by their samples), and what gap.json knows
    before any comparison: the robot, the joints, that floor and the ladder's sections, in their words."""
    floors = np.array([noise_floor_of(p) for p in prepared])
    weights = np.array([p.time.size for p in prepared], dtype=float)
    floor = np.sqrt(np.average(floors**2, axis=0, weights=weights))
    noise_floor = {"torque_rmse": per_joint_dict(floor, joints, float(np.sqrt(np.mean(floor**2)))),
                   **floor_method_document(prepared, joints)}
    # not_judged: the joints the fit runs barely move, their drives held at the URDF's (None: every joint judged)
    report = GapReport(robot, tuple(joints), noise_floor, not_judged=not_judged_document(prepared.fit))
    return floor, report.with_ladder(worded(precomputed, robot) if precomputed else {})


def _torque_comparisons(prepared: RunSet[PreparedRun], model: RigidBodyModel) -> list[TorqueComparison]:
    """Each run's torque against the nominal URDF's inverse dynamics on its motion."""
    comparisons = []
    for p in prepared:
        model_tau = model.inverse_dynamics(p.q, p.qd, p.qdd)
        if measured_after_drive(p.torque_source, p.torque_sensor):  # the links alone: no drive terms
            model_tau = model_tau - model.drive_torque(p.qd, p.qdd)
        comparisons.append(TorqueComparison(run=p, role=p.role, model_tau=model_tau, residual=p.tau - model_tau,
                                            gravity=model.gravity(p.q)))
    return comparisons


def _run_document(c: TorqueComparison, joints: list[str]) -> dict[str, Any]:
    """A run as gap.json lists it: where it comes from, its size, its preparation, its torque error and floor."""
    p = c.run
    per_run = torque_metrics(p.tau, c.residual, joints)
    return {
        "name": p.name, "path": Path(p.entry.path).as_posix(), "role": p.role, "torque_source": p.torque_source,
        "samples": int(p.time.size), "duration_s": float(p.time[-1] - p.time[0]),
        "has_commands": p.tau_cmd is not None, "filter": p.filter.as_document(),
        "torque_rmse": per_run["torque_rmse"],
        "noise_floor": per_joint_dict(noise_floor_of(p), joints, float(np.sqrt(np.mean(noise_floor_of(p) ** 2)))),
    }


def _torque_domain(report: GapReport, comparisons: list[TorqueComparison], model: RigidBodyModel,
                   floor: np.ndarray, current: Mapping[str, Any] | None,
                   residuals_path: str | Path | None) -> tuple[GapReport, list[TorqueComparison]]:
    """``report`` with the runs, the torque metrics and where the model fails; the comparisons judged. Without a
    current model (``current``), the nominal URDF's on every run; with one, its own on the holdout runs (from
    the sysid rule's residuals), and the nominal URDF's under ``nominal``."""
    joints = model.joint_names
    metrics = torque_metrics(np.concatenate([c.run.tau for c in comparisons]),
                             np.concatenate([c.residual for c in comparisons]), joints)
    runs_out = tuple(_run_document(c, joints) for c in comparisons)
    where = where_it_fails(comparisons, model.lower, model.upper, floor)
    if current is None:
        return replace(report, runs=runs_out, metrics=metrics, where=where), comparisons
    judged = holdout_comparisons(residuals_path, model)
    last = torque_metrics(np.concatenate([c.run.tau for c in judged]),
                          np.concatenate([c.residual for c in judged]), joints)
    last["model"] = {
        "rung": current["rung"], "effects": current["effects"],
        "judged_on": "the holdout runs at the fit's rate, as the ladder judges each rung (the nominal URDF's "
        "metrics under nominal: every run at the log's rate)"}
    return replace(report, runs=runs_out, metrics=last, where=where_it_fails(judged, model.lower, model.upper, floor),
                   nominal=nominal_section(metrics, where)), judged


def _replay_models(report: GapReport, nominal: dict[str, Any], comparisons: list[TorqueComparison],
                   current: Mapping[str, Any] | None, replay: _Replay) -> None:
    """The state domain of ``nominal`` (the nominal MJCF on every run) and of the current model (on the holdout
    runs, where it is judged; the ladder's last rung replays the same: one replay for both)."""
    holdout = [c for c in comparisons if c.role == "holdout"]
    sections = ([(nominal, None, comparisons)] if current is None
                else [(nominal, None, comparisons), (report.metrics, current["identified"], holdout)])
    for section, identified, replayed in sections:
        if replay.mjcf is None:
            section["state_domain"] = {"status": "skipped", "reason": "no MJCF given to replay the commands in"}
        else:
            section["state_domain"] = state_domain(replay.mjcf, replayed, replay.settings["horizon_s"],
                                                   section["torque_rmse"]["overall"], replay.models, identified)
        if section["state_domain"]["status"] == "computed":
            section["position_rmse"] = section["state_domain"]["position_rmse"]
            section["velocity_rmse"] = section["state_domain"]["velocity_rmse"]


def _replay_ladders(report: GapReport, comparisons: list[TorqueComparison], replay: _Replay) -> GapReport:
    """``report`` with each rung replayed with its fitted effects written into the MJCF: the state-domain view of the
    ladder, in each rung's metrics (``position_rmse``); the actuator's rungs on the body's last rung."""
    ladder = report.ladder or ()
    positions = ladder_position_rmse(replay.mjcf, comparisons, replay.settings["horizon_s"], ladder,
                                     replay.torque_source, replay.models)
    report = replace(report, ladder=_with_positions(ladder, positions))
    if report.actuator is not None:
        # The actuator's rungs replayed on the body link's last rung: the commands reach that body.
        actuator = report.actuator.ladder
        on_body = [replace(rung, params={**ladder[-1].values, **rung.values}) for rung in actuator]
        positions = ladder_position_rmse(replay.mjcf, comparisons, replay.settings["horizon_s"], on_body,
                                         replay.torque_source, replay.models)
        report = replace(report, actuator=replace(report.actuator, ladder=_with_positions(actuator, positions)))
    return report


def _with_positions(ladder: Sequence[Rung], positions: Sequence[Mapping[str, Any] | None]) -> tuple[Rung, ...]:
    """A side's rungs, each with its replay's position RMSE where it has one."""
    return tuple(rung.with_position(position) if position is not None else rung
                 for rung, position in zip(ladder, positions, strict=True))


def build_gap_report(
    inputs: GapInputs, gap_json: str | Path, gap_md: str | Path, figures: Mapping[str, str | Path],
    threads: int = 1, cache_dir: str | Path | None = None, first_screen_html: str | Path | None = None,
) -> dict[str, Any]:
    """Write gap.json, gap.md and the figures (keys: :data:`sim2real.report.figures.FIGURES`), and gap.md's first
    screen as HTML for the Snakemake report (``first_screen_html``, where given); the figures
    are drawn on up to ``threads`` processes. The ladder and its residuals are used where their files exist.
    ``cache_dir``: where the replays and figures are kept for the next report (:class:`sim2real.cache.FitCache`;
    None: not kept): a round of the loop that adds a rung replays that rung and redraws what shows the ladder,
    and reads the rest back, the same bytes."""
    from sim2real.report.figures import GapFigures
    from sim2real.report.markdown import render_gap_markdown

    precomputed = inputs.read_ladder()
    cache = FitCache(cache_dir)
    drawing = GapFigures(figures, threads, cache)  # each figure drawn as soon as what it shows is known
    if precomputed is None or inputs.residuals is None or not Path(inputs.residuals).exists():
        inputs = replace(inputs, residuals=None)
    gap, comparisons = compute_gap(inputs, precomputed, cache, drawing.show)
    drawing.finish()
    md_dir = Path(gap_md).parent
    rel = {k: relative_path(v, md_dir) for k, v in figures.items()}
    from sim2real.files import write_text

    write_text(gap_md, render_gap_markdown(gap, rel))
    if first_screen_html is not None:
        from sim2real.report.first_screen import first_screen

        write_text(first_screen_html, first_screen(gap).html())
    write_json(gap_json, gap)
    cache.prune()
    return gap
