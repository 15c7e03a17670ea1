"""Effect library: the physical effects a nominal robot model may lack.

One module per effect (see :mod:`sim2real.identification.effects.base` for the shape they share). The
registry maps the vocabulary of configs/{robot}/model.yaml and of the lab to effect objects.

- :func:`get_effect` / :data:`EFFECTS`: the registry.
- :func:`apply_to_spec`: write fitted values (``params["effects"]`` of params.yaml) into an MjSpec;
  the calibrated MJCF rule calls it through ``build_mjcf(..., spec_edit=...)``.
- :func:`calibration_from_params`: the calibration YAML consumed by the Xacro.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from sim2real.identification.effects.actuation_delay import ActuationDelay
from sim2real.identification.effects.actuation_lag import ActuationLag
from sim2real.identification.effects.actuator_gain import ActuatorGain
from sim2real.identification.effects.base_mount import BaseMount
from sim2real.identification.effects.asymmetric_friction import AsymmetricFriction
from sim2real.identification.effects.base import ColumnLabel, Effect, ParameterSpec, Signals, Signature
from sim2real.identification.effects.command_bias import CommandBias
from sim2real.identification.effects.coulomb_friction import CoulombFriction
from sim2real.identification.effects.hysteretic_friction import HystereticFriction
from sim2real.identification.effects.link_inertia import LinkInertia
from sim2real.identification.effects.load_friction import LoadFriction
from sim2real.identification.effects.payload import Payload
from sim2real.identification.effects.position_ripple import PositionRipple
from sim2real.identification.effects.rotor_inertia import RotorInertia
from sim2real.identification.effects.sensor_delay import SensorDelay
from sim2real.identification.effects.sensor_drift import SensorDrift
from sim2real.identification.effects.sensor_lag import SensorLag
from sim2real.identification.effects.stribeck_friction import StribeckFriction
from sim2real.identification.effects.torque_bias import TorqueBias
from sim2real.identification.effects.torque_gain import TorqueGain
from sim2real.identification.effects.viscous_friction import ViscousFriction
from sim2real.errors import InputError

EFFECTS: dict[str, Effect] = {
    effect.name: effect
    for effect in (
        ViscousFriction(),
        CoulombFriction(),
        AsymmetricFriction(),
        StribeckFriction(),
        HystereticFriction(),
        LoadFriction(),
        PositionRipple(),
        RotorInertia(),
        ActuationDelay(),
        ActuationLag(),
        Payload(),
        LinkInertia(),
        BaseMount(),
        TorqueBias(),
        TorqueGain(),
        ActuatorGain(),
        CommandBias(),
        SensorDelay(),
        SensorLag(),
        SensorDrift(),
    )
}

__all__ = [
    "EFFECTS", "ColumnLabel", "Effect", "ParameterSpec", "Signals", "Signature",
    "apply_to_spec", "calibration_from_params", "get_effect", "spec_edit_from_params",
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
        "joints": params.get("joints"),  # the identified joints (None: every actuated one)
    }


def apply_to_spec(spec: Any, params: dict[str, Any], include_urdf_effects: bool = False) -> Any:
    """Write the fitted effects of ``params`` (the content of params.yaml) into ``spec``; returns it.

    By default only the effects the URDF cannot hold (armature, the drive side's delay, gain and bias):
    the calibrated MJCF is built from the calibrated URDF, which already carries friction, payload
    and link inertias. ``include_urdf_effects=True`` writes everything (to calibrate a nominal MJCF).
    """
    context = _mjcf_context(spec, params)
    # Effects the URDF holds write total values (frictionloss = friction); the others may add to them
    # (asymmetric_friction's symmetric part adds to frictionloss), so they come after, whatever the order.
    items = sorted(params.get("effects", {}).items(), key=lambda item: not get_effect(item[0]).in_urdf)
    for name, values in items:
        effect = get_effect(name)
        if include_urdf_effects or not effect.in_urdf:
            effect.apply_to_spec(spec, values, context)
    return spec


def spec_edit_from_params(params_path: str | Path, include_urdf_effects: bool = False) -> Callable[[Any], None]:
    """``spec_edit`` for ``sim2real.assets.mjcf.build_mjcf``: apply results/{robot}/sysid/params.yaml."""
    from sim2real.identification.formats import read_params

    params = read_params(params_path)

    def edit(spec: Any) -> None:
        apply_to_spec(spec, params, include_urdf_effects)

    return edit


def calibration_from_params(params: dict[str, Any]) -> dict[str, Any]:
    """The calibration mapping for the Xacro (``calibration:=`` argument) from params.yaml content."""
    calibration: dict[str, Any] = {}
    for name, values in params.get("effects", {}).items():
        get_effect(name).calibration(values, calibration)
    return calibration
