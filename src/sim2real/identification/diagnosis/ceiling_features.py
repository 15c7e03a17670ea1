"""The features the model-free ceiling's learners read (:mod:`~sim2real.identification.diagnosis.ceiling`): the motion,
the joint's dynamics and their signed products, the pose, harmonics of a joint's own position, the displacement since
a reversal; each column named as data (:func:`feature`, the report words it), and which of them a chosen learner read.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

DYNAMICS_TREES = "trees on the joint's dynamics"
DYNAMICS_LEARNER = "a ridge regression on the joint's dynamics times the sign of its velocity"
# Ridge regressions on features of the pose that carry a function of it to poses the fit runs never visited (trees
# on a 7-dimensional pose do not): the joint's generalized gravity under unit gravity along the base's x, y and z
# (what a gravity turned sideways, a mount off level, adds: exactly linear in them), and those beside the sine and
# cosine of every joint's angle (what the kinematics turns a pose into: a cable's or a spring's pull).
GRAVITY_LEARNER = "a ridge regression on the joint's gravity torque under unit gravity along x, y and z"
POSE_LEARNER = "a ridge regression on the pose"
POSE_LEARNERS = (GRAVITY_LEARNER, POSE_LEARNER)
# Harmonics of a joint's own position: sin and cos of k * q for k = 1..POSITION_HARMONICS (periods down to 2 pi / 40
# = 0.16 rad of the joint), what a cogging or a gear's ripple follows, periodic wherever the runs go.
POSITION_HARMONICS = 40
# A ripple whose period is no whole fraction of a turn parts from those harmonics beyond the positions the fit runs
# visit: its own period (position_ripple.best_periods, on the fit runs) and this many of its harmonics.
PERIOD_HARMONICS = 3


def position_harmonics(q: np.ndarray) -> np.ndarray:
    """(N, 2K) sin and cos of k * q, k = 1..:data:`POSITION_HARMONICS`, of one joint's position."""
    k = np.arange(1, POSITION_HARMONICS + 1)
    return np.hstack([np.sin(np.outer(q, k)), np.cos(np.outer(q, k))])


def period_harmonics(q: np.ndarray, period: float) -> np.ndarray:
    """(N, 2K) sin and cos of 2 pi k q / ``period``, k = 1..:data:`PERIOD_HARMONICS`, of one joint's position."""
    k = np.arange(1, PERIOD_HARMONICS + 1)
    angle = np.outer(q, 2 * np.pi * k / period)
    return np.hstack([np.sin(angle), np.cos(angle)])


def motion_features(data: Any) -> tuple[np.ndarray, list[dict[str, str]]]:
    """(N, 3n) q, qd, qdd of every joint, and each column's feature (:func:`feature`)."""
    joints = list(data.joint_names)
    names = [feature(kind, joint) for kind in ("position", "velocity", "acceleration") for joint in joints]
    return np.hstack([data.q, data.qd, data.qdd]), names


def feature(kind: str, joint: str, **figures: float) -> dict[str, Any]:
    """A learner's feature as data (the report words it): its ``kind`` (``position``, ``velocity``, ``acceleration``,
    ``predicted_torque``, ``velocity_sign``, ``speed``, ``gravity_torque``, ``torque_times_sign``,
    ``abs_torque_times_sign``, ``periodic_position``), the joint it is of, and its figures (a ripple's ``period``)."""
    return {"feature": kind, "joint": joint, **figures}


def dynamics_features(data: Any, residual: np.ndarray, gravity: np.ndarray | None) -> np.ndarray:
    """(N, n, k) per joint: the torque the last rung predicts (the judged torque less its residual), the sign and the
    magnitude of the velocity, and the gravity torque when the nominal model gives it (``gravity``, (N, n))."""
    features = [np.asarray(data.tau, dtype=float) - residual, np.sign(data.qd), np.abs(data.qd)]
    if gravity is not None:
        features.append(np.asarray(gravity, dtype=float))
    return np.stack(features, axis=2)


def dynamics_names(joint: str, k: int) -> list[dict[str, Any]]:
    """The features of :func:`dynamics_features`' ``k`` columns of ``joint``."""
    return [feature(kind, joint) for kind in ("predicted_torque", "velocity_sign", "speed", "gravity_torque")][:k]


def signed_products(features: np.ndarray) -> np.ndarray:
    """(N, 3) of one joint's :func:`dynamics_features` (N, k): the sign of its velocity, and the torque the rung
    predicts times that sign, as it is and in magnitude. A friction that grows with the load is such a product: trees
    on the factors cannot carry it to a run whose torques lie elsewhere, a line on the products can. The gravity
    torque and the speed stay out: nearly the predicted torque on a shoulder, a line in them extrapolates noise."""
    sign = features[:, 1]
    return np.column_stack([sign, features[:, 0] * sign, np.abs(features[:, 0]) * sign])


def signed_names(joint: str) -> list[dict[str, Any]]:
    """The features of :func:`signed_products`' columns of ``joint``."""
    return [feature(kind, joint) for kind in ("velocity_sign", "torque_times_sign", "abs_torque_times_sign")]


def pose_features(q: np.ndarray, unit_gravity: np.ndarray, j: int, learner: str = POSE_LEARNER) -> np.ndarray:
    """(N, 3 + 2n) of joint ``j``: its generalized gravity under unit gravity along x, y, z (``unit_gravity``, (N, n,
    3): :meth:`sim2real.assets.dynamics.RigidBodyModel.unit_gravity`), and sin, cos of every joint's angle; the
    first three alone for :data:`GRAVITY_LEARNER`."""
    if learner == GRAVITY_LEARNER:
        return np.asarray(unit_gravity[:, j, :], dtype=float)
    return np.hstack([unit_gravity[:, j, :], np.sin(q), np.cos(q)])


def pose_names(joints: Sequence[str], j: int, learner: str = POSE_LEARNER) -> list[dict[str, Any]]:
    """The features of :func:`pose_features`' columns of joint ``j``."""
    gravity = [feature(kind, joints[j]) for kind in ("gravity_along_x", "gravity_along_y", "gravity_along_z")]
    if learner == GRAVITY_LEARNER:
        return gravity
    return gravity + [feature("sin_position", joint) for joint in joints] + [feature("cos_position", joint) for joint in joints]


def since_reversal(q: np.ndarray, qd: np.ndarray, segments: Sequence[slice]) -> np.ndarray:
    """(N, n) displacement since the last change of the velocity's sign (per run, from its first sample)."""
    out = np.zeros_like(q)
    for seg in segments:
        qs, vs = q[seg], np.sign(qd[seg])
        rows = np.arange(qs.shape[0])[:, None]
        changed = np.vstack([np.ones((1, qs.shape[1]), dtype=bool), (vs[1:] != vs[:-1]) & (vs[1:] != 0)])
        last = np.maximum.accumulate(np.where(changed, rows, 0), axis=0)
        out[seg] = qs - np.take_along_axis(qs, last, axis=0)
    return out


@dataclass(frozen=True)
class LearnerFeatures:
    """The features of the fit and the holdout runs the ceiling's ridge and tree learners read beside the motion:
    ``dynamics`` (:func:`dynamics_features`) and ``pose`` (the nominal model's unit gravity, (N, n, 3) each, the
    first columns of :func:`pose_features`); None: no such learner."""

    dynamics: tuple[np.ndarray, np.ndarray] | None = None
    pose: tuple[np.ndarray, np.ndarray] | None = None


def _chosen_features(chosen: str, j: int, holdout_data: Any,
                     features: LearnerFeatures | None) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """The holdout features the ``chosen`` learner of joint ``j`` read, and their names (what its gain is read off)."""
    joints = list(holdout_data.joint_names)
    if chosen in (DYNAMICS_TREES, DYNAMICS_LEARNER):
        assert features is not None and features.dynamics is not None
        x_holdout = features.dynamics[1][:, j]
        if chosen == DYNAMICS_LEARNER:
            return signed_products(x_holdout), signed_names(joints[j])
        return x_holdout, dynamics_names(joints[j], x_holdout.shape[1])
    if chosen in POSE_LEARNERS:
        assert features is not None and features.pose is not None
        return pose_features(holdout_data.q, features.pose[1], j, chosen), pose_names(joints, j, chosen)
    return motion_features(holdout_data)
