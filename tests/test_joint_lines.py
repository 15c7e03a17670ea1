"""A line of model.yaml kept on some joints (``- coulomb_friction: {joints: [...]}``), and the rule that no recommended
rung raises a joint beyond the noise: a candidate that raises one is recommended on the joints it helps, or not at all
(issue 68)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from sim2real.errors import InputError
from sim2real.identification import fitting, sysid
from sim2real.identification.documents import params_document
from sim2real.identification.effects import calibration_from_params
from sim2real.identification.model_config import parse_model_config
from sysid_lab import side_ladder
from sysid_synthetic import PANDA_JOINTS, PANDA_URDF, make_run

FAST = {"fit_rate_hz": 100.0, "bootstrap_replicates": 20, "refine_max_samples": 1500}
KEPT = ["panda_joint1", "panda_joint3"]


@pytest.fixture(scope="module")
def nominal():
    return fitting.load_nominal(PANDA_URDF, PANDA_JOINTS, {"panda_joint*": 0.1}, "panda_link8")


def test_a_line_kept_on_some_joints_is_refused_where_it_cannot_be_with_the_file_and_the_fix(tmp_path, nominal):
    model = tmp_path / "model.yaml"
    refused = {
        # a link's inertia acts on every joint before it: no line keeps it on some
        "- link_inertia: {joints: [panda_joint1]}": r"model.yaml: effects/1: 'link_inertia' cannot be kept on some "
                                                    r"joints.*Fix: write '- link_inertia', without joints",
        "- payload: {joints: [panda_joint7]}": r"effects/1: 'payload' cannot be kept on some joints",
        "- base_mount: {joints: [panda_joint2]}": r"'base_mount' cannot be kept on some joints",
        "- sensor_delay: {joints: [panda_joint2]}": r"'sensor_delay' cannot be kept on some joints",
        "- coulomb_friction: {joints: []}": r"model.yaml: key .effects/1.",
        "- coulomb_friction: {joints: [panda_joint1], side: motor}": r"model.yaml: key .effects/1.",
    }
    for line, match in refused.items():
        model.write_text(f"effects:\n- rotor_inertia\n{line}\n")
        with pytest.raises(InputError, match=match):
            sysid.load_model_config(model)
    # an unknown joint: refused where the runs meet the model, before any fit
    model.write_text("effects:\n- coulomb_friction: {joints: [panda_joint1, panda_joint9]}\n")
    config = sysid.load_model_config(model)
    assert config.joints == {"coulomb_friction": ("panda_joint1", "panda_joint9")}
    runs = {"fit": [], "holdout": []}
    with pytest.raises(InputError, match=r"model.yaml: effects/0: 'coulomb_friction' is kept on panda_joint9, which no "
                                         r"run of this robot holds\. Fix: name joints among: panda_joint1, "):
        sysid.fit_model(config, nominal, runs)
    # with a side, for a drive effect
    model.write_text("effects:\n- asymmetric_friction: {joints: [panda_joint2], side: actuator}\n")
    assert sysid.load_model_config(model).sides == {"asymmetric_friction": "actuator"}


def test_a_line_kept_on_some_joints_is_fitted_there_alone_and_round_trips_to_params(nominal):
    """Coulomb friction on joints 1 and 3 of a synthetic Panda, the line kept on them: the fit holds the effect there
    alone (no parameter on the other joints, in the values, the intervals, params.yaml and the calibration), recovers
    it there, and the line goes from model.yaml through ladder.json's settings to params.yaml."""
    hidden = {"coulomb_friction": [0.5 if j in KEPT else 0.0 for j in PANDA_JOINTS]}
    fit_data, holdout = (fitting.stack_runs([make_run(f"r{s}", hidden, s, duration=10.0)], PANDA_JOINTS) for s in (1, 2))
    config = parse_model_config({"effects": [{"coulomb_friction": {"joints": KEPT}}], "fit": FAST}, "model.yaml")
    document, result = side_ladder(config.effects, nominal, fit_data, holdout, config.as_settings()["fit"],
                                   diagnosed=False)
    assert document["settings"]["fit"]["effect_joints"] == {"coulomb_friction": KEPT}
    rung = document["ladder"][-1]
    assert set(rung["params"]["coulomb_friction"]["friction"]) == set(KEPT)
    assert set(rung["intervals"]["coulomb_friction"]["friction"]) == set(KEPT)
    for joint in KEPT:
        assert rung["params"]["coulomb_friction"]["friction"][joint] == pytest.approx(0.5, rel=0.05)
    # the columns of the other joints are not fitted: their coefficients are zero, to the bit
    theta = np.asarray(result.theta["coulomb_friction"])
    others = [k for k, j in enumerate(PANDA_JOINTS) if j not in KEPT]
    assert theta.size == len(PANDA_JOINTS) and np.all(theta[others] == 0.0) and np.all(theta[[0, 2]] > 0.4)
    assert rung["metrics"]["torque_x_floor"]["overall"] < 1.1  # the hidden friction is all there is
    params = params_document([result], nominal, "tau", "panda")
    assert params["effect_joints"] == {"coulomb_friction": KEPT}
    assert set(params["effects"]["coulomb_friction"]["friction"]) == set(KEPT)
    calibration = calibration_from_params(yaml.safe_load(yaml.safe_dump(params)))
    assert {j for j, values in calibration["joints"].items() if "friction" in values} == set(KEPT)


def test_a_candidate_that_raises_a_joint_is_recommended_on_the_joints_it_helps_and_its_rung_raises_none(nominal):
    """A synthetic Panda whose joints 1-6 have Coulomb friction in every run, and whose joint 7 has it in the fit run
    only (a drive changed between the runs): fitted on every joint, coulomb_friction takes the fit run's joint 7
    friction to the holdout, where joint 7 has none, and raises it far above its floor. The report keeps the line off
    joint 7 (its add line lists the joints it helps), says why, and the rung of that line, fitted as the next round
    fits it, raises no joint and delivers what it promised."""
    friction = [0.4] * 7
    fit_data = fitting.stack_runs([make_run("fit", {"coulomb_friction": friction}, 3, duration=10.0)], PANDA_JOINTS)
    holdout = fitting.stack_runs([make_run("holdout", {"coulomb_friction": friction[:6] + [0.0]}, 4, duration=10.0)],
                                 PANDA_JOINTS)
    document, _ = side_ladder([], nominal, fit_data, holdout, FAST, candidates=["coulomb_friction", "torque_bias"])
    diagnosis = document["diagnosis"]
    best = diagnosis["candidates"][0]
    assert diagnosis["status"] == "add_effect" and best["effect"] == "coulomb_friction", diagnosis["verdict"]
    helped = PANDA_JOINTS[:6]
    assert best["kept_to"] == helped and "panda_joint7" not in best["joints"]
    assert best["add"] == f"- coulomb_friction: {{joints: [{', '.join(helped)}]}}"
    arm_wide = best["evidence"]["arm_wide_trial"]
    before, after = arm_wide["raised"]["panda_joint7"]
    assert list(arm_wide["raised"]) == ["panda_joint7"] and after > before + 1.0
    assert f"Add the line '{best['add']}'" in diagnosis["verdict"]
    assert "coulomb_friction raises panda_joint7 from" in diagnosis["verdict"]
    assert "its line keeps it on the joints it helps (panda_joint1, " in diagnosis["verdict"]
    now = document["ladder"][-1]["metrics"]["torque_x_floor"]["per_joint"]
    promised = best["evidence"]["per_joint_x_floor_after"]
    # the next round, the line as the verdict writes it
    config = parse_model_config({"effects": [{"coulomb_friction": {"joints": best["kept_to"]}}], "fit": FAST},
                                "model.yaml")
    following, _ = side_ladder(config.effects, nominal, fit_data, holdout, config.as_settings()["fit"],
                               diagnosed=False)
    delivered = following["ladder"][-1]["metrics"]["torque_x_floor"]["per_joint"]
    for joint in PANDA_JOINTS:
        assert delivered[joint] <= max(now[joint], 1.5) + 0.1, (joint, now[joint], delivered[joint])
        assert delivered[joint] == pytest.approx(promised[joint], abs=2e-3)
    assert set(following["ladder"][-1]["params"]["coulomb_friction"]["friction"]) == set(helped)


def test_gap_md_never_offers_the_line_of_a_withheld_candidate():
    """gap.md's candidate list: a candidate withheld because its trial raises a joint (no per-joint line keeps it off
    that joint) says so, with the joint and its figures, instead of a line to add; a candidate kept on the joints it
    helps offers its kept line."""
    from diagnosis_rows import evidence
    from sim2real.identification.diagnosis.result import Candidate
    from sim2real.identification.records import Side
    from sim2real.report.markdown import _diagnosis_markdown

    joints = ("panda_joint6", "panda_joint7")
    withheld = Candidate("payload", Side.BODY, (), None, 0.4, 0.6, False,
                         evidence(joints, raised={"panda_joint7": (2.64, 5.28)}), "- payload")
    kept = Candidate("coulomb_friction", Side.BODY, ("panda_joint6",), "joints", 0.3, 0.5, True, evidence(joints),
                     "- coulomb_friction: {joints: [panda_joint6]}", kept_to=("panda_joint6",))
    lines = _diagnosis_markdown({"candidates": [kept.as_document(), withheld.as_document()], "verdict": "v"})
    assert lines[0].endswith("add `- coulomb_friction: {joints: [panda_joint6]}`"), lines[0]
    assert lines[1].endswith("withheld: it raises panda_joint7 from 2.64x to 5.28x its floor"), lines[1]
    assert "- payload`" not in "\n".join(lines)


def test_the_declared_drift_kept_or_withheld_is_said_with_the_joint_it_would_raise():
    """The offsets' advice under the rule (side_ladder's declared line): kept on the joints it helps, the text gives
    that line and the joint the line for every joint raises; withheld, no line is given, and the text says why."""
    import dataclasses

    from sim2real.identification.diagnosis.ceiling_records import CeilingReading, EffectAdvice, ModelFreeCeiling
    from sim2real.report.verdicts import ceiling_text

    offset = CeilingReading(0.3, 0.29, 6.0, 5.8, 0.97, 0.02, "not_motion", True, learner="trees on the motion",
                            beyond_motion={"time": 0.1, "run": 0.6, "history": 0.0}, follows="run")
    joints = ("iiwa_joint_5", "iiwa_joint_6")
    raised = {"iiwa_joint_6": (2.097, 5.335)}
    kept = ModelFreeCeiling("trees", 0.2, dict.fromkeys(joints, 0.29), 0.85, dict.fromkeys(joints, offset),
                            declare=EffectAdvice("sensor_drift", joints, "- sensor_drift: {joints: [iiwa_joint_5]}",
                                                 kept_to=("iiwa_joint_5",), raised=raised))
    text = ceiling_text(kept, "iiwa14")
    assert "add the line '- sensor_drift: {joints: [iiwa_joint_5]}' under 'effects:' in configs/iiwa14/model.yaml" in text
    assert "Written for every joint, it raises iiwa_joint_6 from 2.10x to 5.33x its floor (" in text, text
    assert text.endswith("the line is kept on iiwa_joint_5.")
    withheld = dataclasses.replace(kept, declare=None, withheld=EffectAdvice("sensor_drift", joints, "- sensor_drift",
                                                                             raised=raised))
    text = ceiling_text(withheld, "iiwa14")
    assert "add the line" not in text and "A drift of each run's own is not advised for these runs" in text, text
    assert "iiwa_joint_6 from 2.10x" in text
