"""System identification: fit the model ladder of configs/{robot}/model.yaml to measured runs.

:func:`fit_ladder` composes the fitting core (:mod:`sim2real.identification.fitting`) and the diagnosis
(:mod:`sim2real.identification.diagnosis`): every rung (nominal, then each effect added in turn, refining only the
new effect's nonlinear parameters) fitted on the ``role: fit`` runs and judged on the
``role: holdout`` runs, then the diagnosis of the last rung. :func:`fit_model` runs it on each link
of the model (:mod:`sim2real.identification.links`: the actuator and the body, judged apart when the runs log
both the measured and the commanded torque). It returns the ``ladder.json`` content;
:func:`~sim2real.identification.documents.params_document` and :func:`sim2real.identification.effects.calibration_from_params`
give params.yaml and calibration.yaml; :func:`run_sysid` is the files-in, files-out entry point of the rule.
The fitting core's names are re-exported here (``sysid.fit``, ``sysid.TorqueData``, ...).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.identification.inertial.bands import InertiaBands
from sim2real.identification import links
from sim2real.identification.diagnosis import DEFAULT_DIAGNOSIS, model_free_ceiling
from sim2real.identification.diagnosis import diagnose as run_diagnosis
from sim2real.identification.diagnosis.candidates import HARM_TOLERANCE
from sim2real.identification.diagnosis.caveats import NESTED_IN
from sim2real.identification.documents import (  # noqa: F401  (re-exported: the rule's documents)
    load_model_config, merge_link_values, params_document, round_floats, write_model_residuals,
)
from sim2real.identification.effects import Signals, get_effect
from sim2real.errors import InputError
from sim2real.forked import Forked
from sim2real.identification.fitting import (  # noqa: F401  (re-exported: the public names of the fit)
    DEFAULT_SETTINGS, PRIOR_START_SETTING, FitResult, NominalModel, Refinements, TorqueData, fit, fit_on_the_previous, floor_units, holdout_metrics,
    joint_weights,
    kept_segments, load_nominal, make_signals, predict, resolve_armature, RunSamples, stack_runs,
)
from sim2real.blas import one_blas_thread
from sim2real.cache import FitCache
from sim2real.measurements import PreparedRun, noise_floor_of, torque_sensor_of
from sim2real.stats import floor_multiple, rmse


def state_domain_status(data: TorqueData) -> dict[str, str]:
    """The state-domain refinement replays commands in MuJoCo; say plainly when and why it is skipped."""
    if not data.has_commands:
        return {
            "status": "skipped",
            "reason": "the runs have no commanded torque (tau_cmd), so there is nothing to replay; "
            "the ladder and the diagnosis use the torque domain only",
        }
    return {
        "status": "skipped",
        "reason": "the ladder is fitted and judged in the torque domain; the gap report replays each rung "
        "with its fitted effects (gap.json ladder[].metrics.position_rmse)",
    }


def fit_ladder(
    effect_names: Sequence[str],
    nominal: NominalModel,
    fit_data: TorqueData,
    holdout_data: TorqueData,
    settings: Mapping[str, Any] | None = None,
    robot: str = "{robot}",
    diagnose: bool = True,
    *,
    fit_signals: Signals | None = None,
    holdout_signals: Signals | None = None,
    link: str = "body",
    candidates: Sequence[str] | None = None,
    workers: int = 1,
    cache: FitCache | None = None,
    residuals_out: dict[str, np.ndarray] | None = None,
) -> tuple[dict[str, Any], FitResult]:
    """Every rung (nominal, then each effect added in turn) fitted and judged; diagnosis of the last.

    Returns the ``ladder.json`` content (keys ``ladder``, ``diagnosis``, ``noise_floor``,
    ``state_domain``, ...) and the last rung's fit. One link of the model (:mod:`sim2real.identification.links`):
    ``link`` names it in the diagnosis, ``candidates`` are the effects the diagnosis tries, and the
    signals (default: the nominal model's on the data) say what the judged torque is predicted from;
    ``workers``: processes the rungs' two ways (:func:`sim2real.identification.fitting.fit_on_the_previous`) and the
    diagnosis's candidates are fitted on; ``cache``: rungs and diagnoses of earlier rounds with the same
    inputs are read back from it (:class:`sim2real.cache.FitCache`), the same to the last bit;
    ``residuals_out``: filled with the last rung's residual on the fit and the holdout data (keys ``fit``,
    ``holdout``: judged minus predicted torque), what the gap report judges the current model by.
    """
    settings = dict(settings or {})
    fit_settings = {**DEFAULT_SETTINGS, **settings.get("fit", {})}
    fit_signals = fit_signals or make_signals(nominal, fit_data)
    holdout_signals = holdout_signals or make_signals(nominal, holdout_data)
    cache = cache or FitCache(None)
    # Everything a rung depends on but its effects: a rung of an earlier round with the same is the same fit.
    inputs = cache.key(link, nominal, fit_data, holdout_data, fit_signals, holdout_signals)
    # The diagnosis's trials keep their refinements: the rung of the candidate the user adds reads its back.
    refinements = Refinements(cache, inputs) if cache.directory is not None else None
    rungs = []
    result = None
    residual = None
    for k in range(len(effect_names) + 1):
        effects = list(effect_names[:k])
        previous = result.nonlinear if result is not None else None
        # The prior's weight is searched from the previous rung's choice (fitting.PRIOR_START_SETTING).
        chosen = ((result.consistency or {}).get("inertia_prior") or {}) if result is not None else {}
        rung_settings = ({**fit_settings, PRIOR_START_SETTING: chosen["weight"]} if "grid" in chosen
                         else fit_settings)
        result, residual, carried, free = cache.get_or_compute(
            "rung", cache.key(inputs, effects, previous, rung_settings),
            functools.partial(_rung, effects, nominal, fit_data, holdout_data, previous, rung_settings,
                              fit_signals=fit_signals, holdout_signals=holdout_signals, workers=workers,
                              refinements=refinements))
        metrics = {"torque_rmse": rmse(residual, holdout_data.joint_names)}
        x_floor = floor_units(residual, holdout_data.noise_floor)
        rung: dict[str, Any] = {
            "effects": effects,
            "params": result.values,
            "intervals": result.intervals,
            "metrics": {**metrics, "fit_torque_rmse": result.fit_rmse,
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
            rung["notes"] = result.notes
        if carried == "held":
            rung.setdefault("notes", []).append(
                "the previous rung's nonlinear parameters (friction slopes and offsets, delay) are held: refined "
                "again, they predicted the holdout runs worse")
        rungs.append(rung)
    assert result is not None and residual is not None
    joints = holdout_data.joint_names
    floor = np.asarray(holdout_data.noise_floor)
    document: dict[str, Any] = {
        "robot": robot,
        "joints": joints,
        "torque_source": holdout_data.torque_source,
        "fit_runs": fit_data.run_names,
        "holdout_runs": holdout_data.run_names,
        "ladder": rungs,
        "noise_floor": {
            "torque_rmse": {
                "overall": float(np.sqrt(np.mean(floor**2))),
                "per_joint": {j: float(v) for j, v in zip(joints, floor, strict=True)},
            }
        },
        "state_domain": state_domain_status(holdout_data),
        "settings": {"fit": fit_settings},
    }
    # the model-free ceiling learns from the fit runs' residual (a link judged against the motion only)
    fit_residual = fit_data.tau - predict(result, nominal, fit_data, fit_signals) if (
        (diagnose and link != "actuator") or residuals_out is not None) else None
    if residuals_out is not None:
        residuals_out.update({"fit": fit_residual, "holdout": residual})
    if diagnose:
        prior = (result.consistency or {}).get("inertia_prior")
        # Every candidate is fitted with the prior weight the current rung chose: a candidate that merely let the
        # inertias move more would otherwise be credited with their fall, on joints where it does nothing. Its
        # rung chooses again on held-out blocks, which can only help the holdout it was promised.
        diagnosis_fit = {**fit_settings, "inertia_regularization": prior["weight"]} if prior else fit_settings
        diagnosis_settings = {"fit": diagnosis_fit, "diagnosis": settings.get("diagnosis", {})}
        key = cache.key(inputs, list(effect_names), residual, result.nonlinear, diagnosis_settings, robot, candidates)
        document["diagnosis"] = cache.get_or_compute("diagnosis", key, functools.partial(
            _diagnose_link, effect_names, nominal, fit_data, holdout_data, residual, fit_residual, diagnosis_settings,
            fit_signals=fit_signals, holdout_signals=holdout_signals, robot=robot, nonlinear_fixed=result.nonlinear,
            candidates=candidates, link=link, workers=workers, current=result, refinements=refinements,
        ))
    return round_floats(document), result


def _diagnose_link(effect_names: Sequence[str], nominal: NominalModel, fit_data: TorqueData,
                   holdout_data: TorqueData, holdout_residual: np.ndarray, fit_residual: np.ndarray,
                   settings: Mapping[str, Any], *, link: str, **options: Any) -> dict[str, Any]:
    """The diagnosis of one link (:func:`sim2real.identification.diagnosis.diagnose`) and, on a link judged against the motion,
    its model-free ceiling (:func:`sim2real.identification.diagnosis.model_free_ceiling`): when no effect is named, the
    verdict says what kind of thing is left."""
    diagnosis = run_diagnosis(effect_names, nominal, fit_data, holdout_data, holdout_residual, settings, link=link,
                              **options)
    if link == "actuator":
        return diagnosis  # predicted forward from the command: the motion is not what it is a function of
    limits = {**DEFAULT_DIAGNOSIS, **settings.get("diagnosis", {})}
    ceiling = model_free_ceiling(fit_data, fit_residual, holdout_data, holdout_residual,
                                 float(limits["noise_floor_factor"]), workers=options.get("workers", 1),
                                 model_effects=effect_names, robot=options.get("robot", "{robot}"),
                                 gravity=nominal.dynamics.gravity)
    diagnosis["model_free"] = ceiling
    if diagnosis["status"] == "unexplained" and ceiling["text"]:
        diagnosis["verdict"] = diagnosis["verdict"].replace(" Look at the worst windows in the gap report.", "")
        diagnosis["verdict"] += " " + ceiling["text"] + " The gap report's worst windows and residual figures show it."
    return diagnosis


def _rung(
    effects: Sequence[str], nominal: NominalModel, fit_data: TorqueData, holdout_data: TorqueData,
    previous: Mapping[str, np.ndarray] | None, settings: Mapping[str, Any], **options: Any,
) -> tuple[FitResult, np.ndarray, str, dict[str, Any] | None]:
    """One rung of :func:`fit_ladder` (:func:`fit_on_the_previous`) and, where it is constrained, the holdout
    metrics of the same rung without the constraints: (fit, holdout residual, how its nonlinear parameters were
    carried, unconstrained metrics or None), kept whole by the fit cache."""
    result, residual, carried = fit_on_the_previous(effects, nominal, fit_data, holdout_data, previous, settings,
                                                    **options)
    free = None
    if result.unconstrained is not None and result.consistency:
        free, _ = holdout_metrics(result.unconstrained, nominal, holdout_data, options.get("holdout_signals"))
    return result, residual, carried, free


def fit_model(
    effect_names: Sequence[str],
    nominal: NominalModel,
    runs: Mapping[str, Sequence[PreparedRun]],
    settings: Mapping[str, Any] | None = None,
    robot: str = "{robot}",
    workers: int = 1,
    cache: FitCache | None = None,
    release_runs: bool = False,
    current_out: dict[str, Any] | None = None,
) -> tuple[dict[str, Any], list[FitResult]]:
    """Both links of the model (:mod:`sim2real.identification.links`) on prepared runs by role (``fit``, ``holdout``).

    The body link's ladder and diagnosis are the document's ``ladder`` and ``diagnosis`` (on runs
    without a torque sensor: both links together, judged on the command); with a sensor and commands the
    actuator link's are under ``actuator``; ``links`` says what these runs can tell apart. Returns the
    ``ladder.json`` content and the last rung's fit of each link fitted. ``workers``: processes the
    diagnoses fit their candidates on; ``cache``: fits of earlier rounds (:func:`fit_ladder`);
    ``release_runs``: empty the lists of ``runs`` once both links have what they need of them (the caller
    holds no other reference: a 10-minute log's runs at 1 kHz are hundreds of MB the body link does not need);
    ``current_out``: filled with the body link's data and last rung's residual by role (:func:`model_residuals`).
    """
    settings = dict(settings or {})
    fit_settings = {**DEFAULT_SETTINGS, **settings.get("fit", {})}
    joints = nominal.joint_names
    mode = links.link_mode([*runs["fit"], *runs["holdout"]])
    sensor = torque_sensor_of([*runs["fit"], *runs["holdout"]])
    kept_on = dict(settings.get("links") or {})
    for name, link in kept_on.items():
        problem = links.kept_on_problem(name, link, mode, sensor)
        if problem:
            raise InputError(f"configs/{robot}/model.yaml", f"effects: '- {name}: {link}'", problem, f"write '- {name}'")
    body_link = "combined" if mode == "commands_only" else "body"
    body_effects = (list(effect_names) if mode == "commands_only"
                    else links.effects_of_link(effect_names, "body", sensor, kept_on))
    body_data = {
        role: stack_runs([RunSamples.of(run, noise_floor_of(run)) for run in runs[role]], joints,
                         fit_settings["fit_rate_hz"])
        for role in ("fit", "holdout")
    }
    # The actuator link does not depend on the body link: on two or more threads it is fitted beside it.
    beside = (Forked(_actuator_link, effect_names, nominal, runs, settings, robot, sensor, 1, cache, fork=workers > 1)
              if mode == "separate" else None)
    if release_runs:
        if beside is not None and beside.process is None:
            beside = _Done(beside.result())  # on one process the actuator link first, while the runs are here
        for listed in runs.values():
            if isinstance(listed, list):
                listed.clear()
    residuals: dict[str, np.ndarray] = {}
    document, result = fit_ladder(
        body_effects, nominal, body_data["fit"], body_data["holdout"], settings, robot, link=body_link,
        candidates=links.candidates_of_link("body", sensor, kept_on) if mode == "separate" or sensor == "link" else None,
        workers=workers, cache=cache, residuals_out=residuals,
    )
    if current_out is not None:
        current_out.update({"link": body_link, "effects": list(body_effects),
                            **{role: (body_data[role], residuals[role]) for role in ("fit", "holdout")}})
    results = [result]
    if body_link == "body":
        _note_drive(document.get("diagnosis"), "body", sensor)
    confounded = list(document.get("diagnosis", {}).get("confounded", []))
    if beside is not None:
        section, link_result = beside.result()
        document["actuator"] = {
            "judged": "measured torque (tau) predicted from the commanded torque (tau_cmd); no dynamics"
            if sensor == "motor" else "link-side measured torque (tau) predicted from the commanded torque "
            "(tau_cmd) less the drive's rotor inertia, damping and friction on the measured motion",
            **{key: section[key] for key in ("ladder", "diagnosis", "noise_floor") if key in section},
        }
        _note_drive(document["actuator"].get("diagnosis"), "actuator", sensor)
        _note_sensor_lag(document["actuator"].get("diagnosis"), link_result, result, document.get("diagnosis"))
        for named, other, other_link in ((document.get("diagnosis"), document["actuator"].get("diagnosis"), "actuator"),
                                         (document["actuator"].get("diagnosis"), document.get("diagnosis"), body_link)):
            _note_other_link(named, other, other_link, sensor)
        _note_held_on_other_link(document.get("diagnosis"), link_result.effects, "actuator", sensor)
        _note_held_on_other_link(document["actuator"].get("diagnosis"), result.effects, body_link, sensor)
        confounded += section.get("diagnosis", {}).get("confounded", [])
        results.append(link_result)
    document["links"] = round_floats(links.separability(mode, effect_names, confounded, sensor))
    if kept_on:
        # the user's choice, said where the links are: neither link tries the line on the other
        document["links"]["kept_on"] = kept_on
    contradicted = [name for name in body_effects if get_effect(name).drive] if body_link == "body" else []
    if sensor == "link" and contradicted:
        # The metadata put the drive before the sensor; the model the user follows fits it after: say what that means.
        document["links"]["metadata_note"] = (
            f"The runs say the torque sensor is link-side (torque_sensor: link), so the body link was expected to be "
            f"the rigid body alone; yet the model fits {', '.join(contradicted)} on it, against the motion, after "
            "the sensor. The data say part of the joint's friction or inertia acts after the sensor (output "
            "bearings, seals) or that the sensor sits before part of the drive; the calibrated model adds it to "
            "the joint's value.")
    return document, results


class _Done:
    """A result already computed, asked for as a :class:`sim2real.forked.Forked` one is."""

    def __init__(self, value: Any) -> None:
        self.value = value

    def result(self) -> Any:
        return self.value


def _actuator_link(
    effect_names: Sequence[str], nominal: NominalModel, runs: Mapping[str, Sequence[PreparedRun]],
    settings: Mapping[str, Any], robot: str, sensor: str, workers: int, cache: FitCache | None = None,
) -> tuple[dict[str, Any], FitResult]:
    """The actuator link's ladder and diagnosis (:func:`fit_ladder` on the command and the measured torque)."""
    joints = nominal.joint_names
    fit_settings = {**DEFAULT_SETTINGS, **settings.get("fit", {})}
    link_data = {role: links.actuator_data(runs[role], joints) for role in ("fit", "holdout")}
    signals = {role: links.actuator_signals(*link_data[role], nominal) for role in link_data}
    link_settings = {**settings, "fit": {**fit_settings, **links.ACTUATOR_FIT_SETTINGS}}
    kept_on = dict(settings.get("links") or {})
    return fit_ladder(
        links.effects_of_link(effect_names, "actuator", sensor, kept_on), nominal, link_data["fit"][0],
        link_data["holdout"][0], link_settings, robot, fit_signals=signals["fit"],
        holdout_signals=signals["holdout"], link="actuator",
        candidates=links.candidates_of_link("actuator", sensor, kept_on), workers=workers, cache=cache,
    )


AGREEING_LAGS = (0.5, 1.5)  # the body link's lag over the actuator link's: the same lag, seen from both links


def _note_sensor_lag(diagnosis: dict[str, Any] | None, actuator: FitResult, body: FitResult,
                     body_diagnosis: Mapping[str, Any] | None = None) -> None:
    """The actuator link judges the sensor's reading against the command, so a lag of the sensor shows there as an
    actuation lag (a delay, a first-order lag); only the body link (the reading against the motion) tells the two
    apart. Where the actuator link holds or names an actuation lag, its verdict says what the body link finds: the
    sensor lag of its model (sensor_delay, sensor_lag), or its trial of one (``body_diagnosis``)."""
    if not diagnosis:
        return

    def actuation_lag(name: str) -> bool:
        return get_effect(name).time_shift and get_effect(name).link == "actuator"

    def sensor_lag(name: str) -> bool:
        return get_effect(name).time_shift and get_effect(name).sensor_side

    def lag_value(name: str, values: Mapping[str, Any]) -> float:
        return float(values.get(get_effect(name).nonlinear[0].name) or 0.0)

    top = diagnosis["candidates"][0] if diagnosis.get("candidates") else None
    named = diagnosis.get("status") == "add_effect" and top is not None and actuation_lag(top["effect"])
    held = [name for name in actuator.effects if actuation_lag(name)]
    sensor = [name for name in body.effects if sensor_lag(name)]
    lag = sum(lag_value(name, body.values.get(name) or {}) for name in sensor)
    if lag > 0 and (held or named or diagnosis.get("status") != "at_noise_floor"):
        note = (f" The body link finds the torque sensor's reading {lag * 1e3:.2g} ms behind the motion "
                f"({', '.join(sensor)}): that much of the lag this link finds between the command and the reading is "
                "the sensor's, which this link, judging the reading against the command, counts as actuation lag; the "
                "calibrated actuators hold only what lies beyond it (params.yaml, by_link)."
                + (" A sensor's lag is a filter rather than a pure delay: at the command's rate its noise shows the "
                   "difference, which no effect of this link removes." if diagnosis.get("status") == "unexplained" else ""))
    elif (held or named) and not sensor:
        trials = [c for c in (body_diagnosis or {}).get("candidates", []) if sensor_lag(c["effect"])]
        # Of its shapes, the one the body link's ranking would name: the delay where the filter does no better than the
        # data can tell (sim2real.identification.diagnosis.candidates._rank).
        reach = min((c["evidence"]["x_floor_after"] for c in trials), default=0.0)
        trial = min((c for c in trials if c["evidence"]["x_floor_after"]
                     <= reach + float(DEFAULT_DIAGNOSIS["parsimony_noise_fraction"])),
                    key=lambda c: (get_effect(c["effect"]).lowpass, c["evidence"]["x_floor_after"]), default=None)
        own = (sum(lag_value(name, actuator.values.get(name) or {}) for name in held) if held
               else lag_value(top["effect"], top["evidence"]["fitted"]))
        found = lag_value(trial["effect"], trial["evidence"]["fitted"]) if trial else 0.0
        # The body link's lag must be this one, and show above the body's noise, to say whose it is.
        if not own or not AGREEING_LAGS[0] <= found / float(own) <= AGREEING_LAGS[1] \
                or trial["explained_beyond_noise"] < DEFAULT_DIAGNOSIS["joint_min_explained"]:
            return
        note = (" This link cannot tell an actuation lag from a lag of the torque sensor (the reading lags the command "
                f"either way); the body link can, and its trial of {trial['effect']} finds the reading {found * 1e3:.2g} ms "
                f"behind the motion (this link: {float(own) * 1e3:.2g} ms), removing {trial['explained_beyond_noise']:.0%} "
                f"of what lies above its floor: the lag is the sensor's. Add '- {trial['effect']}' under 'effects:' and "
                "the calibrated actuators hold only what lies beyond it.")
    else:
        return
    diagnosis["verdict"] += note
    diagnosis["lag_note"] = note.strip()


def _note_other_link(diagnosis: dict[str, Any] | None, other: Mapping[str, Any] | None, other_link: str,
                     sensor: str) -> None:
    """A line one link names sits on the other link too (a drive's friction behind a link-side sensor): where the
    other link's own trial of it leaves a joint worse than now, above the floor factor or by more than the harm
    tolerance, the verdict says so; the user weighs the two links (``other_link_note``). Only where the other link asks
    for nothing itself: then its next rung is its model with this line, which its trial fitted."""
    if not diagnosis or not other or diagnosis.get("status") != "add_effect" \
            or other.get("status") in ("add_effect", "not_told_apart"):
        return
    effect = diagnosis["candidates"][0]["effect"]
    trial = next((c for c in other.get("candidates", []) if c["effect"] == effect), None)
    if trial is None or not links.effects_of_link([effect], other_link, sensor):
        return
    factor = float(DEFAULT_DIAGNOSIS["noise_floor_factor"])
    now = {j: row["x_floor"] for j, row in (other.get("per_joint") or {}).items()}
    after = trial["evidence"].get("per_joint_x_floor_after") or {}
    worse = [j for j, a in now.items() if j in after and after[j] > a
             and (after[j] > factor or after[j] > a + HARM_TOLERANCE)]
    if not worse:
        return
    explains = (f"explains {trial['explained']:.0%} of its residual" if trial["explained"] > 0
                else "explains nothing")
    link = "body" if other_link == "actuator" else "actuator"
    note = (f" The line sits on the {other_link} link too, where its trial {explains} and leaves "
            + ", ".join(f"{j} at {floor_multiple(after[j])} its floor ({floor_multiple(now[j])} now)" for j in worse)
            + f". To keep it off the {other_link} link, write the line as '- {effect}: {link}'.")
    diagnosis["verdict"] += note
    diagnosis["other_link_note"] = note.strip()


def _note_held_on_other_link(diagnosis: dict[str, Any] | None, other_effects: Sequence[str], other_link: str,
                             sensor: str) -> None:
    """A line one link names that a line kept on the other link alone holds (coulomb_friction, where
    '- asymmetric_friction: actuator' is kept there): added as it is, it would sit on the other link beside its more
    general shape, which that link's own diagnosis never proposes. The verdict says to keep the new line on the link
    that named it (``held_note``)."""
    if not diagnosis or diagnosis.get("status") != "add_effect":
        return
    effect = diagnosis["candidates"][0]["effect"]
    holder = next((held for held in other_effects if effect in NESTED_IN.get(held, ())), None)
    if holder is None or not get_effect(effect).drive or not links.effects_of_link([effect], other_link, sensor):
        return
    link = "body" if other_link == "actuator" else "actuator"
    note = (f" The {other_link} link holds it already ({holder}, kept there, a more general shape of it): write the "
            f"line as '- {effect}: {link}', so that it is not fitted there beside {holder}.")
    diagnosis["verdict"] += note
    diagnosis["held_note"] = note.strip()


def _note_drive(diagnosis: dict[str, Any] | None, link: str, sensor: str) -> None:
    """A drive effect named where the sensor's position did not expect it: the verdict says what that means."""
    if not diagnosis or diagnosis.get("status") != "add_effect":
        return
    note = links.drive_verdict_note(link, diagnosis["candidates"][0]["effect"], sensor)
    if note:
        diagnosis["verdict"] += note
        diagnosis["sensor_note"] = note.strip()


@one_blas_thread
def run_sysid(
    robot: str,
    urdf_path: str | Path,
    robot_config_path: str | Path,
    model_config_path: str | Path,
    measurement_list: str | Path,
    ladder_json: str | Path,
    params_yaml: str | Path,
    calibration_yaml: str | Path,
    root: str | Path = ".",
    threads: int = 1,
    cache_dir: str | Path | None = None,
    residuals_npz: str | Path | None = None,
    robot_settings: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Files in, files out: the ladder (with diagnosis), the fitted parameters and the calibration; the last
    rung's residuals (``residuals_npz``, :func:`write_model_residuals`) for the gap report.
    ``robot_settings``: ``robot_config_path``'s content, when already read (the DAG passes it as params).

    ``measurement_list``: the measurement list, or the runs prepared from it (``prepare_runs``, ``.npz``);
    ``threads``: the diagnosis fits its candidates on that many processes (BLAS on one thread each);
    ``cache_dir``: where the rungs and diagnoses are kept for the next round (:class:`FitCache`; None: not kept).
    """
    from sim2real.identification.effects import calibration_from_params
    from sim2real.files import read_yaml, write_json, write_yaml
    from sim2real.measurements import FIT_ARRAYS, runs_for_model

    model_config = load_model_config(model_config_path)
    robot_config = dict(robot_settings) if robot_settings is not None else (read_yaml(robot_config_path) or {})
    runs = runs_for_model(measurement_list, urdf_path, root, FIT_ARRAYS)
    joints = runs[0].joint_names
    cache = FitCache(cache_dir)
    nominal = load_nominal(urdf_path, joints, robot_config.get("armature"), robot_config.get("flange"), cache=cache,
                           inertia_bands=InertiaBands.of_robot(robot_config))
    by_role: dict[str, list[PreparedRun]] = {"fit": list(runs.fit), "holdout": list(runs.holdout)}
    del runs  # by_role holds the runs alone: fit_model empties it once the links have what they need
    for role in ("fit", "holdout"):
        if not by_role[role]:
            raise InputError(measurement_list, "runs", f"no run with role '{role}'",
                             "mark at least one run role: fit and one role: holdout")
    current: dict[str, Any] = {}
    document, results = fit_model(list(model_config.effects), nominal, by_role, model_config.as_settings(), robot,
                                  workers=threads, cache=cache, release_runs=True, current_out=current)
    params = params_document(results, nominal, document["torque_source"], robot)
    write_json(ladder_json, document)
    write_yaml(params_yaml, params)
    write_yaml(calibration_yaml, round_floats(calibration_from_params(params)))
    if residuals_npz is not None:
        write_model_residuals(residuals_npz, current)
    cache.prune()
    return document
