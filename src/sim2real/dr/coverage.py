"""Coverage of the identified values: every value from ``results/{robot}/sysid/params.yaml`` that a
randomization touches must lie, with its interval, inside the randomized absolute range.

:func:`read_identified` reads the sysid stage's own shape and a simpler hand-written one (see its
docstring); :func:`check_coverage` matches them against dr.json; :func:`coverage_summary` is what the
``dr_summary`` rule writes to ``results/{robot}/dr/coverage.json``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim2real.dr.parameters import fmt
from sim2real.errors import InputError
from sim2real.identification.formats import read_params


# Names the sysid step may use for a parameter -> the randomized channel it corresponds to.
IDENTIFIED_ALIASES: dict[str, str] = {
    "viscous_friction": "damping",
    "damping": "damping",
    "joint_damping": "damping",
    "coulomb_friction": "frictionloss",
    "frictionloss": "frictionloss",
    "friction_loss": "frictionloss",
    "joint_frictionloss": "frictionloss",
    "rotor_inertia": "armature",
    "armature": "armature",
    "joint_armature": "armature",
    "actuation_delay": "delay",
    "action_delay": "delay",
    "delay": "delay",
    "actuation_lag": "lag",
    "action_lag": "lag",
    "mass": "mass",
    "body_mass": "mass",
    "link_mass": "mass",
    "kp": "kp",
    "kd": "kd",
    "sliding_friction": "sliding_friction",
    "surface_friction": "sliding_friction",
}
GLOBAL_ELEMENT = "*"


@dataclass(frozen=True)
class IdentifiedValue:
    parameter: str  # as named in params.yaml
    channel: str
    element: str  # element name, or GLOBAL_ELEMENT for a value shared by all elements
    value: float
    interval: tuple[float, float]  # confidence interval (value, value when none given)
    relative: bool = False  # a factor of the element's nominal value (a motor gain), not an absolute value
    component: int = 0  # which of the channel's values per element (a base tilt's: 0 about x, 1 about y)


def _as_value(entry: Any) -> tuple[float, tuple[float, float]] | None:
    """A number, or a mapping with 'value' and optional 'ci'/'interval'/'ci95'/'lower'+'upper'."""
    if isinstance(entry, bool):
        return None
    if isinstance(entry, (int, float)):
        return float(entry), (float(entry), float(entry))
    if isinstance(entry, Mapping) and isinstance(entry.get("value"), (int, float)) and not isinstance(entry.get("value"), bool):
        value = float(entry["value"])
        for key in ("ci", "ci95", "interval", "confidence_interval"):
            ci = entry.get(key)
            if isinstance(ci, Sequence) and not isinstance(ci, str) and len(ci) == 2:
                return value, (float(min(ci)), float(max(ci)))
        if isinstance(entry.get("lower"), (int, float)) and isinstance(entry.get("upper"), (int, float)):
            return value, (float(entry["lower"]), float(entry["upper"]))
        return value, (value, value)
    return None


# sysid's params.yaml: (effect, quantity) -> randomized channel.
SYSID_QUANTITIES: dict[tuple[str, str], str] = {
    ("viscous_friction", "damping"): "damping",
    ("coulomb_friction", "friction"): "frictionloss",
    # The calibrated MJCF's frictionloss holds a load friction's mean level (effects.load_friction).
    ("load_friction", "mean_level"): "frictionloss",
    ("rotor_inertia", "armature"): "armature",
    ("actuation_delay", "delay"): "delay",
    ("actuation_lag", "time_constant"): "lag",
    # A motor gain scales its actuator's gainprm[0] (a servo's kp), which the kp channel randomizes.
    ("actuator_gain", "gain"): "kp",
    # The calibrated MJCF's root body is turned by the identified mount (effects.base_mount).
    ("base_mount", "tilt_x"): "base_tilt",
    ("base_mount", "tilt_y"): "base_tilt",
}
SYSID_COMPONENTS = {("base_mount", "tilt_y"): 1}  # the channel's value per element that a quantity is
RELATIVE_QUANTITIES = {("actuator_gain", "gain")}  # identified as a factor of the nominal value


def _read_sysid_effects(params: Mapping[str, Any]) -> list[IdentifiedValue]:
    """The sysid stage's shape: ``effects: {effect: {quantity: {joint: value} | value}}`` with
    ``intervals`` of the same shape holding ``[low, high]`` (absent for some quantities)."""
    found = []
    intervals = params.get("intervals") or {}
    for effect, quantities in (params.get("effects") or {}).items():
        if not isinstance(quantities, Mapping):
            continue
        for quantity, values in quantities.items():
            channel = SYSID_QUANTITIES.get((str(effect), str(quantity)))
            if channel is None:
                continue
            effect_intervals = intervals.get(effect) if isinstance(intervals, Mapping) else None
            quantity_intervals = effect_intervals.get(quantity) if isinstance(effect_intervals, Mapping) else None
            per_element = values.items() if isinstance(values, Mapping) else [(GLOBAL_ELEMENT, values)]
            for element, value in per_element:
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    continue
                ci = quantity_intervals.get(element) if isinstance(quantity_intervals, Mapping) else quantity_intervals
                interval = (float(min(ci)), float(max(ci))) if isinstance(ci, list) and len(ci) == 2 else (float(value), float(value))
                found.append(IdentifiedValue(f"{effect}.{quantity}", channel, str(element), float(value), interval,
                                             (str(effect), str(quantity)) in RELATIVE_QUANTITIES,
                                             SYSID_COMPONENTS.get((str(effect), str(quantity)), 0)))
    return found


def read_identified(params: Any) -> list[IdentifiedValue]:
    """Identified values from a parsed ``results/{robot}/sysid/params.yaml``.

    The sysid stage's own shape (``effects`` + ``intervals``, see :func:`_read_sysid_effects`;
    mapping in :data:`SYSID_QUANTITIES`) is read first. Otherwise this simple shape (anything
    else is ignored, unknown parameter names too)::

        parameters:                      # optional wrapper
          viscous_friction:              # parameter name, see IDENTIFIED_ALIASES
            panda_joint1: {value: 0.21, ci: [0.19, 0.23]}   # element -> value (+ interval)
            panda_joint2: 0.18                              # bare number: no interval
          actuation_delay: {value: 0.012, ci: [0.010, 0.014]}  # no element: applies to all

    A list of records ``[{parameter|effect|name, element|joint|body|actuator, value, ci}]`` is also
    accepted, under ``parameters`` or at the top level.
    """
    if isinstance(params, Mapping) and isinstance(params.get("effects"), Mapping):
        return _read_sysid_effects(params)
    root = params.get("parameters", params) if isinstance(params, Mapping) else params
    found: list[IdentifiedValue] = []

    def add(parameter: str, element: str, entry: Any) -> None:
        channel = IDENTIFIED_ALIASES.get(str(parameter))
        parsed = _as_value(entry)
        if channel is not None and parsed is not None:
            found.append(IdentifiedValue(str(parameter), channel, str(element), parsed[0], parsed[1]))

    if isinstance(root, Mapping):
        for parameter, body in root.items():
            if _as_value(body) is not None:
                add(parameter, GLOBAL_ELEMENT, body)
            elif isinstance(body, Mapping):
                for element, entry in body.items():
                    add(parameter, element, entry)
    elif isinstance(root, Sequence) and not isinstance(root, str):
        for record in root:
            if not isinstance(record, Mapping):
                continue
            parameter = record.get("parameter", record.get("effect", record.get("name")))
            element = next((record[k] for k in ("element", "joint", "body", "actuator", "geom") if k in record), GLOBAL_ELEMENT)
            if parameter is not None:
                add(parameter, element, record)
    return found


def check_coverage(resolved: Mapping[str, Any], identified: Sequence[IdentifiedValue]) -> list[dict[str, Any]]:
    """Every identified value (with its interval) that a randomization touches must lie inside the
    randomized absolute range. Returns one record per touched value with ``covered`` true/false."""
    records = []
    for channel in resolved["physics"]:
        for item in identified:
            if item.channel != channel["channel"]:
                continue
            for target in channel["targets"]:
                names = {target["name"], target.get("joint")}
                if item.element != GLOBAL_ELEMENT and item.element not in names:
                    continue
                lo, hi = target["range"][item.component]
                scale = float(target["nominal"][item.component]) if item.relative else 1.0
                value, interval = item.value * scale, sorted((item.interval[0] * scale, item.interval[1] * scale))
                covered = lo <= interval[0] and interval[1] <= hi
                records.append(
                    {
                        "term": channel["term"],
                        "channel": channel["channel"],
                        "element": target["name"],
                        "identified_as": item.parameter,
                        "value": value,
                        "interval": list(interval),
                        "range": [lo, hi],
                        "covered": covered,
                    }
                )
    return sorted(records, key=lambda r: (r["term"], r["channel"], r["element"], r["identified_as"]))


def coverage_summary(
    resolved: Mapping[str, Any], params_path: str | Path | None, *, strict: bool = False
) -> dict[str, Any]:
    """Coverage for ``params_path`` (skipped when None or absent). Uncovered values raise with
    ``strict``, else they are listed under ``warnings``."""
    if params_path is None or not Path(params_path).exists():
        return {"status": "skipped", "reason": "no identified parameters (sysid/params.yaml absent)", "records": [], "warnings": []}
    records = check_coverage(resolved, read_identified(read_params(params_path)))
    uncovered = [r for r in records if not r["covered"]]
    warnings = [
        f"{r['term']}/{r['element']}: identified {r['identified_as']} {fmt(r['value'])} "
        f"(interval [{fmt(r['interval'][0])}, {fmt(r['interval'][1])}]) outside the randomized range "
        f"[{fmt(r['range'][0])}, {fmt(r['range'][1])}]"
        for r in uncovered
    ]
    if uncovered and strict:
        raise InputError(
            params_path,
            "identified values outside the randomized ranges",
            "; ".join(warnings),
            "widen the matching ranges in configs/<robot>/dr.yaml so they contain the identified intervals",
        )
    return {"status": "checked" if records else "nothing touched", "records": records, "warnings": warnings}
