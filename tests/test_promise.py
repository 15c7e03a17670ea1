"""The recommended candidate promises what its rung delivers (sim2real.identification.diagnosis.promise): its figures
after are its rung's own, its trial's kept beside them; the other candidates keep their trials' figures.

The loops that follow the diagnosis (tests/test_consistent_fit.py, tests/test_lab.py) check the same on fitted rungs:
where the rung chooses the inertial prior's weight again, the promise is the rung's fit to the last printed digit.
"""

from __future__ import annotations

import re

import numpy as np

from diagnosis_rows import evidence
from sim2real.identification.diagnosis import Candidate, Diagnosis
from sim2real.identification.diagnosis.promise import kept_promise, promised_effect
from sim2real.identification.records import Side, Status

JOINTS = ("j1", "j2")


def diagnosis(status: Status) -> Diagnosis:
    def candidate(effect: str, after: float) -> Candidate:
        return Candidate(effect=effect, side=Side.BODY, joints=JOINTS, decided_on="arm", explained=0.5,
                         explained_beyond_noise=0.6, decisive=True, add=f"- {effect}",
                         evidence=evidence(JOINTS, x_floor_after=after,
                                           per_joint_x_floor_after={"j1": after, "j2": after}, rmse_after=0.1 * after))

    return Diagnosis(side=Side.BODY, status=status, candidates=(candidate("stribeck_friction", 1.393),
                                                                candidate("rotor_inertia", 1.396)),
                     confounded=(), tied=(), residual_rmse=0.2, noise_floor_ratio=1.59, noise_rmse=0.1,
                     noise_floor_factor=1.5, min_explained=0.3, per_joint={}, above_floor=JOINTS, joints=JOINTS)


def test_the_recommended_candidate_promises_its_rungs_figures_and_keeps_its_trials():
    floor = np.array([0.1, 0.2])
    rng = np.random.default_rng(3)
    residual = rng.normal(size=(4000, 2)) * floor * np.array([1.3, 1.5])  # the rung: 1.3x and 1.5x the floors
    before = diagnosis(Status.ADD_EFFECT)
    assert promised_effect(before) == "stribeck_friction"
    after = kept_promise(before, residual, floor, 0.001)
    best, other = after.candidates
    x = np.sqrt(np.mean((residual / floor) ** 2, axis=0))
    assert best.evidence.per_joint_x_floor_after == {"j1": round(x[0], 3), "j2": round(x[1], 3)}
    assert best.evidence.x_floor_after == round(float(np.sqrt(np.mean(x**2))), 4)
    assert abs(best.evidence.x_floor_after - 1.40) < 0.03
    assert best.evidence.rmse_after == round(float(np.sqrt(np.mean(residual**2))), 6)
    trial = before.candidates[0].evidence
    assert best.evidence.trial_after == {"x_floor_after": trial.x_floor_after, "rmse_after": trial.rmse_after,
                                         "per_joint_x_floor_after": dict(trial.per_joint_x_floor_after)}
    assert best.evidence.rung_inertia_prior == 0.001
    # the document round-trips with both
    assert type(best.evidence).from_document(best.evidence.as_document()) == best.evidence
    assert other == before.candidates[1] and before.candidates[0].evidence.x_floor_after == 1.393  # none changed
    assert promised_effect(diagnosis(Status.AT_NOISE_FLOOR)) is None and promised_effect(None) is None


def test_a_rung_whose_weight_chosen_again_raises_a_joint_holds_the_previous_rungs(shared_lab):
    """The Panda's real_arm_like_smoothed_200hz (its torque low-passed at 20 Hz before a 200 Hz log): the Stribeck
    rung's cross-validation chooses the prior weight 0.01 where the rung before held 1, and at 0.01 the holdout finds
    panda_joint3 raised beyond the noise (4.39x -> 5.03x its floor). The rung holds the previous rung's weight, says
    why, and then leaves panda_joint3 lower than the weight chosen again did: what the diagnosis's trial promised."""
    scenario = "real_arm_like_smoothed_200hz"
    effects = ["link_inertia", "asymmetric_friction", "sensor_delay", "stribeck_friction"]
    ladder = shared_lab.ladder(scenario, effects, diagnose=False)["ladder"]
    before, held = (rung["consistency"]["inertia_prior"] for rung in ladder[-2:])
    assert held["weight"] == before["weight"], (before, held)
    said = held["chosen_by"]
    assert said.startswith("holding the previous rung's: cross-validation on "), said
    raised = re.search(r"chose ([0-9.e-]+), which raised panda_joint3 from ([0-9.]+)x to ([0-9.]+)x its floor", said)
    assert raised is not None and float(raised.group(1)) != held["weight"], said
    now = ladder[-1]["metrics"]["torque_x_floor"]["per_joint"]["panda_joint3"]
    assert now < float(raised.group(3)), (now, said)
