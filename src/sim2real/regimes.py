"""The operating regimes a model error can live in: slow motion and velocity reversals, hard
accelerations, gravity-loaded poses, near the position limits.

One home for what a regime is: its name (:data:`REGIMES`, a contract of gap.json), the words the
report uses (:data:`REGIME_LABELS`), the definition written into gap.json (:data:`REGIME_DEFINITIONS`)
and the same definition as code (:func:`regime_masks`). ``sim2real.gap`` finds the regimes where
the model fails; ``sim2real.report`` draws and words them.
"""

from __future__ import annotations

import numpy as np

from sim2real.measurements import PreparedRun

REGIMES = ("slow_reversal", "hard_acceleration", "gravity_loaded", "near_limit")
REGIME_LABELS = {
    "slow_reversal": "slow motion and velocity reversals",
    "hard_acceleration": "hard accelerations",
    "gravity_loaded": "gravity-loaded poses",
    "near_limit": "near the position limits",
}
REGIME_DEFINITIONS = {
    "slow_reversal": "|qd| below 15% of the joint's 99th-percentile speed; sides: sign of qd",
    "hard_acceleration": "|qdd| above the joint's 80th percentile; sides: sign of qdd",
    "gravity_loaded": "|gravity torque| above 70% of its maximum (joints with > 0.5 N*m); sides: its sign",
    "near_limit": "within 10% of the range of a position limit; sides: which limit",
}


def regime_masks(
    run: PreparedRun, gravity: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> dict[str, tuple[np.ndarray, ...]]:
    """Per regime: (in-regime mask, side = +1/-1 splitting the regime in two, stratum), each (N, n).

    ``gravity`` is the model's gravity torque along the run, ``lower``/``upper`` the position limits.
    The side is the sign of the regime's variable: velocity, acceleration, gravity torque, which limit.
    A model error that lives in the regime shows as a step of the residual between the two sides.
    The stratum is the sign of the variable most likely to confound it (velocity, whose friction
    error would otherwise leak into any regime the motion direction correlates with; acceleration for
    the slow regime): the step is measured within each stratum and averaged.
    """
    speed = np.abs(run.qd)
    v_slow = 0.15 * np.percentile(speed, 99, axis=0)
    acc = np.abs(run.qdd)
    a_hard = np.percentile(acc, 80, axis=0)
    g_abs = np.abs(gravity)
    g_max = g_abs.max(axis=0)
    rng_ = np.where(np.isfinite(upper - lower), upper - lower, np.inf)
    dist_lo = run.q - lower
    dist_hi = upper - run.q
    near = np.minimum(dist_lo, dist_hi) < 0.1 * rng_
    return {
        "slow_reversal": (speed < v_slow, np.sign(run.qd), np.sign(run.qdd)),
        "hard_acceleration": (acc > a_hard, np.sign(run.qdd), np.sign(run.qd)),
        "gravity_loaded": ((g_abs > 0.7 * g_max) & (g_max > 0.5), np.sign(gravity), np.sign(run.qd)),
        "near_limit": (near, np.where(dist_hi < dist_lo, 1.0, -1.0), np.sign(run.qd)),
    }
