"""Payload: a point mass m at position c in the frame of the last moving link.

Linear in (m, m*c) through the last body's gravity/inertia regressor columns; the point mass's
own rotational inertia about the joint, m*(|c|^2 I - c c^T), is the nonlinear remainder and is
added as an offset at the current estimate. MJCF: an added body in the last link; URDF: the
``payload`` section of the calibration file.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.identification.effects.base import (
    ColumnLabel, Effect, ParameterSpec, Signals, Signature, explained_per_joint, per_joint_dict,
)

PAYLOAD_BODY_NAME = "calibrated_payload"


def point_mass_inertia(mass: float, com: np.ndarray) -> np.ndarray:
    """Rotational inertia about the frame origin, Pinocchio order (xx, xy, yy, xz, yz, zz)."""
    c = np.asarray(com, dtype=float)
    inertia = mass * (float(c @ c) * np.eye(3) - np.outer(c, c))
    return np.array([inertia[0, 0], inertia[0, 1], inertia[1, 1], inertia[0, 2], inertia[1, 2], inertia[2, 2]])


def _last_body_columns(signals: Signals) -> np.ndarray:
    last = signals.nominal["n_bodies"] - 1
    return signals.regressor[:, :, 10 * last : 10 * last + 10]


class Payload(Effect):
    in_urdf = True
    name = "payload"
    summary = "an unmodelled mass carried by the last link"
    signature = "residual explained by the gravity columns (m, m*c) of the last link"
    parameters = (
        ParameterSpec("mass", "kg", 0.0, 20.0, False, "payload mass"),
        ParameterSpec("com", "m", -0.5, 0.5, False, "payload position in the last link frame (x, y, z)"),
    )
    joint_local = False

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        return _last_body_columns(signals)[:, :, :4], [
            ColumnLabel("mass"), ColumnLabel("m*com_x"), ColumnLabel("m*com_y"), ColumnLabel("m*com_z"),
        ]

    def theta_lower(self, signals, size):
        return np.array([0.0, -np.inf, -np.inf, -np.inf])  # a payload has a mass >= 0

    def offset(self, signals, state, theta):
        mass = float(theta[0])
        if mass <= 1e-6:
            return None
        com = np.asarray(theta[1:4]) / mass
        return _last_body_columns(signals)[:, :, 4:] @ point_mass_inertia(mass, com)

    def values(self, theta, nonlinear, signals, state):
        mass = float(theta[0])
        com = np.asarray(theta[1:4]) / mass if abs(mass) > 1e-6 else np.zeros(3)
        # Reported in the flange frame (where a payload is mounted and where the Xacro puts it).
        rotation = np.asarray(signals.nominal.get("flange_rotation", np.eye(3)))
        translation = np.asarray(signals.nominal.get("flange_translation", np.zeros(3)))
        return {
            "mass": round(mass, 6),
            "com": [round(float(c), 6) for c in rotation.T @ (com - translation)],
            "link": signals.nominal.get("flange", signals.nominal.get("last_link")),
            "com_in_last_link": [round(float(c), 6) for c in com],
            "last_link": signals.nominal.get("last_link"),
        }

    def evidence(self, residual, signals):
        return Signature(
            description=self.signature,
            statistic="per-joint R^2 of residual on the last link's (m, m*c) regressor columns",
            per_joint=per_joint_dict(
                signals.joint_names, explained_per_joint(residual, _last_body_columns(signals)[:, :, :4]), 3
            ),
        )

    def apply_to_spec(self, spec, values, context):
        mass = float(values["mass"])
        if mass <= 0:
            return
        # The flange may have been fused into the last link by the URDF import: fall back to it.
        if spec.body(values["link"]) is not None:
            parent, pos = spec.body(values["link"]), values["com"]
        else:
            parent, pos = spec.body(values["last_link"]), values["com_in_last_link"]
        body = parent.add_body(name=PAYLOAD_BODY_NAME, pos=[float(c) for c in pos])
        body.mass = mass
        body.explicitinertial = True
        body.inertia = [1e-6, 1e-6, 1e-6]  # a point mass; MuJoCo needs a positive inertia

    def calibration(self, values, calibration):
        if float(values["mass"]) <= 0:
            return
        point = 1e-6  # kg m^2: a point mass; URDF and MuJoCo need a positive inertia
        calibration["payload"] = {
            "mass": float(values["mass"]),
            "com": [float(c) for c in values["com"]],
            "inertia": {"ixx": point, "ixy": 0.0, "ixz": 0.0, "iyy": point, "iyz": 0.0, "izz": point},
        }
