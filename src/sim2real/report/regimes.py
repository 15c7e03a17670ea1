"""The operating regimes a model error can live in: slow motion and velocity reversals, hard
accelerations, gravity-loaded poses, near the position limits.

One home for what a regime is: its name (:data:`REGIMES`, a contract of gap.json), the words the
report uses (:data:`REGIME_LABELS`), the definition written into gap.json (:data:`REGIME_DEFINITIONS`)
and the same definition as code (:func:`regime_masks`); where the model fails in them
(:func:`where_it_fails`: per joint and regime the step of the residual between the regime's two sides) and the
worst time windows. :mod:`sim2real.report.figures` and :mod:`~sim2real.report.markdown` draw and word them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.measurements import PreparedRun
from sim2real.report.metrics import TorqueComparison

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


WINDOW_S = 0.5


N_WORST_WINDOWS = 5


def _stratified_step(r: np.ndarray, pos: np.ndarray, neg: np.ndarray, strata: np.ndarray) -> float:
    """|mean(r | pos) - mean(r | neg)| within each stratum, averaged with the stratum sizes."""
    total, weight = 0.0, 0
    for value in (-1.0, 1.0):
        a, b = pos & (strata == value), neg & (strata == value)
        if a.sum() > 10 and b.sum() > 10:
            n = int(a.sum() + b.sum())
            total += n * float(r[a].mean() - r[b].mean())
            weight += n
    return abs(total / weight) if weight else 0.0


def where_it_fails(
    comparisons: Sequence[TorqueComparison], lower: np.ndarray, upper: np.ndarray, noise_floor: np.ndarray,
) -> dict[str, Any]:
    joints = comparisons[0].run.joint_names
    masks = [regime_masks(c.run, c.gravity, lower, upper) for c in comparisons]
    residual = np.concatenate([c.residual for c in comparisons])
    overall = np.sqrt(np.mean(residual**2, axis=0))
    per_joint: dict[str, Any] = {}
    findings = []
    for jj, joint in enumerate(joints):
        entry: dict[str, Any] = {"rmse": float(overall[jj]), "noise_floor": float(noise_floor[jj]), "regimes": {}}
        for regime in REGIMES:
            inside = np.concatenate([m[regime][0][:, jj] for m in masks])
            side = np.concatenate([m[regime][1][:, jj] for m in masks])
            r = residual[:, jj]
            n_in = int(inside.sum())
            if n_in < 20 or n_in == inside.size:
                entry["regimes"][regime] = {"fraction": n_in / inside.size, "applicable": False}
                continue
            rin = r[inside]
            pos, neg = inside & (side > 0), inside & (side < 0)
            strata = np.concatenate([m[regime][2][:, jj] for m in masks])
            step = _stratified_step(r, pos, neg, strata)
            p = pos.sum() / max(n_in, 1)
            # share of the in-regime residual power that the two-sided step explains
            explained = float(min(1.0, step**2 * p * (1 - p) / max(np.mean(rin**2), 1e-18)))
            rmse_in = float(np.sqrt(np.mean(rin**2)))
            rmse_out = float(np.sqrt(np.mean(r[~inside] ** 2)))
            entry["regimes"][regime] = {
                "applicable": True, "fraction": float(n_in / inside.size), "rmse": rmse_in, "rmse_outside": rmse_out,
                "step": step, "explained": explained,
            }
            systematic = step > 3.0 * noise_floor[jj] and step > 0.5 * overall[jj]
            if systematic and explained > 0.2:
                findings.append({"joint": joint, "regime": regime, "step": step, "explained": explained,
                                 "rmse_in_regime": rmse_in, "label": REGIME_LABELS[regime]})
        per_joint[joint] = entry
    # keep, per joint, the regimes whose step is comparable to that joint's strongest one
    strongest = {}
    for f in findings:
        strongest[f["joint"]] = max(strongest.get(f["joint"], 0.0), f["step"] * f["explained"])
    findings = [f for f in findings if f["step"] * f["explained"] >= 0.5 * strongest[f["joint"]]]
    findings.sort(key=lambda f: (-f["step"] * f["explained"], f["joint"], f["regime"]))
    regime_counts: dict[str, int] = {}
    for f in findings:
        regime_counts[f["regime"]] = regime_counts.get(f["regime"], 0) + 1
    return {
        "per_joint": per_joint,
        "findings": findings,
        "summary": {
            "joints": sorted({f["joint"] for f in findings}, key=joints.index),
            "regimes": sorted(regime_counts, key=lambda r: (-regime_counts[r], r)),
        },
        "worst_windows": worst_windows(comparisons, masks),
        "definitions": {
            **REGIME_DEFINITIONS,
            "step": "|mean residual on one side - on the other| in N*m: an error that lives in the regime",
            "explained": "share of the in-regime residual power explained by that step (0..1)",
            "finding": "step > 3x noise floor and > 0.5x the joint RMSE and explained > 0.2",
        },
    }


def worst_windows(comparisons: Sequence[TorqueComparison], masks: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The N worst non-overlapping windows (by residual RMSE over all joints), with stamps."""
    candidates = []
    for c, m in zip(comparisons, masks):
        w = max(1, int(round(WINDOW_S / c.run.dt)))
        n_win = c.residual.shape[0] // w
        for k in range(n_win):
            block = c.residual[k * w:(k + 1) * w]
            per_joint = np.sqrt(np.mean(block**2, axis=0))
            jj = int(np.argmax(per_joint))
            shares = {r: float(m[r][0][k * w:(k + 1) * w, jj].mean()) for r in REGIMES}
            candidates.append({
                "run": c.run.name,
                "t_start": float(c.run.time[k * w]),
                "t_end": float(c.run.time[min((k + 1) * w, c.run.time.size - 1)]),
                "rmse": float(np.sqrt(np.mean(block**2))),
                "worst_joint": c.run.joint_names[jj],
                "worst_joint_rmse": float(per_joint[jj]),
                "regime_share": shares,
            })
    candidates.sort(key=lambda x: (-x["rmse"], x["run"], x["t_start"]))
    return candidates[:N_WORST_WINDOWS]
