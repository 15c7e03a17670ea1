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

# The range a joint must sweep within one fit run to be judged (rad, or m for a prismatic joint), when the other joints
# move more: a friction's velocity law and a rotor's inertia need the joint to reverse and accelerate. The lab's
# excitations sweep each joint over 0.6 rad and more; a joint held by a brake or a controller's stiffness, or one an
# excitation forgot, wanders by hundredths (a real KUKA log: 0.02 and 0.04 rad, its other joints a radian).
MIN_RANGE_RAD = 0.1
# ... and it must sweep at least this share of the median joint's range: an arm excited slowly on purpose (the lab's
# slow_viscous: every joint 0.07 to 0.3 rad in 8 s) still identifies each joint's friction, none of its joints being
# left behind the others.
MIN_SHARE_OF_MEDIAN = 0.25


def joint_ranges(fit_runs: Sequence[PreparedRun]) -> dict[str, float]:
    """Each joint's largest range of motion within one of ``fit_runs`` (rad or m): the difference of two runs'
    resting poses is no motion."""
    ranges = np.max([np.ptp(run.q, axis=0) for run in fit_runs], axis=0)
    return {joint: float(r) for joint, r in zip(fit_runs[0].joint_names, ranges, strict=True)}


def needed_range(ranges: dict[str, float]) -> float:
    """The range a joint needs to be judged beside the others' ``ranges`` (:data:`MIN_RANGE_RAD`,
    :data:`MIN_SHARE_OF_MEDIAN`)."""
    return min(MIN_RANGE_RAD, MIN_SHARE_OF_MEDIAN * float(np.median(list(ranges.values()))))


def still_joints(fit_runs: Sequence[PreparedRun]) -> dict[str, float]:
    """The joints that move less than they need (:func:`needed_range`) in every fit run, with their range
    (:func:`joint_ranges`), in the runs' joint order; empty when every joint moves (or there is no fit run)."""
    if not fit_runs:
        return {}
    ranges = joint_ranges(fit_runs)
    needed = needed_range(ranges)
    return {joint: r for joint, r in ranges.items() if r < needed}


def not_judged_document(fit_runs: Sequence[PreparedRun]) -> dict[str, object] | None:
    """gap.json's ``not_judged``: each still joint's range (:func:`still_joints`), the range it would need, and what
    the fit holds of it; None when every joint moves."""
    still = still_joints(fit_runs)
    if not still:
        return None
    return {"joints": {joint: {"range_rad": r} for joint, r in still.items()},
            "needs_rad": needed_range(joint_ranges(fit_runs)), "held_at_nominal": ["drive friction", "rotor inertia"]}
