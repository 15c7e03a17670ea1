"""Diagnosis: which physical effect is the model missing?

On the holdout residual of the last rung, every effect of the library not yet in the model is
tried: it is added to the model, the model is refitted on the fit runs, and its holdout residual
is compared with the current one. ``explained`` is the fraction of the current holdout residual
energy the candidate removes (1 - SSE_after / SSE_now, clipped to 0..1); because it is measured
on runs the fit never saw, an effect that only soaks up noise explains nothing.

Each candidate also carries its residual signature (:meth:`sim2real.effects.base.Effect.evidence`
on the current holdout residual), the joints it acts on (those where it removes a good share of
that joint's residual), its fitted values and ``add``, the line to add to configs/{robot}/model.yaml.

When no candidate explains enough, the verdict says so instead of forcing a label:
``at_noise_floor`` when the residual is already within ``noise_floor_factor`` of the noise floor,
``unexplained`` otherwise. The diagnosis never looks at the lab's truth.yaml: it sees only runs.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim2real.effects import EFFECTS
from sim2real.effects.base import Signals, per_joint_dict

DEFAULT_DIAGNOSIS: dict[str, float] = {
    "min_explained": 0.3,  # a candidate must remove this share of the holdout residual energy
    "joint_min_explained": 0.2,  # ... and this share of a joint's residual to name that joint
    "noise_floor_factor": 1.5,  # residual RMS within this factor of the noise floor: nothing to add
    "parsimony": 1.05,  # a simpler candidate within this factor of the best holdout RMSE ranks first
}


def add_line(effect: str) -> str:
    """The exact line to add under ``effects:`` in configs/{robot}/model.yaml."""
    return f"- {effect}"


def _sse(residual: np.ndarray) -> np.ndarray:
    return np.sum(residual**2, axis=0)


def _rank(candidates: list[dict[str, Any]], parsimony: float) -> list[dict[str, Any]]:
    """By explained share; then the simplest candidate that does about as well as the best goes first.

    Effects nest (a payload is a change of the last link's inertia; link_inertia holds it): the
    bigger one always explains a little more, the smaller one is the better name for what is missing.
    """
    ranked = sorted(candidates, key=lambda c: (-c["explained"], c["effect"]))
    if not ranked:
        return ranked
    limit = parsimony * ranked[0]["evidence"]["rmse_after"]
    close = [c for c in ranked if c["evidence"]["rmse_after"] <= limit]
    simplest = min(close, key=lambda c: (c["evidence"]["parameters"], -c["explained"], c["effect"]))
    return [simplest] + [c for c in ranked if c is not simplest]


def diagnose(
    model_effects: Sequence[str],
    nominal: Any,
    fit_data: Any,
    holdout_data: Any,
    holdout_residual: np.ndarray,
    settings: Mapping[str, Any] | None = None,
    fit_signals: Signals | None = None,
    holdout_signals: Signals | None = None,
    robot: str = "{robot}",
    nonlinear_fixed: Mapping[str, np.ndarray] | None = None,
) -> dict[str, Any]:
    """Rank every effect not in ``model_effects`` by the holdout residual it removes.

    ``nominal``, ``fit_data``, ``holdout_data`` are :mod:`sim2real.sysid` objects; the residual is the
    current model's holdout residual (judged minus predicted torque). ``nonlinear_fixed``: the
    current model's nonlinear parameters, held while a candidate is tried (only its own are refined).
    """
    from sim2real import sysid  # the fit lives there; imported here to keep the modules acyclic

    settings = dict(settings or {})
    limits = {**DEFAULT_DIAGNOSIS, **settings.get("diagnosis", {})}
    fit_signals = fit_signals or sysid.make_signals(nominal, fit_data)
    holdout_signals = holdout_signals or sysid.make_signals(nominal, holdout_data)
    joints = list(holdout_data.joint_names)
    sse_now = _sse(holdout_residual)
    total_now = float(sse_now.sum())
    rmse_now = float(np.sqrt(np.mean(holdout_residual**2)))
    noise = float(np.sqrt(np.mean(np.asarray(holdout_data.noise_floor) ** 2)))
    candidates, skipped = [], []
    for name, effect in EFFECTS.items():
        if name in model_effects:
            continue
        if effect.needs_commands and holdout_data.torque_source != "tau_cmd":
            skipped.append({
                "effect": name,
                "reason": "the judged torque is measured by a sensor (tau), which a command delay does not "
                "change; it needs runs with only tau_cmd, or the state-domain replay",
            })
            continue
        result = sysid.fit([*model_effects, name], nominal, fit_data, settings.get("fit"), signals=fit_signals,
                           uncertainty=False, consistency=False, nonlinear_fixed=nonlinear_fixed)
        _, residual = sysid.holdout_metrics(result, nominal, holdout_data, holdout_signals)
        sse_after = _sse(residual)
        explained = float(np.clip(1.0 - sse_after.sum() / total_now, 0.0, 1.0)) if total_now > 0 else 0.0
        with np.errstate(invalid="ignore", divide="ignore"):
            per_joint = np.clip(np.where(sse_now > 0, 1.0 - sse_after / sse_now, 0.0), 0.0, 1.0)
        acting = [j for j, v in zip(joints, per_joint, strict=True) if v >= limits["joint_min_explained"]]
        evidence = effect.evidence(holdout_residual, holdout_signals)
        evidence["per_joint_explained"] = per_joint_dict(joints, per_joint, 3)
        evidence["rmse_after"] = round(float(np.sqrt(np.mean(residual**2))), 6)
        evidence["fitted"] = result.values[name]
        evidence["parameters"] = int(len(result.theta.get(name, [])) + len(result.nonlinear.get(name, [])))
        candidates.append({
            "effect": name,
            "joints": acting if explained >= limits["min_explained"] else [],
            "explained": round(explained, 4),
            "evidence": evidence,
            "add": add_line(name),
        })
    candidates = _rank(candidates, float(limits["parsimony"]))
    best = candidates[0] if candidates else None
    ratio = rmse_now / noise if noise > 0 else float("inf")
    if best is not None and best["explained"] >= limits["min_explained"]:
        status = "add_effect"
        joint_text = f" on {', '.join(best['joints'])}" if best["joints"] else ""
        verdict = (
            f"The model is missing {best['effect']}{joint_text}: it explains {best['explained']:.0%} of the holdout "
            f"residual. Add the line '{best['add']}' under 'effects:' in configs/{robot}/model.yaml."
        )
    elif ratio <= limits["noise_floor_factor"]:
        status = "at_noise_floor"
        verdict = (
            f"Nothing to add: the holdout residual ({rmse_now:.3g} N*m) is within {limits['noise_floor_factor']}x "
            f"the noise floor ({noise:.3g} N*m) and no effect explains more than {limits['min_explained']:.0%} of it."
        )
    else:
        status = "unexplained"
        verdict = (
            f"No effect in the library explains the residual: it is {ratio:.1f}x the noise floor, but the best "
            f"candidate ({best['effect'] if best else 'none'}) removes only "
            f"{best['explained'] if best else 0:.0%} of it. Look at the worst windows in the gap report."
        )
    return {
        "candidates": candidates,
        "verdict": verdict,
        "status": status,
        "residual_rmse": round(rmse_now, 6),
        "noise_floor_ratio": round(ratio, 4) if np.isfinite(ratio) else None,
        "skipped": skipped,
    }
