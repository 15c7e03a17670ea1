"""Viscous joint friction: tau_f = d * qd per joint (MJCF joint ``damping``, URDF ``<dynamics damping>``)."""

from __future__ import annotations

import numpy as np

from sim2real.identification.effects.base import DiagonalEffect, ParameterSpec


class ViscousFriction(DiagonalEffect):
    in_urdf = True
    name = "viscous_friction"
    summary = "viscous joint friction, torque proportional to joint velocity"
    signature = "residual proportional to joint velocity"
    parameters = (ParameterSpec("damping", "N*m*s/rad", 0.0, 100.0, True, "joint damping (total)"),)
    feature = "qd"

    def apply_to_spec(self, spec, values, context):
        for joint, value in values["damping"].items():
            # MuJoCo 4 joint damping is a polynomial in velocity (3 coefficients): set the linear one.
            damping = np.array(spec.joint(joint).damping, dtype=float).reshape(-1)
            damping[0] = float(value)
            spec.joint(joint).damping = damping

    def calibration(self, values, calibration):
        for joint, value in values["damping"].items():
            calibration.setdefault("joints", {}).setdefault(joint, {})["damping"] = float(value)
