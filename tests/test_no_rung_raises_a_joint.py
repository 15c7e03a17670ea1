"""No rung raises a joint (sim2real.identification.diagnosis.raises): a candidate that lowers the arm as a whole but
raises one joint beyond the noise is set aside, the ranking and the line to add go to the best candidate that raises
none, and the verdict says which joints the set-aside one lowers and which it raises."""

from __future__ import annotations

import numpy as np
import pytest

from sysid_synthetic import PANDA_JOINTS, PANDA_URDF, make_run
from sim2real.identification import fitting
from sim2real.identification.diagnosis import diagnose
from sim2real.identification.diagnosis.current import CurrentResidual
from sim2real.identification.diagnosis.raises import raised_joints
from sim2real.identification.records import NoteKind, Status
from sim2real.report.verdicts import verdict

FRICTION = [0.34] * 6 + [0.0]


@pytest.fixture(scope="module")
def offsets_diagnosis():
    """A Panda whose joints 1-6 hide a Coulomb friction, and whose torque sensors start each run with an offset of
    their own: 0.4 N m on joints 1-6 in both runs, but on joint 7 only in the fit run. A torque bias fitted on the fit
    run removes more of the arm's residual than the friction does, and puts 0.4 N m on joint 7's, at its floor."""
    nominal = fitting.load_nominal(PANDA_URDF, PANDA_JOINTS, {"panda_joint*": 0.1}, "panda_link8")
    runs = []
    for name, seed, last in (("fit", 3, 0.4), ("holdout", 4, 0.0)):
        hidden = {"coulomb_friction": FRICTION, "torque_bias": [0.4] * 6 + [last]}
        runs.append(fitting.stack_runs([make_run(name, hidden, seed, duration=6.0, noise=0.01)], PANDA_JOINTS, 100.0))
    fit_data, holdout_data = runs
    settings = {**fitting.DEFAULT_SETTINGS, "fit_rate_hz": 100.0, "bootstrap_replicates": 0, "refine_max_samples": 1500}
    context = fitting.FitContext.on_nominal(nominal, fit_data, holdout_data, settings)
    current = fitting.fit([], nominal, fit_data, settings, uncertainty=False)
    residual = holdout_data.tau - fitting.predict(current, nominal, holdout_data)
    return diagnose([], context, residual, current=current, candidates=["torque_bias", "coulomb_friction"])


def test_the_best_arm_wide_candidate_that_raises_a_joint_is_kept_off_it(offsets_diagnosis):
    diagnosis = offsets_diagnosis
    bias = diagnosis.candidate("torque_bias")
    friction = diagnosis.candidate("coulomb_friction")
    # torque_bias removes more of the arm's residual than the friction, yet raises joint 7 far beyond its floor
    assert bias.explained > friction.explained
    assert set(bias.evidence["raised_joints"]) == {"panda_joint7"} and not bias.decisive
    raised = bias.evidence["raised_joints"]["panda_joint7"]
    assert raised["to"] > raised["from"] + 10
    # the ranking and the line to add go to the candidate that raises no joint
    assert diagnosis.status == Status.ADD_EFFECT and diagnosis.best.effect == "coulomb_friction"
    assert "raised_joints" not in friction.evidence
    text = verdict(diagnosis, "panda")
    assert "Add the line '- coulomb_friction'" in text and "Add the line '- torque_bias'" not in text
    note = next(n for n in diagnosis.notes if n.kind == NoteKind.RAISES_JOINTS)
    assert note.effect == "torque_bias" and set(note.figures["raises"]) == {"panda_joint7"}
    assert set(note.figures["lowers"]) == set(PANDA_JOINTS[:6])
    assert "torque_bias lowers panda_joint1" in text and "but raises panda_joint7" in text
    assert "so it is not recommended" in text


def test_a_rise_within_the_noise_is_no_raise():
    rng = np.random.default_rng(5)
    now = CurrentResidual.of(rng.standard_normal((2000, 2)) * np.array([0.1, 0.1]), np.array([0.1, 0.1]))
    scaled_now = now.scaled
    # a tenth of a floor more on joint 1, twice the residual on joint 2
    after = np.column_stack([scaled_now[:, 0] * 1.05, scaled_now[:, 1] * 2.0])
    assert set(raised_joints(after, now, ["a", "b"])) == {"b"}
