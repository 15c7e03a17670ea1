"""System identification: fit the model ladder of configs/{robot}/model.yaml to measured runs.

:func:`~sim2real.identification.side_ladder.fit_ladder` composes the fitting core
(:mod:`sim2real.identification.fitting`) and the diagnosis (:mod:`sim2real.identification.diagnosis`) on one side:
every rung (nominal, then each effect added in turn, refining only the new effect's nonlinear parameters) fitted on
the ``role: fit`` runs and judged on the ``role: holdout`` runs, then the diagnosis of the last rung (this module
re-exports it). :func:`fit_model` runs it on each side
of the model (:mod:`sim2real.identification.sides`: the drive and the body, judged apart when the runs log
both the measured and the commanded torque) and adds what each side's diagnosis takes from the other
(:mod:`sim2real.identification.diagnosis.across`). It returns the ``ladder.json`` content, data without words
(:mod:`sim2real.report.verdicts` words it); :func:`~sim2real.identification.documents.params_document` and
:func:`sim2real.identification.effects.calibration_from_params` give params.yaml and calibration.yaml;
:func:`run_sysid` is the files-in, files-out entry point of the rule.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.blas import one_blas_thread
from sim2real.cache import FitCache
from sim2real.errors import InputError
from sim2real.forked import Forked
from sim2real.identification import sides
from sim2real.identification.diagnosis.across import across_sides
from sim2real.identification.documents import params_document, round_floats
from sim2real.identification.effects import get_effect
from sim2real.identification.formats import (
    ModelResiduals, RoleResiduals, write_ladder, write_model_residuals, write_params,
)
from sim2real.identification.fitting import (
    DEFAULT_SETTINGS, STILL_JOINTS_SETTING, FitContext, FitResult, NominalModel, RunSamples, TorqueData, load_nominal,
    stack_runs,
)
from sim2real.identification.inertial.bands import InertiaBands
from sim2real.identification.model_config import ModelConfig, load_model_config
from sim2real.identification.records import SensorPlacement, Side
from sim2real.identification.side_ladder import (  # noqa: F401  (re-exported: one side's ladder, the rule's too)
    SideLadder, fit_ladder, state_domain_status,
)
from sim2real.measurements import PreparedRun, noise_floor_of, torque_sensor_of
from sim2real.measurements.motion import still_joints


@dataclasses.dataclass(frozen=True)
class _Sides:
    """What the runs let the sides be (:func:`sim2real.identification.sides.side_mode`), the sensor's placement and the
    lines model.yaml keeps on one side."""

    mode: str
    sensor: SensorPlacement
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

    Parameters
    ----------
    model : ModelConfig
        model.yaml's content (:func:`~sim2real.identification.model_config.parse_model_config`): effects, fit settings.
    nominal : NominalModel
        The URDF's model on the runs' joints (:func:`~sim2real.identification.fitting.load_nominal`).
    runs : mapping of str to sequence of PreparedRun
        The prepared runs by role, ``fit`` and ``holdout``.
    robot : str
        The robot's name in the document.
    workers, cache, release_runs : optional
        See above.

    Returns
    -------
    ModelFit
        ``document`` (ladder.json's content), ``results`` (each side's last rung), ``residuals`` (residuals.npz's).

    Raises
    ------
    InputError
        An effect model.yaml keeps on a side the runs' torque sensor cannot fit it on, or on a joint they do not hold.

    Examples
    --------
    A one-effect ladder on two three-second runs, a coarse grid and few replicates (seconds):

    >>> from sim2real.identification.fitting import load_nominal
    >>> from sim2real.identification.model_config import parse_model_config
    >>> from sim2real.measurements import prepare_for_model
    >>> runs = prepare_for_model(example_dir / "measurements.yaml", urdf, root=example_dir)
    >>> model = parse_model_config({"effects": ["viscous_friction"], "fit": {
    ...     "fit_rate_hz": 50.0, "bootstrap_replicates": 5, "refine_max_samples": 300}}, "model.yaml")
    >>> fitted = fit_model(model, load_nominal(urdf, runs[0].joint_names),
    ...                    {"fit": list(runs.fit), "holdout": list(runs.holdout)}, robot="panda")
    >>> [rung["effects"] for rung in fitted.document["ladder"]], fitted.document["diagnosis"]["status"]
    ([[], ['viscous_friction']], 'at_noise_floor')
    """
    model.check_joints(nominal.joint_names)
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

    Parameters
    ----------
    robot : str
    files : SysidFiles
    threads : int, default 1
    cache_dir : str or Path, optional
    robot_settings : mapping, optional

    Returns
    -------
    dict
        ladder.json's content (:attr:`ModelFit.document`), also written to ``files.ladder``.

    Raises
    ------
    InputError
        A file is bad (naming it, the key or column and the fix), or no run has role ``fit`` or ``holdout``.

    Examples
    --------
    The fit of :func:`fit_model`'s example, from files to files; it takes its seconds, so it is not run here:

    >>> _ = (example_dir / "model.yaml").write_text("effects: [viscous_friction]")
    >>> files = SysidFiles(urdf, example_dir / "robot.yaml", example_dir / "model.yaml",
    ...                    example_dir / "measurements.yaml", ladder=example_dir / "ladder.json",
    ...                    params=example_dir / "params.yaml", calibration=example_dir / "calibration.yaml",
    ...                    root=example_dir)
    >>> ladder = run_sysid("panda", files, robot_settings={})  # doctest: +SKIP
    >>> ladder["diagnosis"]["status"]  # doctest: +SKIP
    'at_noise_floor'

    A measurement list without a holdout run is refused before any fit (this runs):

    >>> _ = (example_dir / "fit_only.yaml").write_text("runs: [{name: fit, path: fit.csv, role: fit}]")
    >>> run_sysid("panda", dataclasses.replace(files, measurements=example_dir / "fit_only.yaml"), robot_settings={})
    Traceback (most recent call last):
    ...
    sim2real.errors.InputError: ...fit_only.yaml: runs: no run with role 'holdout'. Fix: ...
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
