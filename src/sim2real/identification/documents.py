"""What the sysid rule reads and writes besides the ladder: model.yaml (:func:`load_model_config`, parsed in
:mod:`sim2real.identification.model_config`), params.yaml
(:func:`params_document`, with the drive effects of two sides merged by :func:`merge_side_values`);
:func:`round_floats` keeps every document's numbers stable and readable. The files themselves are read and written
by :mod:`sim2real.identification.formats`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.identification.effects import get_effect
from sim2real.identification.effects.sensor_delay import actuation_beyond_sensor
from sim2real.identification.fitting import FitResult, NominalModel
from sim2real.identification.records import Side

def round_floats(tree: Any, digits: int = 6) -> Any:
    """Round every float to ``digits`` significant digits: stable, readable, byte-identical outputs."""
    if isinstance(tree, dict):
        return {str(k): round_floats(v, digits) for k, v in tree.items()}
    if isinstance(tree, (list, tuple)):
        return [round_floats(v, digits) for v in tree]
    if isinstance(tree, (np.floating, float)):
        value = float(tree)
        return float(f"{value:.{digits}g}") if np.isfinite(value) else None
    if isinstance(tree, np.integer):
        return int(tree)
    if isinstance(tree, np.bool_):
        return bool(tree)
    return tree


# Why the drive side's lag is split in params.yaml's by_link (the delay's key, or the time constant's).
LAG_WHY = {
    "delay": "the measured torque lags the command by the actuation's delay plus the sensor's own (found on the body "
    "side): the actuators hold what is left of it",
    "time_constant": "the measured torque lags the command by the actuation's lag plus the sensor's own (found on the "
    "body side): the actuators hold what is left of it",
}


def merge_side_values(results: Sequence[FitResult], nominal: NominalModel) -> tuple[dict[str, Any], dict[str, Any]]:
    """Each effect's values for the assets, and the drive effects fitted on two sides apart.

    Behind a link-side sensor a drive effect may be fitted on the body side (its part after the sensor,
    from zero) and on the drive side (its part before it, from the URDF's value): the joint holds both,
    so the calibrated value is their sum. Found on the body side alone, it adds to the URDF's value.
    ``results``: the body side's last rung first (:func:`fit_model`).
    """
    effects: dict[str, Any] = {}
    by_side: dict[str, Any] = {}
    body = results[0]
    for result in results[1:]:
        effects.update(result.values)
    for name, values in body.values.items():
        spec = get_effect(name).parameters[0] if get_effect(name).parameters else None
        if not (get_effect(name).drive and body.after_sensor) or spec is None or not spec.per_joint:
            effects.setdefault(name, values)
            continue
        key = spec.name
        # the URDF holds friction, damping and armature; other parameters start from zero
        base = effects.get(name, {}).get(key) or dict(zip(nominal.joint_names, map(float, nominal.info.get(key, [])), strict=False))
        merged = dict(effects.get(name) or values)
        merged[key] = {j: float(base.get(j, 0.0)) + float(v) for j, v in values[key].items()}
        by_side[name] = {"body": values, **({"actuator": effects[name]} if name in effects else {}),
                         "why": "the body side's value acts after the link-side sensor; the joint holds the sum"}
        effects[name] = merged
    sensor = {n: v for n, v in body.values.items() if get_effect(n).time_shift and get_effect(n).sensor_side}
    actuation = [n for n in (results[1].values if len(results) > 1 else {}) if _actuator_lag(n)]
    if sensor and actuation:
        # The drive side judges the sensor's reading against the command: its lag holds the sensor's too.
        for name, taken in zip(actuation, _sensor_shares(results[1].values, actuation, sensor), strict=True):
            key = _lag_key(name)
            lag = float(effects[name][key])
            effects[name] = {**effects[name], key: actuation_beyond_sensor(lag, taken)}
            by_side[name] = {
                "actuator": {key: lag}, "body": {n: v[_lag_key(n)] for n, v in sensor.items()},
                "why": LAG_WHY[key], "sensor": list(sensor),
            }
    order = [name for result in results for name in result.effects]
    return {name: effects[name] for name in dict.fromkeys(order) if name in effects}, by_side


def _actuator_lag(name: str) -> bool:
    return get_effect(name).time_shift and get_effect(name).side == Side.DRIVE


def _lag_key(name: str) -> str:
    """A lag's one parameter in its values: ``delay`` or a first-order lag's ``time_constant``."""
    return get_effect(name).nonlinear[0].name


def _sensor_shares(values: Mapping[str, Any], actuation: Sequence[str], sensor: Mapping[str, Any]) -> list[float]:
    """The sensor's lag (its delay and time constant: at a motion's frequencies lags add) as it is taken out of each
    of the drive side's lags in turn: what is left of it when each is reached."""
    left = sum(float(v[_lag_key(n)]) for n, v in sensor.items())
    shares = []
    for name in actuation:
        shares.append(left)
        left -= float(values[name][_lag_key(name)]) - actuation_beyond_sensor(float(values[name][_lag_key(name)]), left)
    return shares


def _intervals_of(results: Sequence[FitResult], by_side: Mapping[str, Any]) -> dict[str, Any]:
    """Each effect's intervals; an actuation lag's moved with its value, the sensor's lag taken out."""
    intervals = {name: values for result in results for name, values in result.intervals.items()}
    actuation = [n for n in (results[1].values if len(results) > 1 else {}) if _actuator_lag(n) and n in by_side]
    if actuation:
        sensor = {n: {_lag_key(n): v} for n, v in by_side[actuation[0]]["body"].items()}
        for name, taken in zip(actuation, _sensor_shares(results[1].values, actuation, sensor), strict=True):
            if name in intervals:
                key = _lag_key(name)
                intervals[name] = {key: [actuation_beyond_sensor(bound, taken) for bound in intervals[name][key]]}
    return intervals


def params_document(
    results: Sequence[FitResult], nominal: NominalModel, torque_source: str, robot: str
) -> dict[str, Any]:
    """params.yaml: the last rung's fitted values of every side (:func:`fit_model`), with their intervals.

    ``torque_source``: the body side's judged torque (``tau`` or ``tau_cmd``; ladder.json's ``torque_source``).
    """
    effects, by_side = merge_side_values(results, nominal)
    # the lines model.yaml keeps on some joints: their effects hold values on those joints alone
    kept = {name: joints for result in results for name, joints in result.effect_joints.items()}
    return round_floats({
        "robot": robot,
        "effects": effects,
        **({"effect_joints": kept} if kept else {}),
        **({"by_link": by_side} if by_side else {}),
        "intervals": _intervals_of(results, by_side),
        "order": list(dict.fromkeys(name for result in results for name in result.effects)),
        "joints": nominal.joint_names,
        "torque_source": torque_source,
        "last_link": nominal.info["last_link"],
        "flange": nominal.info["flange"],
        "uncertainty": "block bootstrap of the fit runs (blocks of time, all joints together), "
        "percentile intervals with a small-sample correction for the number of blocks, conditional on the "
        "nonlinear parameters",
        "notes": [note for result in results for note in result.notes],
    })
