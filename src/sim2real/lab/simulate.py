"""One run of a scenario: the control loop (:mod:`.loop`) and the logger (:mod:`.logger`) put together
(:func:`simulate_run`), and the files it writes (:func:`run_lab_scenario_run`, truth.yaml)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from sim2real.assets.arm import arm_spec
from sim2real.errors import InputError
from sim2real.files import write_yaml
from sim2real.lab.config import EFFECTS, _per_joint, lab_scenario, read_excitation
from sim2real.lab.hidden import (
    _cable_spring, _cogging, _hysteretic_friction, _joint_friction, _load_friction, _torque_drift, _warming_friction,
)
from sim2real.lab.logger import _logged, log_every
from sim2real.lab.loop import _arms, _Controller, _desired_motion, _hidden_effects, _link_side_model, _LinkSide, _play
from sim2real.lab.sensor_chain import logged_noise_rms, sensor_chain
from sim2real.lab.spec_effects import _apply_spec_effects, _gains_and_biases
from sim2real.measurements.records import SensorPlacement
from sim2real.measurements.runs import DEFAULT_TORQUE_SENSOR


def _torque_sensor(scenario: Mapping[str, Any], path: Path | None) -> SensorPlacement:
    """``sensors.torque_sensor`` of a scenario: ``motor`` (the default) or ``link``."""
    where = str(scenario.get("sensors", {}).get("torque_sensor", DEFAULT_TORQUE_SENSOR))
    if where not in tuple(SensorPlacement):
        raise InputError(path, "sensors/torque_sensor", f"unknown torque sensor '{where}'",
                         f"use one of {', '.join(SensorPlacement)}")
    return SensorPlacement(where)


def simulate_run(
    mjcf_path: str | Path, joints: Sequence[str], scenario: Mapping[str, Any], seed: int,
    config_path: str | Path | None = None,
    trajectory: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, Any]]:
    """Simulate one run of a scenario: (time, {column kind: (N, n)}, resolved hidden values).

    ``trajectory`` (time, q, qd, qdd at the scenario's rate): the desired motion to play instead of the
    scenario's random Fourier series (a designed excitation, :func:`read_excitation`).
    """
    path = Path(config_path) if config_path else None
    effects = dict(scenario.get("effects") or {})
    unknown = [e for e in effects if e not in EFFECTS]
    if unknown:
        raise InputError(path, f"effects/{unknown[0]}", "unknown effect", f"use one of {', '.join(EFFECTS)}")
    rate = float(scenario["sample_rate_hz"])
    arms = _arms(mjcf_path, joints, effects, path, rate, int(scenario["substeps"]))
    desired = _desired_motion(arms.nominal, joints, scenario, seed, path, trajectory)
    hidden = _hidden_effects(effects, joints, path, seed, arms.truth, desired[0], rate)
    # A link-side torque sensor: the rigid-body inverse dynamics of the real arm without its drive terms,
    # at each sample's true state and acceleration (two MuJoCo calls per sample, only when tau is logged).
    link_side = _torque_sensor(scenario, path) == SensorPlacement.LINK_SIDE and "tau" in scenario["columns"]
    link = None
    # A load friction's level follows the same torque: what the gear transmits to the link.
    if link_side or hidden.load is not None:
        real_link = _link_side_model(mjcf_path, joints, effects, path)
        link = _LinkSide(real_link, mujoco.MjData(real_link),
                         np.array([real_link.jnt_dofadr[real_link.joint(j).id] for j in joints]),
                         {int(d): i for i, d in enumerate(arms.dadr_r)})
    sensors, controller = scenario["sensors"], scenario["controller"]
    control = _Controller(str(controller["type"]), _per_joint(controller["kp"], joints, "controller/kp", path),
                          _per_joint(controller["kd"], joints, "controller/kd", path),
                          float(sensors["encoder_resolution_rad"]), float(sensors["velocity_noise_std"]))
    rng = np.random.default_rng(seed + 7919)  # sensor noise stream, independent of the excitation draw
    played = _play(arms, desired, hidden, control, link, link_side, rng)
    return _logged(scenario, joints, desired, played, hidden, 1.0 / rate, rng) + (arms.truth,)


def run_lab_scenario_run(
    mjcf_path: str | Path, lab_config: str | Path, robot: str, scenario: str, run: str, output: str | Path,
    excitation: str | Path | None = None, scenario_spec: Mapping[str, Any] | None = None,
) -> None:
    """Simulate one run of ``scenario`` and write it (table + metadata) to ``output``.

    ``excitation``: the designed trajectory's CSV when the run names one
    (:func:`~sim2real.lab.config.excitation_designs`); ``scenario_spec``: the scenario as
    :func:`~sim2real.lab.config.lab_scenario` reads it from ``lab_config`` (read here without one).
    """
    from sim2real.measurements import RunMeta, write_run

    spec = scenario_spec if scenario_spec is not None else lab_scenario(lab_config, scenario)
    joints, settings = list(spec["joints"]), spec["settings"]
    runs = {r["name"]: r for r in settings["runs"]}
    if run not in runs:
        raise InputError(lab_config, f"scenarios/{scenario}/runs", f"no run '{run}'", f"use {', '.join(runs)}")
    trajectory = None
    if excitation is not None:
        trajectory = read_excitation(excitation, joints, float(settings["sample_rate_hz"]),
                                     f"scenarios/{scenario}/runs/{run}/excitation", lab_config)
    time, signals, _ = simulate_run(mjcf_path, joints, settings, int(runs[run]["seed"]), lab_config, trajectory)
    meta = RunMeta(
        robot=robot, source="synthetic", control_mode="torque",
        sample_rate_hz=float(settings["sample_rate_hz"]) / log_every(settings),
        torque_sensor=_torque_sensor(settings, Path(lab_config)) if "tau" in signals else None,
        notes=f"virtual lab scenario '{scenario}', run '{run}' (seed {runs[run]['seed']}"
              + (f", designed excitation '{runs[run]['excitation']}'" if excitation is not None else "") + "); "
              "hidden effects are in truth.yaml, which no comparison reads",
    )
    write_run(output, time, joints, signals, meta)


def write_truth(lab_config: str | Path, mjcf_path: str | Path, scenario: str, output: str | Path,
                scenario_spec: Mapping[str, Any] | None = None) -> None:
    """truth.yaml: the hidden effects with their resolved values, and the scenario's settings (``scenario_spec``:
    as :func:`run_lab_scenario_run` takes it)."""
    spec = scenario_spec if scenario_spec is not None else lab_scenario(lab_config, scenario)
    joints, settings = list(spec["joints"]), spec["settings"]
    spec = arm_spec(mjcf_path, joints)
    truth = _apply_spec_effects(spec, joints, settings.get("effects") or {}, Path(lab_config))
    effects = settings.get("effects") or {}
    _joint_friction(effects, joints, Path(lab_config), truth)
    dt = 1.0 / float(settings["sample_rate_hz"])
    if "actuation_delay" in effects:
        truth["actuation_delay"] = {"delay_s": round(float(effects["actuation_delay"]["delay_s"]) / dt) * dt}
    if "actuation_lag" in effects:
        truth["actuation_lag"] = {"time_constant_s": float(effects["actuation_lag"]["time_constant_s"])}
    _gains_and_biases(effects, joints, Path(lab_config), truth)
    _hysteretic_friction(effects, joints, Path(lab_config), truth)
    _load_friction(effects, joints, Path(lab_config), truth)
    _warming_friction(effects, joints, Path(lab_config), truth)
    _cogging(effects, joints, Path(lab_config), truth)
    _cable_spring(effects, joints, Path(lab_config), truth)
    if "torque_drift" in effects:
        _torque_drift(effects, joints, Path(lab_config), 0, truth, np.zeros(1))
    write_yaml(output, {
        "scenario": scenario,
        "joints": joints,
        "effects": truth,
        "sensors": settings["sensors"],
        "controller": settings["controller"],
        "columns": list(settings["columns"]),
        **_chain_truth(settings, dt),
    })


def _chain_truth(settings: Mapping[str, Any], dt: float) -> dict[str, Any]:
    """With a sensor chain (:mod:`sim2real.lab.sensor_chain`): ``sensor_noise``, the sensor's white noise (``std``)
    and what of it the log holds (``as_logged``, RMS N*m): the floor a perfect model is left at."""
    chain = sensor_chain(settings)
    if not chain:
        return {}
    std = float(settings["sensors"]["torque_noise_std"])
    return {"sensor_noise": {"std": std, "as_logged": logged_noise_rms(chain, std, dt)}}
