"""The base's mount: the direction of gravity in the robot's base frame, two tilt angles.

An arm is not always bolted level: on a mobile base, on a plate that bends, on a wall. The URDF's world says "z up";
the real gravity, seen from the base, is

    g_base = |g| (sin b, -sin a cos b, -cos a cos b)

for a base turned by ``a`` about the world's x and then ``b`` about the world's y (R = Ry(b) Rx(a), a URDF origin's
``rpy = (a, b, 0)``; g_base = R^T g_world).
Gravity torque is linear in the gravity vector for given inertials: with ``G`` (N, n, 3) the nominal model's
generalized gravity under unit gravity along the base's x, y and z
(:meth:`sim2real.assets.dynamics.RigidBodyModel.unit_gravity`), the torque the tilt adds to the level model is

    |g| [ sin b G_x - sin a cos b G_y + (1 - cos a cos b) G_z ]

Linear in (b, a) to first order: the columns are ``|g| G_x`` (coefficient ``b``) and ``-|g| G_y`` (``a``); the rest
(second order in the angles, 0.06 % of the gravity torque at 2 degrees) is the offset at the current estimate, as a
payload's own inertia is. It nests the level mount (``a = b = 0``).

An angle the data cannot see is not fitted and is reported as not identified (``identified``): the part of its
column no other tilt column explains is below :data:`VISIBLE` of the nominal gravity torque per radian (a joint 1
that never carries load, an arm that hardly moves, a planar motion whose axes are all parallel to that tilt's).

The magnitude stays the URDF's (9.81 m/s^2): scaling gravity and scaling every link's mass give the same gravity
torque, and link_inertia carries the latter (the accelerations alone tell them apart, too weakly to trust).

Assets: MJCF and URDF keep their world level (the scene's floor stays level) and turn the base. The calibrated URDF
holds a fixed joint ``world`` -> the base link with ``rpy = (a, b, 0)`` (the calibration's ``base_mount``); the
MJCF built from it carries the same as the base body's orientation, and the USD as the base prim's orientation.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sim2real.identification.effects.base import (
    ColumnLabel, Effect, ParameterSpec, Replicates, Signals, Signature, explained_per_joint, per_joint_dict,
)

STANDARD_GRAVITY = 9.81  # m/s^2: the URDF's (Pinocchio's and MuJoCo's default)
# An angle is seen when the part of its column that the other tilt's column does not explain is at least this share
# of the nominal gravity torque, per radian (RMS over the fit data): 1 % per radian is 0.02 % of the gravity torque
# at one degree, below a torque sensor's floor on any arm.
VISIBLE = 0.01
ANGLES = ("tilt_x", "tilt_y")  # a (about x), b (about y), radians


def gravity_direction(tilt_x: float, tilt_y: float) -> np.ndarray:
    """The unit gravity vector in the base frame of a base turned by ``tilt_x`` about the world's x, then ``tilt_y``
    about the world's y (URDF ``rpy = (tilt_x, tilt_y, 0)``)."""
    a, b = float(tilt_x), float(tilt_y)
    return np.array([np.sin(b), -np.sin(a) * np.cos(b), -np.cos(a) * np.cos(b)])


def mount_angles(gravity: np.ndarray) -> tuple[float, float]:
    """(tilt_x, tilt_y) of a gravity vector in the base frame (:func:`gravity_direction`'s inverse)."""
    gx, gy, gz = (float(v) for v in gravity)
    return float(np.arctan2(-gy, -gz)), float(np.arctan2(gx, np.hypot(gy, gz)))


def _columns(unit_gravity: np.ndarray) -> np.ndarray:
    """(N, n, 2): the first-order torques of the tilts (b, a) per radian."""
    return np.stack([STANDARD_GRAVITY * unit_gravity[:, :, 0], -STANDARD_GRAVITY * unit_gravity[:, :, 1]], axis=2)


def visible_angles(unit_gravity: np.ndarray) -> np.ndarray:
    """(2,) bool: whether each tilt (about x, about y) shows on these samples (module docstring, :data:`VISIBLE`)."""
    columns = _columns(unit_gravity).reshape(-1, 2)
    nominal = STANDARD_GRAVITY * unit_gravity[:, :, 2].reshape(-1)
    scale = float(np.sqrt(np.mean(nominal**2)))
    if scale <= 0:
        return np.zeros(2, dtype=bool)
    seen = np.zeros(2, dtype=bool)
    for angle in (0, 1):  # a's column is _columns' second, b's its first
        own, rest = columns[:, 1 - angle], columns[:, angle]
        along = float(rest @ own) / float(rest @ rest) if float(rest @ rest) > 0 else 0.0
        seen[angle] = float(np.sqrt(np.mean((own - along * rest) ** 2))) >= VISIBLE * scale
    return seen


class BaseMount(Effect):
    in_urdf = True
    name = "base_mount"
    summary = "the base mounted off level: gravity along another direction of the base frame than the URDF's -z"
    signature = ("residual shaped like the arm's gravity torque under a gravity turned sideways: a function of the "
                 "pose alone, on every joint that carries load, joint 1 included")
    parameters = (
        ParameterSpec("tilt_x", "rad", -0.5, 0.5, False, "a: the base turned about the world's x"),
        ParameterSpec("tilt_y", "rad", -0.5, 0.5, False, "b: then about the world's y"),
    )
    joint_local = False
    # a tilt needs only the poses, which any excitation of the gravity torque visits
    in_design = False

    def prepare(self, signals: Signals) -> dict[str, Any]:
        return {"visible": visible_angles(signals.unit_gravity)}

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        visible = state.get("visible", np.ones(2, dtype=bool))
        order = [angle for angle in (0, 1) if visible[angle]]  # a's column is _columns' second, b's its first
        cols = _columns(signals.unit_gravity)[:, :, [1 - angle for angle in order]]
        return cols, [ColumnLabel(ANGLES[angle]) for angle in order]

    def _angles(self, theta: np.ndarray, state: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """(tilt_x, tilt_y) of ``theta`` (stacked over replicates or not); an angle not seen is level."""
        visible = state.get("visible", np.ones(2, dtype=bool))
        theta = np.asarray(theta, dtype=float)
        angles, k = [], 0
        for seen in visible:
            if seen:
                angles.append(theta[..., k])
                k += 1
            else:
                angles.append(np.zeros(theta.shape[:-1]))
        return angles[0], angles[1]

    def offset(self, signals, state, theta):
        a, b = (float(v) for v in self._angles(theta, state))
        if a == 0.0 and b == 0.0:
            return None
        g = signals.unit_gravity
        return STANDARD_GRAVITY * ((np.sin(b) - b) * g[:, :, 0] - (np.sin(a) * np.cos(b) - a) * g[:, :, 1]
                                   + (1.0 - np.cos(a) * np.cos(b)) * g[:, :, 2])

    # Not stacked: the gravity vector it reports is a function of both angles together, which a replicate-wise
    # mean of stacked angles would not give.
    values_stacked = False

    def values(self, theta, nonlinear, signals, state):
        a, b = self._angles(theta, state)
        visible = state.get("visible", np.ones(2, dtype=bool))
        direction = gravity_direction(float(np.mean(a)), float(np.mean(b)))

        def rounded(value: np.ndarray, digits: int) -> Any:
            return (Replicates([round(float(v), digits) for v in np.reshape(value, -1)]) if np.ndim(value)
                    else round(float(value), digits))

        return {
            "tilt_x": rounded(a, 7),
            "tilt_y": rounded(b, 7),
            "tilt_x_deg": rounded(np.degrees(a), 4),
            "tilt_y_deg": rounded(np.degrees(b), 4),
            "identified": {"tilt_x": bool(visible[0]), "tilt_y": bool(visible[1])},
            "gravity": [round(float(v), 6) for v in STANDARD_GRAVITY * direction],
            "magnitude": STANDARD_GRAVITY,
        }

    def evidence(self, residual, signals):
        return Signature(
            description=self.signature,
            statistic="per-joint R^2 of the residual on the gravity torques under unit gravity along x and y",
            per_joint=per_joint_dict(signals.joint_names,
                                     explained_per_joint(residual, _columns(signals.unit_gravity)), 3),
        )

    def apply_to_spec(self, spec, values, context):
        # Used when calibrating an MJCF directly (the ladder's replay): the world stays level and the base turns, as
        # in the MJCF built from the calibrated URDF (the world -> base joint).
        from sim2real.assets.mount import turn_base_body

        turn_base_body(spec, float(values["tilt_x"]), float(values["tilt_y"]))

    def calibration(self, values, calibration):
        calibration["base_mount"] = {"rpy": [float(values["tilt_x"]), float(values["tilt_y"]), 0.0]}
