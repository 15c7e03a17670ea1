"""Rotor (reflected motor) inertia: tau = I_a * qdd per joint (MJCF joint ``armature``; URDF cannot hold it)."""

from __future__ import annotations

from sim2real.identification.effects.base import DiagonalEffect, ParameterSpec


class RotorInertia(DiagonalEffect):
    name = "rotor_inertia"
    summary = "reflected rotor inertia (armature), torque proportional to joint acceleration"
    signature = "residual proportional to joint acceleration"
    parameters = (ParameterSpec("armature", "kg*m^2", 0.0, 10.0, True, "rotor inertia at the joint (total)"),)
    feature = "qdd"

    def apply_to_spec(self, spec, values, context):
        for joint, value in values["armature"].items():
            spec.joint(joint).armature = float(max(value, 0.0))
