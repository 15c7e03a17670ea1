"""How far each joint moves in the fit runs (:func:`still_joints`).

A joint that barely moves while the others are excited (a wrist held still, a joint an excitation forgot) gives its
drive's friction and rotor inertia nothing to be told from: fitted, they would be fitted on noise, and its residual
judged against effects its motion cannot show. The fit holds that joint's own drive parameters at the nominal model's
(:data:`sim2real.identification.fitting.STILL_JOINTS_SETTING`) and the report names it as not judged, with the motion
it would need.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sim2real.measurements.runs import PreparedRun

# The range a joint must sweep within one fit run to be judged (rad, or m for a prismatic joint): a friction's
# velocity law and a rotor's inertia need the joint to reverse and accelerate over more than its encoder's and the
# filter's error. The lab's excitations sweep each joint over 0.6 rad and more; a joint held by a brake or a
# controller's stiffness wanders by hundredths.
MIN_RANGE_RAD = 0.1


def joint_ranges(fit_runs: Sequence[PreparedRun]) -> dict[str, float]:
    """Each joint's largest range of motion within one of ``fit_runs`` (rad or m): the difference of two runs'
    resting poses is no motion."""
    ranges = np.max([np.ptp(run.q, axis=0) for run in fit_runs], axis=0)
    return {joint: float(r) for joint, r in zip(fit_runs[0].joint_names, ranges, strict=True)}


def still_joints(fit_runs: Sequence[PreparedRun]) -> dict[str, float]:
    """The joints that move less than :data:`MIN_RANGE_RAD` in every fit run, with their range (:func:`joint_ranges`),
    in the runs' joint order; empty when every joint moves (or there is no fit run)."""
    if not fit_runs:
        return {}
    return {joint: r for joint, r in joint_ranges(fit_runs).items() if r < MIN_RANGE_RAD}


def not_judged_document(still: dict[str, float]) -> dict[str, object]:
    """gap.json's ``not_judged``: each still joint's range (:func:`still_joints`), the range it would need, and what
    the fit holds of it."""
    return {"joints": {joint: {"range_rad": r} for joint, r in still.items()}, "needs_rad": MIN_RANGE_RAD,
            "held_at_nominal": ["drive friction", "rotor inertia"]}
