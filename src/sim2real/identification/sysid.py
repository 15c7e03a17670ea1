"""System identification: fit the model ladder of configs/{robot}/model.yaml to measured runs.

:func:`fit_ladder` composes the fitting core (:mod:`sim2real.identification.fitting`) and the diagnosis
(:mod:`sim2real.identification.diagnosis`): every rung (nominal, then each effect added in turn, refining only the
new effect's nonlinear parameters) fitted on the ``role: fit`` runs and judged on the
``role: holdout`` runs, then the diagnosis of the last rung. :func:`fit_model` runs it on each side
of the model (:mod:`sim2real.identification.sides`: the drive and the body, judged apart when the runs log
both the measured and the commanded torque) and adds what each side's diagnosis takes from the other
(:mod:`sim2real.identification.diagnosis.across`). It returns the ``ladder.json`` content, data without words
(:mod:`sim2real.report.verdicts` words it); :func:`~sim2real.identification.documents.params_document` and
:func:`sim2real.identification.effects.calibration_from_params` give params.yaml and calibration.yaml;
:func:`run_sysid` is the files-in, files-out entry point of the rule.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.blas import one_blas_thread
from sim2real.cache import FitCache
from sim2real.errors import InputError
from sim2real.forked import Forked
from sim2real.identification import sides
from sim2real.identification.diagnosis import DEFAULT_DIAGNOSIS, Diagnosis, diagnose, model_free_ceiling
from sim2real.identification.diagnosis.across import across_sides
from sim2real.identification.diagnosis.promise import kept_promise, promised_effect
from sim2real.identification.diagnosis.trials import trial_effects
from sim2real.identification.documents import params_document, round_floats
from sim2real.identification.effects import get_effect
from sim2real.identification.formats import (
    ModelResiduals, RoleResiduals, write_ladder, write_model_residuals, write_params,
)
from sim2real.identification.fitting import (
    DEFAULT_SETTINGS, PRIOR_START_SETTING, STILL_JOINTS_SETTING, FitContext, FitResult, NominalModel, Refinements,
    RunSamples, TorqueData, fit_on_the_previous, floor_units, holdout_metrics, load_nominal, predict, stack_runs,
)
from sim2real.identification.inertial.bands import InertiaBands
from sim2real.identification.model_config import ModelConfig, load_model_config
from sim2real.identification.records import Note, NoteKind, SensorPlacement, Side, Status
from sim2real.measurements import PreparedRun, noise_floor_of, torque_sensor_of
from sim2real.measurements.motion import still_joints
from sim2real.stats import rmse


@dataclasses.dataclass(frozen=True)
class SideLadder:
    """One side's ladder: its ``ladder.json`` content (``ladder``, ``noise_floor``, ...), the last rung's fit, the
    diagnosis of that rung (None when not asked for), and its residuals (judged minus predicted torque) on the
    holdout and the fit data (the fit data's: None on the drive side, whose diagnosis has no model-free ceiling)."""

    document: dict[str, Any]
    result: FitResult
    diagnosis: Diagnosis | None
    holdout_residual: np.ndarray
    fit_residual: np.ndarray | None

    def as_document(self) -> dict[str, Any]:
        """The side's ``ladder.json`` content with its diagnosis's document (a side judged alone)."""
        if self.diagnosis is None:
            return dict(self.document)
        return {**self.document, "diagnosis": round_floats(self.diagnosis.as_document())}


def state_domain_status(data: TorqueData) -> dict[str, str]:
    """The state-domain refinement replays commands in MuJoCo: skipped here, and why (``no_commands``: the runs have
    no commanded torque to replay; ``replayed_in_gap_report``: the gap report replays each rung)."""
    return {"status": "skipped", "reason": "replayed_in_gap_report" if data.has_commands else "no_commands"}


def fit_ladder(effect_names: Sequence[str], context: FitContext, *, side: Side = Side.BODY,
               candidates: Sequence[str] | None = None, limits: Mapping[str, float] | None = None,
               diagnosed: bool = True, cache: FitCache | None = None) -> SideLadder:
    """Every rung (nominal, then each effect added in turn) fitted and judged on one side of the model
    (:mod:`sim2real.identification.sides`); the diagnosis of the last (``diagnosed``).

    ``context``: the side's data, signals and fit settings; ``candidates``: the effects the diagnosis tries;
    ``limits``: the diagnosis's (model.yaml ``diagnosis``); ``cache``: rungs and diagnoses of earlier rounds with the
    same inputs are read back from it (:class:`sim2real.cache.FitCache`), the same to the last bit. Off the drive
    side, the last rung's residual on the fit data is returned too: what the model-free ceiling learns from and,
    with the holdout's, what the gap report judges the current model by.
    """
    cache = cache or FitCache(None)
    # Everything a rung depends on but its effects: a rung of an earlier round with the same is the same fit.
    inputs = cache.key(str(side), context.nominal, context.fit_data, context.holdout_data, context.fit_signals,
                       context.holdout_signals)
    # The diagnosis's trials keep their refinements: the rung of the candidate the user adds reads its back.
    if cache.directory is not None:
        context = dataclasses.replace(context, refinements=Refinements(cache, inputs))
    rungs, result, residual = _rungs(effect_names, context, cache, inputs)
    document = _ladder_document(rungs, context)
    # the model-free ceiling learns from the fit runs' residual (a side judged against the motion only)
    fit_residual = (context.fit_data.tau - predict(result, context.nominal, context.fit_data, context.fit_signals)
                    if side != Side.DRIVE else None)
    if not diagnosed:
        return SideLadder(round_floats(document), result, None, residual, fit_residual)
    prior = (result.consistency or {}).get("inertia_prior")
    # Every candidate is fitted with the prior weight the current rung chose: a candidate that merely let the
    # inertias move more would otherwise be credited with their fall, on joints where it does nothing. Its
    # rung chooses again on held-out blocks, which the holdout can find worse: the recommended candidate promises
    # what that rung delivers (_promised_by_its_rung).
    trials = context.with_settings({**context.settings, "inertia_regularization": prior["weight"]} if prior
                                   else context.settings)
    limits = {**DEFAULT_DIAGNOSIS, **(limits or {})}
    key = cache.key(inputs, list(effect_names), residual, result.nonlinear, dict(trials.settings), limits, candidates)
    diagnosis = cache.get_or_compute("diagnosis", key, functools.partial(
        _diagnose_side, effect_names, trials, residual, fit_residual, side=side, current=result, limits=limits,
        candidates=candidates))
    return SideLadder(round_floats(document), result, _promised_by_its_rung(diagnosis, effect_names, context, cache,
                                                                             inputs, result), residual, fit_residual)


def _promised_by_its_rung(diagnosis: Diagnosis, effect_names: Sequence[str], context: FitContext, cache: FitCache,
                          inputs: str, result: FitResult) -> Diagnosis:
    """``diagnosis`` whose recommended candidate promises what its rung delivers (:mod:`sim2real.identification.
    diagnosis.promise`): where the current rung chose the inertial prior's weight on held-out blocks, the rung of
    the added line chooses it again, as :func:`_rungs` fits it (the next round reads it back from ``cache``)."""
    effect = promised_effect(diagnosis)
    chosen = (result.consistency or {}).get("inertia_prior") or {}
    if effect is None or "grid" not in chosen:
        return diagnosis  # no weight chosen again: the trial is the rung's fit
    rung, residual, _, _ = _next_rung(trial_effects(effect_names, effect), context, cache, inputs, result)
    prior = (rung.consistency or {}).get("inertia_prior") or {}
    return kept_promise(diagnosis, residual, context.holdout_data.noise_floor, prior.get("weight"))


def _next_rung(effects: Sequence[str], context: FitContext, cache: FitCache, inputs: str, result: FitResult | None,
               ) -> tuple[FitResult, np.ndarray, str, dict[str, Any] | None]:
    """The rung of ``effects`` fitted on the one before it (``result``; None: the nominal model), read back from
    ``cache`` when fitted before (:func:`_rung`). The prior's weight is searched from the previous rung's choice
    (fitting.PRIOR_START_SETTING)."""
    previous = result.nonlinear if result is not None else None
    chosen = ((result.consistency or {}).get("inertia_prior") or {}) if result is not None else {}
    rung_context = (context.with_settings({**context.settings, PRIOR_START_SETTING: chosen["weight"]})
                    if "grid" in chosen else context)
    return cache.get_or_compute("rung", cache.key(inputs, list(effects), previous, dict(rung_context.settings)),
                                functools.partial(_rung, list(effects), rung_context, previous))


def _rungs(effect_names: Sequence[str], context: FitContext, cache: FitCache,
           inputs: str) -> tuple[list[dict[str, Any]], FitResult, np.ndarray]:
    """Each rung's ``ladder.json`` entry, and the last rung's fit and holdout residual."""
    rungs: list[dict[str, Any]] = []
    result: FitResult | None = None
    residual: np.ndarray | None = None
    for k in range(len(effect_names) + 1):
        effects = list(effect_names[:k])
        result, residual, carried, free = _next_rung(effects, context, cache, inputs, result)
        rungs.append(_rung_document(effects, result, residual, carried, free, context.holdout_data))
    assert result is not None and residual is not None
    return rungs, result, residual


def _rung_document(effects: Sequence[str], result: FitResult, residual: np.ndarray, carried: str,
                   free: Mapping[str, Any] | None, holdout_data: TorqueData) -> dict[str, Any]:
    """One rung's entry of ``ladder.json``: its effects, parameters and intervals, its holdout metrics (each joint in
    units of its own floor as its headline), and what it says of its fit."""
    x_floor = floor_units(residual, holdout_data.noise_floor)
    rung: dict[str, Any] = {
        "effects": list(effects),
        "params": result.values,
        "intervals": result.intervals,
        "metrics": {"torque_rmse": rmse(residual, holdout_data.joint_names), "fit_torque_rmse": result.fit_rmse,
                    # the rung's headline: each joint in units of its own noise floor
                    "torque_x_floor": {"overall": x_floor["overall"], "per_joint": dict(
                        zip(holdout_data.joint_names, x_floor["per_joint"], strict=True))}},
    }
    if free is not None:
        # The same rung without the physical constraints: what consistency costs (or gains) on holdout.
        rung["metrics"]["unconstrained_torque_rmse"] = free["torque_rmse"]
        # Wall time stays out of the document (outputs are byte-identical on rebuild).
        rung["consistency"] = {k: v for k, v in result.consistency.items() if k != "solve_time_s"}
    if result.notes:
        rung["notes"] = list(result.notes)
    if carried == "held":
        # refined again, the previous rung's nonlinear parameters predicted the holdout runs worse
        rung.setdefault("notes", []).append(Note(NoteKind.NONLINEAR_HELD).as_document())
    return rung


def _ladder_document(rungs: list[dict[str, Any]], context: FitContext) -> dict[str, Any]:
    """One side's ``ladder.json`` content around its rungs: the runs, the noise floor, the settings."""
    holdout = context.holdout_data
    joints = holdout.joint_names
    floor = np.asarray(holdout.noise_floor)
    return {
        "joints": joints,
        "torque_source": holdout.torque_source,
        "fit_runs": context.fit_data.run_names,
        "holdout_runs": holdout.run_names,
        "ladder": rungs,
        "noise_floor": {"torque_rmse": {"overall": float(np.sqrt(np.mean(floor**2))),
                                        "per_joint": {j: float(v) for j, v in zip(joints, floor, strict=True)}}},
        "state_domain": state_domain_status(holdout),
        "settings": {"fit": dict(context.settings)},
    }


def _diagnose_side(effect_names: Sequence[str], context: FitContext, holdout_residual: np.ndarray,
                   fit_residual: np.ndarray | None, *, side: Side, **options: Any) -> Diagnosis:
    """The diagnosis of one side (:func:`sim2real.identification.diagnosis.diagnose`) and, on a side judged against
    the motion, its model-free ceiling (:func:`sim2real.identification.diagnosis.model_free_ceiling`): when no effect
    is named, what kind of thing is left."""
    diagnosis = _still_rows_marked(diagnose(effect_names, context, holdout_residual, side=side, **options),
                                   context.settings.get(STILL_JOINTS_SETTING) or ())
    if side == Side.DRIVE:
        return diagnosis  # predicted forward from the command: the motion is not what it is a function of
    ceiling = model_free_ceiling(context.fit_data, fit_residual, context.holdout_data, holdout_residual,
                                 float(options["limits"]["noise_floor_factor"]), workers=context.workers,
                                 model_effects=effect_names,
                                 nominal_dynamics=context.nominal.dynamics if context.nominal else None)
    if diagnosis.status == Status.ADD_EFFECT and ceiling.declare is not None:
        # A candidate a held-out run judged comes first: a drift estimated on every run, holdout included, could
        # stand in for it; the next round's ceiling declares the drift if it is still there.
        ceiling = dataclasses.replace(ceiling, declare=None)
    return dataclasses.replace(diagnosis, model_free=ceiling)


def _rung(effects: Sequence[str], context: FitContext, previous: Mapping[str, np.ndarray] | None,
          ) -> tuple[FitResult, np.ndarray, str, dict[str, Any] | None]:
    """One rung of :func:`fit_ladder` (:func:`fit_on_the_previous`) and, where it is constrained, the holdout
    metrics of the same rung without the constraints: (fit, holdout residual, how its nonlinear parameters were
    carried, unconstrained metrics or None), kept whole by the fit cache."""
    result, residual, carried = fit_on_the_previous(effects, context, previous)
    free = None
    if result.unconstrained is not None and result.consistency:
        free, _ = holdout_metrics(result.unconstrained, context.nominal, context.holdout_data, context.holdout_signals)
    return result, residual, carried, free


@dataclasses.dataclass(frozen=True)
class _Sides:
    """What the runs let the sides be (:func:`sim2real.identification.sides.side_mode`), the sensor's placement and the
    lines model.yaml keeps on one side."""

    mode: str
    sensor: str
    kept_on: Mapping[str, Side]

    @property
    def body(self) -> Side:
        """The side judged against the motion: the body's, or both sides at once on runs without a sensor."""
        return Side.COMBINED if self.mode == "commands_only" else Side.BODY

    def body_effects(self, effect_names: Sequence[str]) -> list[str]:
        return (list(effect_names) if self.body == Side.COMBINED
                else sides.effects_of_side(effect_names, Side.BODY, self.sensor, self.kept_on))

    def body_candidates(self) -> list[str] | None:
        if self.mode == "separate" or self.sensor == SensorPlacement.LINK_SIDE:
            return sides.candidates_of_side(Side.BODY, self.sensor, self.kept_on)
        return None


def _sides_of(runs: Mapping[str, Sequence[PreparedRun]], model: ModelConfig, robot: str) -> _Sides:
    """The sides these runs judge; a line model.yaml keeps on a side they cannot keep it on is an input error."""
    every = [*runs["fit"], *runs["holdout"]]
    mode, sensor = sides.side_mode(every), torque_sensor_of(every)
    for name, side in model.sides.items():
        sides.check_kept_on(name, side, mode, sensor, model.path or f"configs/{robot}/model.yaml")
    return _Sides(mode, sensor, model.sides)


@dataclasses.dataclass(frozen=True)
class ModelFit:
    """What :func:`fit_model` returns: the ``ladder.json`` content (``document``), the last rung's fit of each side
    fitted, the body side's first (``results``), and the current model (the body side's last rung) on every run by
    role (``residuals``, the gap report's ``residuals.npz``)."""

    document: dict[str, Any]
    results: list[FitResult]
    residuals: ModelResiduals


def fit_model(model: ModelConfig, nominal: NominalModel, runs: Mapping[str, Sequence[PreparedRun]],
              robot: str = "{robot}", *, workers: int = 1, cache: FitCache | None = None,
              release_runs: bool = False) -> ModelFit:
    """Both sides of ``model`` (model.yaml: :mod:`sim2real.identification.sides`) on prepared runs by role (``fit``,
    ``holdout``).

    The body side's ladder and diagnosis are the document's ``ladder`` and ``diagnosis`` (on runs
    without a torque sensor: both sides together, judged on the command); with a sensor and commands the
    drive side's are under ``actuator``; ``links`` says what these runs can tell apart. Returns a
    :class:`ModelFit`. ``workers``: processes the diagnoses fit their candidates on; ``cache``: fits of earlier
    rounds (:func:`fit_ladder`); ``release_runs``: empty the lists of ``runs`` once both sides have what they need
    of them (the caller holds no other reference: a 10-minute log's runs at 1 kHz are hundreds of MB the body side
    does not need).
    """
    settings = model.as_settings()
    effect_names = list(model.effects)
    fit_settings = {**DEFAULT_SETTINGS, **settings["fit"], **_still_setting(runs["fit"])}
    split = _sides_of(runs, model, robot)
    body_effects = split.body_effects(effect_names)
    body_data = {role: stack_runs([RunSamples.of(run, noise_floor_of(run)) for run in runs[role]],
                                  nominal.joint_names, fit_settings["fit_rate_hz"]) for role in ("fit", "holdout")}
    # The drive side does not depend on the body side: on two or more threads it is fitted beside it.
    beside = (Forked(_drive_side, effect_names, nominal, runs, settings, split, cache, fork=workers > 1)
              if split.mode == "separate" else None)
    if release_runs:
        if beside is not None and beside.process is None:
            beside = _Done(beside.result())  # on one process the drive side first, while the runs are here
        for listed in runs.values():
            if isinstance(listed, list):
                listed.clear()
    body = fit_ladder(body_effects, FitContext.on_nominal(nominal, body_data["fit"], body_data["holdout"],
                                                          fit_settings, workers=workers),
                      side=split.body, candidates=split.body_candidates(), limits=settings["diagnosis"], cache=cache)
    drive = beside.result() if beside is not None else None
    return ModelFit(_model_document(robot, body, drive, split, effect_names),
                    [body.result] + ([drive.result] if drive else []),
                    _current_residuals(body, body_data, split.body, body_effects))


def _current_residuals(body: SideLadder, data: Mapping[str, TorqueData], side: Side,
                       effects: Sequence[str]) -> ModelResiduals:
    """The body side's last rung (``effects``) on the fit and the holdout data, as residuals.npz holds it."""
    assert body.fit_residual is not None  # the body side's ladder returns it
    holdout = data["holdout"]
    return ModelResiduals(side=side, effects=tuple(effects), joints=tuple(holdout.joint_names),
                          torque_source=holdout.torque_source, torque_sensor=holdout.torque_sensor,
                          roles={"fit": _role_residuals(data["fit"], body.fit_residual),
                                 "holdout": _role_residuals(holdout, body.holdout_residual)})


def _role_residuals(data: TorqueData, residual: np.ndarray) -> RoleResiduals:
    """A role's stacked data and the last rung's residual on it."""
    runs = tuple((name, int(seg.start), int(seg.stop)) for name, seg in zip(data.run_names, data.segments, strict=True))
    return RoleResiduals(runs, np.asarray(data.noise_floor, dtype=float), data.time, data.q, data.qd, data.qdd,
                         data.tau, np.asarray(residual))


def _model_document(robot: str, body: SideLadder, drive: SideLadder | None, split: _Sides,
                    effect_names: Sequence[str]) -> dict[str, Any]:
    """ladder.json: the body side's ladder and diagnosis, the drive side's under ``actuator``, and what the runs can
    tell apart under ``links`` (the sides' diagnoses with what each takes from the other)."""
    body_diagnosis, drive_diagnosis = across_sides(body.diagnosis, drive.diagnosis if drive else None, body.result,
                                                   drive.result if drive else None, split.sensor)
    document = {"robot": robot, **body.document}
    if body_diagnosis is not None:
        document["diagnosis"] = round_floats(body_diagnosis.as_document())
    confounded = [list(pair) for d in (body_diagnosis, drive_diagnosis) if d is not None for pair in d.confounded]
    if drive is not None:
        document["actuator"] = {key: drive.document[key] for key in ("ladder", "noise_floor")}
        if drive_diagnosis is not None:
            document["actuator"]["diagnosis"] = round_floats(drive_diagnosis.as_document())
    document["links"] = round_floats(sides.separability(split.mode, effect_names, confounded, split.sensor))
    if split.kept_on:
        # the user's choice, said where the sides are: neither side tries the line on the other
        document["links"]["kept_on"] = {name: str(side) for name, side in split.kept_on.items()}
    contradicted = ([name for name in split.body_effects(effect_names) if get_effect(name).drive]
                    if split.body == Side.BODY else [])
    if split.sensor == SensorPlacement.LINK_SIDE and contradicted:
        # The metadata put the drive before the sensor; the model the user follows fits it after it.
        document["links"]["drive_after_sensor"] = contradicted
    return document


def _still_rows_marked(diagnosis: Diagnosis, still: Sequence[str]) -> Diagnosis:
    """``diagnosis`` with the per-joint rows of the joints the fit runs barely move marked ``judged: false``: their
    drives were held at the nominal model's (:func:`_still_setting`), and the report names them as not judged."""
    if not still:
        return diagnosis
    return dataclasses.replace(diagnosis, per_joint={
        joint: dataclasses.replace(row, judged=False) if joint in still else row
        for joint, row in diagnosis.per_joint.items()})


def _still_setting(fit_runs: Sequence[PreparedRun]) -> dict[str, list[str]]:
    """The fit setting that holds the drive parameters of the joints that barely move in the fit runs
    (:func:`sim2real.measurements.motion.still_joints`) at the nominal model's; nothing when every joint moves."""
    still = still_joints(fit_runs)
    return {STILL_JOINTS_SETTING: list(still)} if still else {}


class _Done:
    """A result already computed, asked for as a :class:`sim2real.forked.Forked` one is."""

    def __init__(self, value: Any) -> None:
        self.value = value

    def result(self) -> Any:
        return self.value


def _drive_side(effect_names: Sequence[str], nominal: NominalModel, runs: Mapping[str, Sequence[PreparedRun]],
                settings: Mapping[str, Any], split: _Sides, cache: FitCache | None = None) -> SideLadder:
    """The drive side's ladder and diagnosis (:func:`fit_ladder` on the command and the measured torque), on one
    process (the body side's run beside it)."""
    joints = nominal.joint_names
    data = {role: sides.drive_data(runs[role], joints) for role in ("fit", "holdout")}
    signals = {role: sides.drive_signals(*data[role], nominal) for role in data}
    context = FitContext(nominal, data["fit"][0], data["holdout"][0], signals["fit"], signals["holdout"],
                         {**DEFAULT_SETTINGS, **settings.get("fit", {}), **sides.DRIVE_FIT_SETTINGS,
                          **_still_setting(runs["fit"])})
    return fit_ladder(sides.effects_of_side(effect_names, Side.DRIVE, split.sensor, split.kept_on), context,
                      side=Side.DRIVE, candidates=sides.candidates_of_side(Side.DRIVE, split.sensor, split.kept_on),
                      limits=settings.get("diagnosis"), cache=cache)


@dataclasses.dataclass(frozen=True)
class SysidFiles:
    """The sysid rule's files: the URDF, robot.yaml, model.yaml and the runs (a measurement list, or the runs prepared
    from it: ``prepare_runs``, ``.npz``; relative paths of a list against ``root``) it reads; ladder.json,
    params.yaml, calibration.yaml and the last rung's residuals (None: not written; each file's format:
    :mod:`sim2real.identification.formats`) it writes."""

    urdf: str | Path
    robot_config: str | Path
    model_config: str | Path
    measurements: str | Path
    ladder: str | Path
    params: str | Path
    calibration: str | Path
    root: str | Path = "."
    residuals: str | Path | None = None


@one_blas_thread
def run_sysid(robot: str, files: SysidFiles, threads: int = 1, cache_dir: str | Path | None = None,
              robot_settings: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Files in, files out (:class:`SysidFiles`): the ladder (with diagnosis), the fitted parameters and the
    calibration; the last rung's residuals for the gap report. ``robot_settings``: robot.yaml's content, when already
    read (the DAG passes it as params); ``threads``: the diagnosis fits its candidates on that many processes (BLAS on
    one thread each); ``cache_dir``: where the rungs and diagnoses are kept for the next round (:class:`FitCache`;
    None: not kept).
    """
    from sim2real.identification.effects import calibration_from_params
    from sim2real.files import read_yaml, write_yaml
    from sim2real.measurements import FIT_ARRAYS, runs_for_model

    model_config = load_model_config(files.model_config)
    robot_config = dict(robot_settings) if robot_settings is not None else (read_yaml(files.robot_config) or {})
    runs = runs_for_model(files.measurements, files.urdf, files.root, FIT_ARRAYS)
    joints = runs[0].joint_names
    cache = FitCache(cache_dir)
    nominal = load_nominal(files.urdf, joints, robot_config.get("armature"), robot_config.get("flange"), cache=cache,
                           inertia_bands=InertiaBands.of_robot(robot_config))
    by_role: dict[str, list[PreparedRun]] = {"fit": list(runs.fit), "holdout": list(runs.holdout)}
    del runs  # by_role holds the runs alone: fit_model empties it once the sides have what they need
    for role in ("fit", "holdout"):
        if not by_role[role]:
            raise InputError(files.measurements, "runs", f"no run with role '{role}'",
                             "mark at least one run role: fit and one role: holdout")
    fitted = fit_model(model_config, nominal, by_role, robot, workers=threads, cache=cache, release_runs=True)
    params = params_document(fitted.results, nominal, fitted.document["torque_source"], robot)
    write_ladder(files.ladder, fitted.document)
    write_params(files.params, params)
    write_yaml(files.calibration, round_floats(calibration_from_params(params)))
    if files.residuals is not None:
        write_model_residuals(files.residuals, fitted.residuals)
    cache.prune()
    return fitted.document
