"""Effect library: the physical effects a nominal robot model may lack.

One module per effect (see :mod:`sim2real.effects.base` for the shape they share). The
registry maps the vocabulary of configs/{robot}/model.yaml and of the lab to effect objects.

- :func:`get_effect` / :data:`EFFECTS`: the registry.
- :func:`apply_to_spec`: write fitted values (``params["effects"]`` of params.yaml) into an MjSpec;
  the calibrated MJCF rule calls it through ``build_mjcf(..., spec_edit=...)``.
- :func:`calibration_from_params`: the calibration YAML consumed by the Xacro.
"""

from __future__ import annotations

from typing import Any

from sim2real.effects.actuation_delay import ActuationDelay
from sim2real.effects.base import ColumnLabel, Effect, ParameterSpec, Signals
from sim2real.effects.coulomb_friction import CoulombFriction
from sim2real.effects.link_inertia import LinkInertia
from sim2real.effects.payload import Payload
from sim2real.effects.rotor_inertia import RotorInertia
from sim2real.effects.torque_bias import TorqueBias
from sim2real.effects.torque_gain import TorqueGain
from sim2real.effects.viscous_friction import ViscousFriction
from sim2real.errors import InputError

EFFECTS: dict[str, Effect] = {
    effect.name: effect
    for effect in (
        ViscousFriction(),
        CoulombFriction(),
        RotorInertia(),
        ActuationDelay(),
        Payload(),
        LinkInertia(),
        TorqueBias(),
        TorqueGain(),
    )
}

__all__ = [
    "EFFECTS", "ColumnLabel", "Effect", "ParameterSpec", "Signals",
    "apply_to_spec", "calibration_from_params", "get_effect",
]


def get_effect(name: str, path: str | None = None) -> Effect:
    try:
        return EFFECTS[name]
    except KeyError:
        raise InputError(
            path, f"effect '{name}'", "is not in the effect library", f"use one of: {', '.join(EFFECTS)}"
        ) from None


def _mjcf_context(spec: Any, params: dict[str, Any]) -> dict[str, Any]:
    """Joint -> actuator name (actuators that drive a joint directly), plus what params say."""
    actuators: dict[str, str] = {}
    for actuator in spec.actuators:
        if actuator.target and actuator.name:
            actuators.setdefault(actuator.target, actuator.name)
    return {
        "actuators": actuators,
        "torque_source": params.get("torque_source"),
        "last_link": params.get("last_link"),
    }


def apply_to_spec(spec: Any, params: dict[str, Any]) -> Any:
    """Write the fitted effects of ``params`` (the content of params.yaml) into ``spec``; returns it.

    Effects URDF cannot hold (armature, actuation delay, actuator gain) land here; writing the
    others again is harmless (same values as the calibrated URDF).
    """
    context = _mjcf_context(spec, params)
    for name, values in params.get("effects", {}).items():
        get_effect(name).apply_to_spec(spec, values, context)
    return spec


def calibration_from_params(params: dict[str, Any]) -> dict[str, Any]:
    """The calibration mapping for the Xacro (``calibration:=`` argument) from params.yaml content."""
    calibration: dict[str, Any] = {}
    for name, values in params.get("effects", {}).items():
        get_effect(name).calibration(values, calibration)
    return calibration
