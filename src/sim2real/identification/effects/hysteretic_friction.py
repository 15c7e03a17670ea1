"""Hysteretic (Dahl) joint friction: friction with memory, per joint.

    tau_f = F_h * z,   dz/dq = (1 - z * sign(dq)) / q_0,   |z| <= 1

Dahl's model (the presliding part of LuGre): after every reversal the friction does not jump to the other side
as a static law of the velocity would (Coulomb's sign, Gaz's sigmoid, a Stribeck hump), it turns over a few
presliding lengths ``q_0`` of the joint's own displacement. Harmonic drives show it near every reversal. The state
``z`` is integrated along the MEASURED positions of each run (segment), so the torque-domain fit can use it: along a
stretch of motion in one direction ``s`` from a reversal at ``q_r`` where the state was ``z_r``,

    z(q) = s - (s - z_r) * exp(-|q - q_r| / q_0),

exactly (no time step), and each stretch starts where the last one ended. ``F_h`` (the sliding level, >= 0) is
linear; ``q_0`` (rad, per joint, refined in log scale) nonlinear. A run starts sliding (``z = sign(qd)``).

MJCF: MuJoCo has no friction with memory. :meth:`HystereticFriction.apply_to_spec` ADDS the sliding level ``F_h``
to the joint's ``frictionloss`` (Dahl's steady state is Coulomb friction, which frictionloss is); what is lost is
the presliding hysteresis around reversals: the simulated joint turns its friction at once. URDF has no place for
it either (``in_urdf = False``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from sim2real.identification.effects.base import (
    ColumnLabel, Effect, ParameterSpec, Signals, Signature, diagonal_columns, explained_per_joint, per_joint_dict,
)

DEFAULT_PRESLIDING_RAD = 0.02  # start value of the refinement


def dahl_state(q: np.ndarray, qd: np.ndarray, segments: Sequence[slice], presliding: np.ndarray) -> np.ndarray:
    """(N, n) Dahl state ``z`` along the measured positions, run by run (see the module docstring).

    Only the state at each reversal is carried from one stretch to the next (a few scalars per joint); the
    samples of every stretch are computed at once."""
    z = np.zeros_like(q, dtype=float)
    for seg in segments:
        position, direction = q[seg], np.sign(qd[seg])
        for j in range(q.shape[1]):
            moving = np.flatnonzero(direction[:, j])
            if not moving.size:
                continue
            # a sample at rest keeps the direction it had (the motion has not reversed yet)
            filled = direction[moving, j][np.maximum(np.searchsorted(moving, np.arange(len(direction)), "right") - 1, 0)]
            starts = np.concatenate([[0], np.flatnonzero(filled[1:] != filled[:-1]) + 1])
            stops = np.append(starts[1:], len(filled))
            stretch = np.repeat(np.arange(starts.size), stops - starts)
            origin = position[starts, j]
            # the state where each stretch starts: where the one before it ended
            decay = np.exp(-np.abs(position[stops - 1, j] - origin) / presliding[j])
            sign = filled[starts]
            begin = np.empty(starts.size)
            state = sign[0]
            for k in range(starts.size):
                begin[k] = state
                state = sign[k] - (sign[k] - state) * decay[k]
            z[seg, j] = filled - (filled - begin[stretch]) * np.exp(-np.abs(position[:, j] - origin[stretch]) / presliding[j])
    return z


class HystereticFriction(Effect):
    drive = True
    in_urdf = False
    name = "hysteretic_friction"
    summary = "hysteretic (Dahl) joint friction, which turns over a presliding displacement after each reversal"
    signature = ("residual that follows the displacement since the last velocity reversal: a friction that keeps "
                 "its sign a little past each reversal")
    parameters = (ParameterSpec("level", "N*m", 0.0, 100.0, True, "sliding friction level F_h"),)
    nonlinear = (ParameterSpec("presliding_rad", "rad", 1e-3, 0.5, True, "presliding length q_0"),)

    def nonlinear_init(self, signals):
        return np.full(signals.n, DEFAULT_PRESLIDING_RAD)

    def nonlinear_bounds(self, signals):
        return np.full(signals.n, self.nonlinear[0].lower), np.full(signals.n, self.nonlinear[0].upper)

    def nonlinear_log_scale(self, signals):
        return np.ones(signals.n, dtype=bool)  # presliding lengths span decades

    def columns(self, signals: Signals, state: dict[str, Any], nonlinear: np.ndarray):
        presliding = nonlinear if len(nonlinear) else self.nonlinear_init(signals)
        z = dahl_state(signals.q, signals.qd, signals.segments, presliding)
        return diagonal_columns(z), [ColumnLabel("level", j) for j in signals.joint_names]

    def theta_lower(self, signals, size):
        return np.zeros(size)  # a sliding level is never negative

    values_stacked = True

    def values(self, theta, nonlinear, signals, state):
        presliding = nonlinear if len(nonlinear) else self.nonlinear_init(signals)
        return {
            "level": per_joint_dict(signals.joint_names, np.asarray(theta), 6),
            "presliding_rad": per_joint_dict(signals.joint_names, presliding, 5),
        }

    def evidence(self, residual, signals):
        z = dahl_state(signals.q, signals.qd, signals.segments, self.nonlinear_init(signals))
        return Signature(
            description=self.signature,
            statistic=f"per-joint R^2 of residual on the Dahl state (presliding {DEFAULT_PRESLIDING_RAD} rad)",
            per_joint=per_joint_dict(signals.joint_names, explained_per_joint(residual, diagonal_columns(z)), 3),
        )

    def apply_to_spec(self, spec, values, context):
        # Only the sliding level has a MuJoCo equivalent (dry friction); it adds to the frictionloss already there.
        for joint, value in values["level"].items():
            spec.joint(joint).frictionloss = float(spec.joint(joint).frictionloss) + float(max(value, 0.0))
