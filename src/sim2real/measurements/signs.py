"""The sign of a run's measured torque against the model's (:func:`check_torque_signs`).

A torque sensor or a driver that reports the reaction torque, or whose positive turn is the opposite of the URDF's
joint axis, logs the negative of what the arm's dynamics predict. Fitted as it came, the model would bend every
inertia and friction to turn it round; the preparation refuses it instead, naming the joints and the metadata line
that turns it (``torque_sign``). Where the model first meets the runs (:func:`sim2real.measurements.prepare_for_model`),
once per run of the measurement list, on a thinned copy of its samples: the correlation is unmoved by thinning and the
check costs milliseconds beside the preparation.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

import numpy as np

from sim2real.errors import InputError
from sim2real.measurements.runs import PreparedRun, RunSet

# A joint whose measured torque correlates with the URDF's inverse-dynamics torque below this over a run, and that the
# model predicts far better turned round (:data:`TURNED_RESIDUAL_SHARE`), is logged with the opposite sign. On the
# lab's arms, CAD errors and hidden effects included, a joint whose model torque is large against its friction stays
# above 0.8; a wrist joint whose tiny model torque drowns in its friction wanders from -0.3 to 0.8 by run, and turning
# it round changes its residual by 6 to 27 % only: no sign is told there. A flipped sign gives -0.9 to -1 and a
# residual turned round many times smaller.
FLIPPED_CORRELATION = -0.5
TURNED_RESIDUAL_SHARE = 0.5
# Samples per run the correlation is taken on (evenly spread over the run's pieces).
SIGN_SAMPLES = 4000


class InverseDynamics(Protocol):
    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray: ...


def torque_agreement(runs: Sequence[PreparedRun], model: InverseDynamics) -> tuple[np.ndarray, np.ndarray]:
    """Per joint, over ``runs``: the correlation of the measured torque with ``model``'s inverse-dynamics torque on
    their motion (NaN where either does not vary), and the RMS of the measured torque plus the model's over that of
    the measured minus the model's (below 1: the model fits the torque better turned round)."""
    step = max(1, sum(run.time.size for run in runs) // SIGN_SAMPLES)
    q, qd, qdd, tau = (np.concatenate([getattr(run, name)[::step] for run in runs])
                       for name in ("q", "qd", "qdd", "tau"))
    predicted = model.inverse_dynamics(q, qd, qdd)
    turned, logged = np.sqrt(np.mean((tau + predicted) ** 2, axis=0)), np.sqrt(np.mean((tau - predicted) ** 2, axis=0))
    measured, predicted = tau - tau.mean(axis=0), predicted - predicted.mean(axis=0)
    scale = np.sqrt((measured**2).sum(axis=0) * (predicted**2).sum(axis=0))
    correlation = np.divide((measured * predicted).sum(axis=0), scale, out=np.full(scale.shape, np.nan),
                            where=scale > 0)
    return correlation, np.divide(turned, logged, out=np.ones_like(turned), where=logged > 0)


def flipped_joints(runs: Sequence[PreparedRun], model: InverseDynamics) -> dict[str, float]:
    """The joints whose measured torque is anti-correlated with ``model``'s (:data:`FLIPPED_CORRELATION`) over
    ``runs`` (the pieces of one run), and fitted far better turned round (:data:`TURNED_RESIDUAL_SHARE`), with their
    correlation."""
    correlation, turned = torque_agreement(runs, model)
    return {joint: float(c) for joint, c, share in zip(runs[0].joint_names, correlation, turned, strict=True)
            if c < FLIPPED_CORRELATION and share < TURNED_RESIDUAL_SHARE}


def check_torque_signs(runs: RunSet[PreparedRun], model: InverseDynamics, root: str | Path = ".") -> None:
    """Each run of the list whose measured torque (``tau``, not a commanded one) is anti-correlated with ``model``'s on
    some joint is refused: one line naming the run's metadata file, every such joint and the ``torque_sign`` that
    turns it; the other runs so flipped are named."""
    by_run: dict[str, list[PreparedRun]] = {}
    for run in runs:
        if run.torque_source == "tau":
            by_run.setdefault(run.entry.name if run.entry is not None else run.name, []).append(run)
    flipped = {name: found for name, pieces in by_run.items() if (found := flipped_joints(pieces, model))}
    if not flipped:
        return
    name, joints = next(iter(flipped.items()))
    entry = by_run[name][0].entry
    run_file = Path(root) / entry.path if entry is not None else Path(name)
    listing = ", ".join(f"{joint} ({c:.2f})" for joint, c in joints.items())
    others = [other for other in flipped if other != name]
    raise InputError(
        run_file, ", ".join(f"column tau.{joint}" for joint in joints),
        f"the measured torque of run '{name}' is anti-correlated with the URDF's inverse-dynamics torque on "
        f"{len(joints)} joint(s): {listing}"
        + (f"; so are runs {', '.join(others)}" if others else ""),
        f"if the logger's torque sign is the opposite of the URDF's joint axis, add to {run_file.with_suffix('.yaml')} "
        f"'torque_sign: {{{', '.join(f'{joint}: -1' for joint in joints)}}}' (else check the joint names and the URDF)",
    )
