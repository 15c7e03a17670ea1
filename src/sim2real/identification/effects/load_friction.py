"""Load-dependent joint friction: a Coulomb level that grows with the torque the gear transmits, per joint,

    tau_f = (F_0 + mu * |tau_T|) * tanh(qd / v_s)

as harmonic drives show it (the tooth and wave-generator bearing loads grow with the transmitted torque). ``tau_T``
is the nominal model's prediction of the judged torque (``Signals.tau_nominal``): on the body side the inverse
dynamics of the URDF along the measured motion (behind a motor-side sensor with the URDF's drive terms, behind a
link-side one without), on the drive side the command. It is the nominal model's, not the current rung's: the
columns of an effect see the nominal model only, and a fitted link inertia moves ``|tau_T|`` by a few percent, which
changes the load part by a few percent of its few percent. Linear in ``F_0`` (the unloaded level, ``>= 0`` in total)
and ``mu`` (``>= 0``) for that fixed torque; the smoothing velocity ``v_s`` is refined as coulomb_friction's is.
It holds coulomb_friction (``mu = 0``), whose line it replaces (:data:`~sim2real.identification.diagnosis.caveats.SPANNED_BY`);
runs whose loaded and unloaded stretches move at the same speeds tell the two apart.

MJCF and URDF: neither has a friction that depends on the load (MuJoCo's joint ``frictionloss`` is a constant
dry friction). The calibration writes the MEAN level over the fit runs, ``F_0 + mu * mean |tau_T|`` (``mean_level``
in the values; ``mean_torque`` the mean ``|tau_T|`` it used), as the Coulomb friction into ``<dynamics friction>``
and ``frictionloss``; what is lost is the spread around it: a simulated joint under more load than the runs'
mean slides too easily, under less too hard. USD: the builder writes no joint friction (see docs/method.md, "Load
friction and PhysX").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.identification.effects.base import (
    ColumnLabel, Effect, ParameterSpec, Signals, Signature, diagonal_columns, explained_per_joint, per_joint_dict,
)
from sim2real.identification.effects.coulomb_friction import DEFAULT_SMOOTHING, SmoothedSign


def transmitted_torque(signals: Signals) -> np.ndarray:
    """(N, n) |tau_T|: the magnitude of the torque the gear carries, as the nominal model predicts it."""
    return np.abs(signals.tau_nominal)


class LoadFriction(SmoothedSign, Effect):
    drive = True
    in_urdf = True  # its mean level, as the Coulomb friction's (see the module docstring)
    name = "load_friction"
    summary = "joint friction whose Coulomb level grows with the transmitted torque (F_0 + mu |tau|), as a harmonic drive's"
    signature = ("residual steps with the sign of joint velocity whose height follows the torque the joint transmits: "
                 "larger where the joint carries more load at the same speed")
    parameters = (
        ParameterSpec("static", "N*m", 0.0, 100.0, True, "F_0: the Coulomb level without load (total)"),
        ParameterSpec("load_coefficient", "1", 0.0, 1.0, True, "mu: Coulomb level per N*m of transmitted torque"),
    )
    needs_model_torque = True

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        sliding = self.sliding(signals, nonlinear)
        labels = ([ColumnLabel("static", j) for j in signals.joint_names]
                  + [ColumnLabel("load_coefficient", j) for j in signals.joint_names])
        return np.concatenate([diagonal_columns(sliding), diagonal_columns(transmitted_torque(signals) * sliding)],
                              axis=2), labels

    def _nominal(self, signals: Signals) -> np.ndarray:
        return np.asarray(signals.nominal.get("friction", np.zeros(signals.n)), dtype=float)

    def theta_lower(self, signals, size):
        # The total unloaded level (the URDF's friction plus the fit's) is never negative, nor is mu.
        return np.concatenate([-self._nominal(signals), np.zeros(size - signals.n)])

    values_stacked = True

    def values(self, theta, nonlinear, signals, state):
        theta = np.asarray(theta, dtype=float)
        n = signals.n
        static = self._nominal(signals) + theta[..., :n]
        load = theta[..., n:]
        mean_torque = transmitted_torque(signals).mean(axis=0)
        smoothing = nonlinear if len(nonlinear) else self.nonlinear_init(signals)
        return {
            "static": per_joint_dict(signals.joint_names, static, 6),
            "load_coefficient": per_joint_dict(signals.joint_names, load, 6),
            "smoothing_velocity": per_joint_dict(signals.joint_names, smoothing, 5),
            "mean_torque": per_joint_dict(signals.joint_names, mean_torque, 4),
            "mean_level": per_joint_dict(signals.joint_names, static + load * mean_torque, 6),
        }

    def evidence(self, residual, signals):
        # What the load adds to a Coulomb friction: the share of each joint's residual the load column removes
        # beyond the sign alone.
        sliding = np.tanh(signals.qd / self.nonlinear_init(signals))
        both = np.concatenate([diagonal_columns(sliding), diagonal_columns(transmitted_torque(signals) * sliding)], axis=2)
        beyond = explained_per_joint(residual, both) - explained_per_joint(residual, diagonal_columns(sliding))
        return Signature(
            description=self.signature,
            statistic=(f"per-joint R^2 of the residual on |tau_nominal| tanh(qd / {DEFAULT_SMOOTHING} rad/s) beyond "
                       "the sign alone"),
            per_joint=per_joint_dict(signals.joint_names, np.maximum(beyond, 0.0), 3),
        )

    def apply_to_spec(self, spec, values, context):
        # MuJoCo's frictionloss is constant: the mean level over the fit runs (module docstring).
        for joint, value in values["mean_level"].items():
            spec.joint(joint).frictionloss = float(max(value, 0.0))

    def calibration(self, values, calibration):
        for joint, value in values["mean_level"].items():
            calibration.setdefault("joints", {}).setdefault(joint, {})["friction"] = float(max(value, 0.0))
