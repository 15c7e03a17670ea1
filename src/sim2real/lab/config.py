"""lab.yaml: its scenarios with the defaults merged in, their runs, per-joint values, a designed excitation."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sim2real.errors import InputError
from sim2real.files import merge_settings, read_validated_yaml
from sim2real.measurements.runs import DEFAULT_TORQUE_SENSOR


EFFECTS = (
    "viscous_friction",
    "coulomb_friction",
    "hysteretic_friction",
    "load_friction",
    "warming_friction",
    "cogging",
    "cable_spring",
    "torque_drift",
    "rotor_inertia",
    "actuation_delay",
    "actuation_lag",
    "payload",
    "link_inertia",
    "torque_bias",
    "torque_gain",
    "actuator_gain",
    "command_bias",
    "base_mount",
)


DEFAULTS: dict[str, Any] = {
    "duration_s": 20.0,
    "sample_rate_hz": 1000.0,
    "substeps": 1,
    "columns": ["q", "qd", "tau", "tau_cmd", "q_cmd"],
    "controller": {"type": "computed_torque", "kp": 400.0, "kd": 40.0},
    "excitation": {
        "harmonics": 5,
        "base_frequency_rad_s": 0.15 * np.pi,
        "position_fraction": 0.6,
        "velocity_fraction": 0.6,
    },
    "sensors": {"torque_noise_std": 0.05, "encoder_resolution_rad": 1.0e-6, "velocity_noise_std": 0.002,
                "torque_sensor": DEFAULT_TORQUE_SENSOR.value},
    "effects": {},
}


def load_lab_config(path: str | Path) -> dict[str, Any]:
    """Validated lab.yaml with defaults merged into every scenario: {joints, scenarios: {name: settings}}."""
    path = Path(path)
    data = read_validated_yaml(path, "lab.schema.yaml")
    base = merge_settings(DEFAULTS, data.get("defaults", {}), replace=("effects",))
    scenarios = {name: merge_settings(base, spec or {}, replace=("effects",))
                 for name, spec in data["scenarios"].items()}
    for name, scenario in scenarios.items():
        if not scenario.get("runs"):
            raise InputError(path, f"scenarios/{name}/runs", "no runs: neither the scenario nor defaults lists any",
                             "list runs under defaults: (or the scenario), e.g. runs: [{name: fit, seed: 1, role: fit}, "
                             "{name: holdout, seed: 2, role: holdout}]")
        names = [run["name"] for run in scenario["runs"]]
        if len(set(names)) != len(names):
            raise InputError(path, f"scenarios/{name}/runs", "duplicate run names", "give each run a unique name")
        if "q" not in scenario["columns"] or not {"tau", "tau_cmd"} & set(scenario["columns"]):
            raise InputError(path, f"scenarios/{name}/columns", "must contain q and tau or tau_cmd",
                             "add q and at least one torque column")
    return {"joints": list(data["joints"]), "scenarios": scenarios, "path": path}


def scenario_runs(config_path: str | Path, scenario: str) -> list[dict[str, Any]]:
    """Runs ({name, seed, role}) that a scenario writes."""
    return list(lab_scenario(config_path, scenario)["settings"]["runs"])


def lab_scenario(config_path: str | Path, scenario: str) -> dict[str, Any]:
    """What a run or the truth of ``scenario`` reads of lab.yaml: ``{joints, settings}``, the scenario's settings
    with the defaults merged in, its description left out (plain data: the lab rules take it as a param, so a comment,
    a description or an edit of another scenario reruns none of this one's runs)."""
    config = load_lab_config(config_path)
    if scenario not in config["scenarios"]:
        raise InputError(config_path, f"scenarios/{scenario}", "no such scenario",
                         f"use one of {', '.join(sorted(config['scenarios']))}")
    settings = {key: value for key, value in config["scenarios"][scenario].items() if key != "description"}
    return {"joints": config["joints"], "settings": settings}


def _per_joint(value: Any, joints: Sequence[str], where: str, path: Path | None) -> np.ndarray:
    if isinstance(value, Mapping):
        unknown = [k for k in value if k not in joints]
        if unknown:
            raise InputError(path, where, f"unknown joint(s) {', '.join(unknown)}", f"use {', '.join(joints)}")
        return np.array([float(value.get(j, 0.0)) for j in joints])
    if isinstance(value, (list, tuple)):
        if len(value) != len(joints):
            raise InputError(path, where, f"has {len(value)} values for {len(joints)} joints",
                             "give one value per joint, a scalar, or a {joint: value} map")
        return np.asarray(value, dtype=float)
    return np.full(len(joints), float(value))


def _per_joint_vectors(value: Mapping[str, Any], joints: Sequence[str], where: str, path: Path | None) -> np.ndarray:
    """``{joint: [x, y, z]}`` -> (n, 3), zero for joints not listed."""
    unknown = [k for k in value if k not in joints]
    if unknown:
        raise InputError(path, where, f"unknown joint(s) {', '.join(unknown)}", f"use {', '.join(joints)}")
    return np.array([np.asarray(value.get(j, [0.0, 0.0, 0.0]), dtype=float) for j in joints])


def excitation_designs(lab_config: str | Path) -> dict[tuple[str, str], str]:
    """The designed excitation each run plays (its ``excitation`` key): {(scenario, run): design}; a run not in it
    plays its scenario's random series."""
    scenarios = load_lab_config(lab_config)["scenarios"]
    return {(name, run["name"]): run["excitation"]
            for name, scenario in scenarios.items() for run in scenario["runs"] if run.get("excitation")}


def read_excitation(path: str | Path, joints: Sequence[str], rate_hz: float, where: str,
                    config_path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A designed excitation CSV (time, q.<j>, qd.<j>, qdd.<j>) as the desired motion of a lab run."""
    import pandas as pd

    table = pd.read_csv(path)
    missing = [f"{kind}.{j}" for kind in ("q", "qd", "qdd") for j in joints if f"{kind}.{j}" not in table]
    if missing:
        raise InputError(path, f"column {missing[0]}", "missing: the design does not move the lab's joints",
                         f"list the lab's joints ({', '.join(joints)}) in the excitation.yaml `joints`")
    time = table["time"].to_numpy()
    if len(time) > 1 and abs(float(np.median(np.diff(time))) * rate_hz - 1.0) > 1e-6:
        raise InputError(config_path, where, f"the design is sampled at {1.0 / float(np.median(np.diff(time))):.6g} Hz, "
                         f"the scenario at {rate_hz:g} Hz", "give both the same sample rate")
    return (time, *(table[[f"{kind}.{j}" for j in joints]].to_numpy() for kind in ("q", "qd", "qdd")))
