"""The promise of the candidate a diagnosis recommends: its rung, fitted as the ladder will fit it (:func:`kept_promise`).

Every candidate's trial holds the inertial prior's weight the current rung chose (:func:`sim2real.identification.
sysid.fit_ladder`): fitted at one weight, the candidates are compared on what each adds, not on how far each lets the
link inertias move. The rung the user's added line makes chooses that weight again on held-out blocks of the fit runs
(:data:`sim2real.identification.fitting.PRIOR_START_SETTING`), and the holdout can find its choice worse than the weight
the trial held: on the lab's 8 s Panda runs the Stribeck rung chose 0.001 where its trial held 0.01 (1.419 x floor
delivered against 1.393 promised), on the UR5's 0.01 where 0.001 was held (1.037 against 1.026). So the recommended
candidate's figures after (``x_floor_after``, ``per_joint_x_floor_after``, ``rmse_after``) are its rung's own: the
promise is what the rung delivers. The trial's, which the ranking and the decision read, stay beside them
(``trial_after``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from sim2real.identification.diagnosis.current import CurrentResidual
from sim2real.identification.diagnosis.result import Diagnosis
from sim2real.identification.effects.base import per_joint_dict
from sim2real.identification.records import Status

def promised_effect(diagnosis: Diagnosis | None) -> str | None:
    """The candidate whose rung a diagnosis promises (the one it recommends), or None when it recommends none."""
    if diagnosis is None or diagnosis.status != Status.ADD_EFFECT or not diagnosis.candidates:
        return None
    return diagnosis.candidates[0].effect


def kept_promise(diagnosis: Diagnosis, rung_residual: np.ndarray, noise_floor: np.ndarray,
                 rung_prior: float | None) -> Diagnosis:
    """``diagnosis`` with its recommended candidate's figures after taken from its rung's holdout residual
    ``rung_residual`` (judged minus predicted torque; ``noise_floor``: the holdout runs'), the trial's kept under
    ``trial_after`` with the prior weight each was fitted at (``rung_prior``: the rung's choice, None without one)."""
    best = diagnosis.candidates[0]
    joints = list(diagnosis.joints)
    after = CurrentResidual.of(np.asarray(rung_residual, dtype=float), noise_floor)
    trial = best.evidence
    evidence = dataclasses.replace(
        trial, trial_after={"x_floor_after": trial.x_floor_after,
                            "per_joint_x_floor_after": dict(trial.per_joint_x_floor_after),
                            "rmse_after": trial.rmse_after},
        x_floor_after=round(after.ratio, 4), per_joint_x_floor_after=per_joint_dict(joints, after.x_floor, 3),
        rmse_after=round(after.rmse, 6), rung_inertia_prior=None if rung_prior is None else float(rung_prior))
    return dataclasses.replace(diagnosis, candidates=(dataclasses.replace(best, evidence=evidence),
                                                      *diagnosis.candidates[1:]))
