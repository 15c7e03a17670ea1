"""Metrics of the gap report: the torque domain's errors (RMSE, relative RMSE, R^2, per joint and overall) and the
state domain's reality-gap score and fidelity grade of the source chapter (P02.5)::

    score = 0.3 min(pos/0.1,1) + 0.2 min(vel/1,1) + 0.15 min(tau/5,1) + 0.15 (1-corr) + 0.1 min(spec/1,1)
            + 0.1 (1-contact F1)

``tau`` is the torque-domain RMSE. Without contact flags the contact term is not applicable and the other weights
are renormalised to sum to 1 (an arm in free space would otherwise be charged 0.1 for contacts that do not exist).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim2real.measurements import PreparedRun
from sim2real.stats import rmse

GAP_WEIGHTS = {"position": 0.3, "velocity": 0.2, "torque": 0.15, "correlation": 0.15, "spectral": 0.1, "contact": 0.1}


@dataclass(frozen=True)
class TorqueComparison:
    run: PreparedRun
    role: str
    model_tau: np.ndarray
    residual: np.ndarray  # measured - model
    gravity: np.ndarray


def per_joint_dict(values: np.ndarray, joints: Sequence[str], overall: float) -> dict[str, Any]:
    return {"overall": float(overall), "per_joint": {j: float(v) for j, v in zip(joints, values)}}


def torque_metrics(measured: np.ndarray, residual: np.ndarray, joints: Sequence[str]) -> dict[str, Any]:
    """RMSE, relative RMSE (to the measured RMS) and R^2, each {overall, per_joint}."""
    err = rmse(residual, joints)
    rms = np.sqrt(np.mean(measured**2, axis=0))
    rms_all = float(np.sqrt(np.mean(measured**2)))
    rel = np.asarray([err["per_joint"][j] for j in joints]) / np.maximum(rms, 1e-12)
    ss_res = np.sum(residual**2, axis=0)
    ss_tot = np.sum((measured - measured.mean(axis=0)) ** 2, axis=0)
    r2 = 1.0 - ss_res / np.maximum(ss_tot, 1e-12)
    r2_all = 1.0 - ss_res.sum() / max(float(ss_tot.sum()), 1e-12)
    return {
        "torque_rmse": err,
        "torque_relative_rmse": per_joint_dict(rel, joints, err["overall"] / max(rms_all, 1e-12)),
        "torque_r2": per_joint_dict(r2, joints, r2_all),
    }


def spectral_divergence(sim: np.ndarray, real: np.ndarray) -> float:
    """KL divergence of normalised magnitude spectra of the positions (source chapter P02.5), mean over joints."""
    divs = []
    for j in range(min(sim.shape[1], 7)):
        s = np.abs(np.fft.rfft(sim[:, j]))
        r = np.abs(np.fft.rfft(real[:, j]))
        s = s / (s.sum() + 1e-10)
        r = r / (r.sum() + 1e-10)
        divs.append(float(np.sum(r * np.log((r + 1e-10) / (s + 1e-10)))))
    return float(np.mean(divs))


def reality_gap(pos_rmse: float, vel_rmse: float, tau_rmse: float, corr: float, spectral: float,
                contact_f1: float | None) -> dict[str, Any]:
    """Overall gap score, grade and recommendation of the source chapter's reality-gap metric."""
    terms = {
        "position": min(pos_rmse / 0.1, 1.0),
        "velocity": min(vel_rmse / 1.0, 1.0),
        "torque": min(tau_rmse / 5.0, 1.0),
        "correlation": 1.0 - corr,
        "spectral": min(spectral / 1.0, 1.0),
    }
    weights = dict(GAP_WEIGHTS)
    if contact_f1 is None:
        weights.pop("contact")
        total = sum(weights.values())
        weights = {k: v / total for k, v in weights.items()}
    else:
        terms["contact"] = 1.0 - contact_f1
    score = float(sum(weights[k] * terms[k] for k in weights))
    if score < 0.15:
        grade, rec = "low", "low gap: transfer directly, light domain randomization is enough"
    elif score < 0.35:
        grade, rec = "medium", "medium gap: calibrate with system identification, then moderate domain randomization"
    elif score < 0.6:
        grade, rec = "high", "high gap: re-identify the physical parameters and check the contact model"
    else:
        grade, rec = "very_high", "very high gap: the model is probably fundamentally wrong; re-check the URDF"
    return {"score": score, "grade": grade, "recommendation": rec,
            "weights": {k: float(v) for k, v in weights.items()}, "terms": {k: float(v) for k, v in terms.items()}}


def fidelity_grade(mean_abs_position_error: float) -> str:
    if mean_abs_position_error < 0.02:
        return "high"
    if mean_abs_position_error <= 0.1:
        return "medium"
    return "low"
