"""The actuator link (issue 10): with a torque sensor beside the command, the actuator is judged apart.

Lab runs log the measured torque (tau) and the command (tau_cmd) with one effect hidden between them
(a delay, motor gains off, a command bias). The actuator link (tau against tau_cmd) must name it and
fall to its noise floor once it is added; the body link (tau against the motion) must not change its
verdict. Without the tau columns the report must say what the commands alone can still tell.
"""

from __future__ import annotations

import pytest

from sysid_lab import Lab, model_config, overall

from sim2real.report.figures import FIGURES

ACTUATOR_SCENARIOS = {
    "sensor_actuation_delay": "actuation_delay",
    "actuator_gain": "actuator_gain",
    "command_bias": "command_bias",
}


@pytest.fixture(scope="module")
def lab(shared_lab: Lab) -> Lab:
    """The suite's lab (conftest): runs made once, scenarios followed once."""
    return shared_lab


def floor(section: dict) -> float:
    return float(section["noise_floor"]["torque_rmse"]["overall"])


@pytest.mark.parametrize("scenario", sorted(ACTUATOR_SCENARIOS))
def test_a_hidden_actuator_effect_is_named_on_the_actuator_link_and_the_body_verdict_is_unchanged(lab, scenario):
    hidden = ACTUATOR_SCENARIOS[scenario]
    clean = lab.model("clean", [])
    document = lab.model(scenario, [])
    assert document["links"]["mode"] == "separate"
    diagnosis = document["actuator"]["diagnosis"]
    assert diagnosis["status"] == "add_effect", diagnosis["verdict"]
    top = diagnosis["candidates"][0]
    assert (top["effect"], top["link"]) == (hidden, "actuator")
    assert "actuator link" in diagnosis["verdict"] and hidden in diagnosis["verdict"]
    # The body link sees the applied torque: the hidden effect is not its business.
    assert document["diagnosis"]["status"] == clean["diagnosis"]["status"] == "at_noise_floor"
    assert not {c["effect"] for c in document["diagnosis"]["candidates"]} & set(ACTUATOR_SCENARIOS.values())

    after = lab.model(scenario, [hidden])
    link = after["actuator"]
    assert link["ladder"][-1]["effects"] == [hidden]
    assert overall(link["ladder"][-1]) <= 1.5 * floor(link), (overall(link["ladder"][-1]), floor(link))
    assert link["diagnosis"]["status"] == "at_noise_floor", link["diagnosis"]["verdict"]
    assert after["diagnosis"]["status"] == "at_noise_floor"
    # What the lab hid (configs/panda/lab.yaml), recovered from tau and tau_cmd alone.
    values = link["ladder"][-1]["params"][hidden]
    if hidden == "actuation_delay":
        assert values["delay"] == pytest.approx(0.006, abs=0.5e-3)
        lo, hi = after["actuator"]["ladder"][-1]["intervals"]["actuation_delay"]["delay"]
        assert lo <= 0.006 <= hi and hi - lo < 0.5e-3  # every sample at 1 kHz: the interval holds the truth
    elif hidden == "actuator_gain":
        assert values["gain"]["panda_joint2"] == pytest.approx(0.88, rel=0.01)
        assert values["gain"]["panda_joint5"] == pytest.approx(1.12, rel=0.01)
    else:
        assert values["bias"]["panda_joint2"] == pytest.approx(-0.5, abs=0.02)


def test_a_long_logs_delay_is_refined_on_windows_at_the_logs_own_step(lab, monkeypatch):
    """Beyond refine_max_samples the actuator link refines on windows spread over the runs (its memory stays
    put however long the log): the delay of a few samples is found as on every sample, and the link falls to
    its floor. The cap is lowered here so that the lab's short runs exceed it."""
    from sim2real.identification import sides

    monkeypatch.setattr(sides, "DRIVE_FIT_SETTINGS",
                        {**sides.DRIVE_FIT_SETTINGS, "refine_max_samples": 4000, "refine_windows_s": 1.0})
    link = lab.model("sensor_actuation_delay", ["actuation_delay"])["actuator"]
    delay = link["ladder"][-1]["params"]["actuation_delay"]["delay"]
    assert delay == pytest.approx(0.006, abs=0.5e-3)
    assert overall(link["ladder"][-1]) <= 1.5 * floor(link), (overall(link["ladder"][-1]), floor(link))


@pytest.mark.parametrize("scenario", sorted(ACTUATOR_SCENARIOS))
def test_without_the_sensor_the_report_says_what_the_commands_can_still_tell(lab, scenario):
    hidden = ACTUATOR_SCENARIOS[scenario]
    document = lab.model(scenario, [], with_sensor=False)
    links = document["links"]
    assert links["mode"] == "commands_only" and "actuator" not in document
    assert document["diagnosis"]["link"] == "combined"
    assert document["diagnosis"]["candidates"][0]["effect"] == hidden, document["diagnosis"]["verdict"]
    if hidden == "actuation_delay":  # against the motion a filter of the same lag is a tie: said, the delay named
        assert "cannot tell it from actuation_lag: two shapes of the same lag" in document["diagnosis"]["verdict"]
    told = {effect for fact in links["can_tell"] for effect in fact["effects"]}
    untold = {effect for fact in links["cannot_tell"] for effect in fact["effects"]}
    assert {"actuation_delay", "command_bias"} <= told
    assert {"actuator_gain", "link_inertia"} <= untold  # a common motor gain is the body scaled
    assert {"torque_gain", "torque_bias"} <= {s["effect"] for s in document["diagnosis"]["skipped"]}


def test_friction_and_a_delay_hidden_together_are_both_found_within_two_rounds(lab):
    documents = lab.follow("sensor_delay_and_friction")
    assert len(documents) <= 3, [d["diagnosis"]["verdict"] for d in documents]
    first = documents[0]
    assert first["diagnosis"]["candidates"][0]["effect"] == "coulomb_friction"
    assert first["actuator"]["diagnosis"]["candidates"][0]["effect"] == "actuation_delay"
    last = documents[-1]
    assert {"coulomb_friction", "actuation_delay"} <= set(last["ladder"][-1]["effects"] + last["actuator"]["ladder"][-1]["effects"])
    assert overall(last["actuator"]["ladder"][-1]) <= 1.5 * floor(last["actuator"])
    assert overall(last["ladder"][-1]) <= 1.5 * floor(last)


def test_on_an_arm_like_a_real_one_both_links_reach_their_noise_floor(lab):
    """Inertias off, a heavier hand, wrong armature, Gaz friction, stamp jitter, plus a delay and motor gains."""
    documents = lab.follow("real_arm_like_actuator")
    last = documents[-1]
    for section in (last, last["actuator"]):
        assert section["diagnosis"]["status"] == "at_noise_floor", section["diagnosis"]["verdict"]
        rmse = [overall(rung) for rung in section["ladder"]]
        assert rmse == sorted(rmse, reverse=True), rmse
        assert rmse[-1] <= 1.5 * floor(section), (rmse, floor(section))
    assert set(last["actuator"]["ladder"][-1]["effects"]) == {"actuation_delay", "actuator_gain"}
    # The body link finds what real_arm_like alone needs first: the actuator effects do not leak into it.
    assert documents[0]["diagnosis"]["candidates"][0]["effect"] == lab.model("real_arm_like", [])["diagnosis"]["candidates"][0]["effect"]


DRIVE = {"rotor_inertia", "coulomb_friction", "viscous_friction"}


def test_behind_a_link_side_sensor_the_drive_is_found_on_the_actuator_link(lab, tmp_path):
    """real_arm_like measured after the gearbox (the Panda's tau_J): rotor inertia and joint friction lie
    between the command and tau. The loop finds them on the actuator link, the body needs its inertias
    only, both links reach their floors, and the armature comes back as the lab hid it."""
    import json

    import yaml

    from sim2real.report.gap import GapInputs, build_gap_report

    documents = lab.follow("link_side_sensor")  # as tests/test_trustworthy_loop.py: followed once
    first, last = documents[0], documents[-1]
    assert first["links"]["torque_sensor"] == "link"
    assert first["diagnosis"]["candidates"][0]["effect"] == "link_inertia"
    # The sensor's position is a prior, not a veto: the body tries the drive's effects against the motion too.
    assert {"rotor_inertia", "coulomb_friction", "viscous_friction"} <= {c["effect"] for c in first["diagnosis"]["candidates"]}
    top = first["actuator"]["diagnosis"]["candidates"][0]
    assert "friction" in top["effect"] and top["link"] == "actuator", first["actuator"]["diagnosis"]["verdict"]
    actuator_effects = set(last["actuator"]["ladder"][-1]["effects"])
    assert "rotor_inertia" in actuator_effects and any("friction" in e for e in actuator_effects), actuator_effects
    for section in (last, last["actuator"]):
        assert section["diagnosis"]["status"] == "at_noise_floor", section["diagnosis"]["verdict"]
        rmse = [overall(rung) for rung in section["ladder"]]
        # A rung the actuator link asked for (rotor inertia, its friction) is fitted after the sensor on the body
        # too, from zero: there it may cost a hair of noise, never more than a twentieth of the floor.
        assert all(b <= a + 0.05 * floor(section) for a, b in zip(rmse, rmse[1:], strict=False)), rmse
        assert rmse[-1] <= 1.5 * floor(section), (rmse, floor(section))
    hidden = yaml.safe_load(lab.lab_config.read_text(encoding="utf-8"))["scenarios"]["link_side_sensor"]["effects"]
    armature = last["actuator"]["ladder"][-1]["params"]["rotor_inertia"]["armature"]
    for joint, truth in zip(lab.nominal.joint_names, hidden["rotor_inertia"]["armature"], strict=True):
        assert armature[joint] == pytest.approx(truth, rel=0.15), (joint, armature[joint], truth)

    # gap.md says which sensor it assumed, and replays the drive on the actuator link.
    listing = lab.measurement_list("link_side_sensor")
    out = tmp_path / "gap"
    out.mkdir()
    (out / "ladder.json").write_text(json.dumps(last), encoding="utf-8")
    figures = {k: out / f"{k}.png" for k in FIGURES}
    gap = build_gap_report(GapInputs("panda", lab.urdf, lab.mjcf, listing, root="/", ladder=out / "ladder.json"),
                           out / "gap.json", out / "gap.md", figures)
    assert gap["links"]["torque_sensor"] == "link"
    markdown = (out / "gap.md").read_text(encoding="utf-8")
    assert "The torque sensor is link-side" in markdown
    # Each joint in N*m and in its own floor's units; the inertial prior's weight and how it was chosen.
    assert "| joint | RMSE [N m] | noise floor [N m] | x floor |" in markdown
    assert "The inertial prior (the entropic pull of every link towards its CAD inertials) has weight" in markdown
    assert "chosen by cross-validation on 4 held-out blocks of the fit runs" in markdown
    replayed = [rung["metrics"]["position_rmse"]["overall"] for rung in gap["actuator"]["ladder"]]
    assert replayed[-1] < replayed[0], replayed  # the drive's effects move the replayed arm too


def test_gap_report_shows_each_link_and_the_replay_falls_when_the_delay_is_added(lab, tmp_path):
    import json

    from sim2real.report.gap import GapInputs, build_gap_report

    def report(scenario, effects, name, with_sensor=True):
        listing = lab.measurement_list(scenario) if with_sensor else lab.without_sensor(scenario)
        document = lab.model(scenario, effects, with_sensor=with_sensor)  # as the tests above fitted it
        out = tmp_path / name
        out.mkdir()
        (out / "ladder.json").write_text(json.dumps(document), encoding="utf-8")
        figures = {k: out / f"{k}.png" for k in FIGURES}
        inputs = GapInputs("panda", lab.urdf, lab.mjcf, listing, root="/", ladder=out / "ladder.json")
        gap = build_gap_report(inputs, out / "gap.json", out / "gap.md", figures)
        return gap, (out / "gap.md").read_text(encoding="utf-8")

    gap, markdown = report("sensor_actuation_delay", ["actuation_delay"], "sensor")
    nominal, delayed = (rung["metrics"]["position_rmse"]["overall"] for rung in gap["actuator"]["ladder"])
    assert delayed < 0.5 * nominal, (nominal, delayed)  # the state domain sees the delay too
    assert "## Actuator link (measured against commanded torque)" in markdown
    assert gap["actuator"]["diagnosis"]["verdict"] in markdown and gap["diagnosis"]["verdict"] in markdown

    gap, markdown = report("actuator_gain", [], "commands", with_sensor=False)
    assert gap["links"]["mode"] == "commands_only" and "actuator" not in gap
    assert "## What these runs can tell apart" in markdown
    assert "**Not told apart:** `actuator_gain`, `link_inertia`" in markdown


def test_the_calibrated_mjcf_carries_the_actuator_effects(lab):
    from sim2real.identification import sysid
    from sim2real.identification.effects import apply_to_spec
    from sim2real.assets.arm import arm_spec

    runs = lab.prepared(lab.measurement_list("actuator_gain"))
    fitted = sysid.fit_model(model_config(["actuator_gain", "actuation_delay", "command_bias"]), lab.nominal, runs,
                             "panda")
    document, results = fitted.document, fitted.results
    params = sysid.params_document(results, lab.nominal, document["torque_source"], "panda")
    assert set(params["effects"]) == {"actuation_delay", "actuator_gain", "command_bias"}
    spec = arm_spec(lab.mjcf, lab.nominal.joint_names)  # the dev MJCF driven by joint torque motors
    apply_to_spec(spec, params)
    model = spec.compile()
    assert model.actuator_delay[model.actuator("motor_panda_joint1").id] == pytest.approx(
        params["effects"]["actuation_delay"]["delay"])
    motor = model.actuator("motor_panda_joint2").id
    assert model.actuator_gainprm[motor, 0] == pytest.approx(params["effects"]["actuator_gain"]["gain"]["panda_joint2"])
    assert model.actuator_gainprm[motor, 0] == pytest.approx(0.88, rel=0.01)
    bias = params["effects"]["command_bias"]["bias"]["panda_joint2"]
    assert model.actuator_biasprm[motor, 0] == pytest.approx(bias) and abs(bias) < 0.05  # none hidden


def typed(document: dict, side: str):
    """A diagnosis as data (:class:`sim2real.identification.diagnosis.Diagnosis`) from the few fields a test gives:
    its status, candidates and per-joint rows (the rest of each row: a plain trial's, no candidate closest)."""
    from diagnosis_rows import evidence_document
    from sim2real.identification.diagnosis import Diagnosis

    candidates = [{"link": side, "joints": [], "explained_beyond_noise": c["explained"], "add": f"- {c['effect']}",
                   **c, "evidence": {**evidence_document(), **c.get("evidence", {})}} for c in document.get("candidates", [])]
    return Diagnosis.from_document({
        "link": side, "status": document["status"], "candidates": candidates, "confounded": [], "tied": [],
        "residual_rmse": 0.1, "noise_floor_ratio": 1.0, "noise_rmse": 0.1, "noise_floor_factor": 1.5,
        "min_explained": 0.3, "above_floor": [], "skipped": [],
        "per_joint": {j: {"closest": None, "closest_explained_beyond_noise": 0.0, "closest_x_floor_after": row["x_floor"],
                          **row} for j, row in document.get("per_joint", {}).items()},
        "failed": [], "notes": []})


def note_text(note) -> str:
    from sim2real.report.verdicts import NOTE_TEXT

    return NOTE_TEXT[note.kind](note, "panda").strip()


def test_an_actuation_delay_is_called_the_sensors_lag_only_where_the_body_link_finds_the_same_lag():
    """The actuator link judges the sensor's reading against the command: a lagging sensor looks like an actuation
    delay there. Its verdict says the lag is the sensor's where the body link's trial of sensor_delay finds the same
    lag (within 0.5x-1.5x) above the body's noise (a UR5 whose currents lag 8 ms, 20 s runs: 7.5 ms against the
    actuator link's 7 ms, 45 % of what lies above the floor); never on another lag, nor on one lost in the noise."""
    from types import SimpleNamespace

    from sim2real.identification.diagnosis.across import sensor_lag
    from sim2real.report.verdicts import verdict

    actuator = SimpleNamespace(effects=["actuation_delay"], values={"actuation_delay": {"delay": 0.007}})
    body = SimpleNamespace(effects=["link_inertia", "coulomb_friction"], values={})
    calm = typed({"status": "at_noise_floor"}, "actuator")

    def noted(delay: float, share: float) -> str | None:
        trial = {"effect": "sensor_delay", "explained": share, "explained_beyond_noise": share, "decisive": False,
                 "evidence": {"fitted": {"delay": delay}, "x_floor_after": 1.2}}
        note = sensor_lag(calm, actuator, body, typed({"status": "at_noise_floor", "candidates": [trial]}, "body"))
        if note is None:
            return None
        assert verdict(calm.with_notes(note), "panda") == verdict(calm, "panda") + " " + note_text(note)
        return note_text(note)

    note = noted(0.0075, 0.45)
    assert note is not None and "7.5 ms" in note and "the lag is the sensor's" in note and "- sensor_delay" in note
    assert noted(0.035, 0.45) is None  # another lag than the actuator link's
    assert noted(0.0075, 0.05) is None  # within the body's noise
    assert noted(0.0, 0.0) is None

    def named_shape(filter_after: float) -> str:
        """The line the note asks for when the body link tried both shapes of the sensor's lag."""
        trials = [{"effect": "sensor_delay", "explained": 0.45, "explained_beyond_noise": 0.45, "decisive": False,
                   "evidence": {"fitted": {"delay": 0.0075}, "x_floor_after": 1.2}},
                  {"effect": "sensor_lag", "explained": 0.5, "explained_beyond_noise": 0.5, "decisive": False,
                   "evidence": {"fitted": {"time_constant": 0.0077}, "x_floor_after": filter_after}}]
        note = sensor_lag(calm, actuator, body, typed({"status": "at_noise_floor", "candidates": trials}, "body"))
        return "sensor_lag" if "- sensor_lag" in note_text(note) else "sensor_delay"

    assert named_shape(1.15) == "sensor_delay"  # no better than the data can tell: the plainer shape
    assert named_shape(1.0) == "sensor_lag"  # clearly better: the filter
    with_it = SimpleNamespace(effects=["link_inertia", "sensor_delay"], values={"sensor_delay": {"delay": 0.0046}})
    note = sensor_lag(typed({"status": "unexplained"}, "actuator"), actuator, with_it, None)
    assert "4.6 ms behind the motion (sensor_delay)" in note_text(note) and "filter" in note_text(note)


def test_a_line_one_link_names_says_what_its_trial_does_on_the_other_link():
    """Behind a link-side sensor a drive's friction sits on both links: a line the actuator link names is fitted on
    the body link too. Where the body link's own trial of it leaves a joint worse than now (above the floor factor,
    or by more than the harm tolerance) and it asks for nothing itself, the actuator link's verdict says so. The
    diagnoses are the loop's own, on the lab's real_panda_log (20 s runs, round 8 of
    benchmarks/bench_real_arm_loop.py): the actuator link names
    asymmetric_friction, which the body link's trial finds explains nothing there and takes panda_joint2 from 1.46x
    to 1.51x its floor, where the next round indeed put it."""
    import copy
    import json
    from pathlib import Path

    from sim2real.identification.diagnosis.across import other_side

    data = json.loads((Path(__file__).parent / "data" / "real_panda_log_round8_diagnoses.json").read_text())
    actuator, body = typed(data["actuator"], "actuator"), typed(data["body"], "body")
    assert note_text(other_side(actuator, body, "link")) == (
        "The line sits on the body link too, where its trial explains nothing and leaves panda_joint2 at 1.51x its "
        "floor (1.46x now). To keep it off the body link, write the line as '- asymmetric_friction: actuator'.")
    # at its floor the body link names nothing, so it has nothing to say of the other link
    assert other_side(body, actuator, "link") is None

    calm = copy.deepcopy(data["body"])  # a trial that leaves every joint where it is: nothing to say
    for candidate in calm["candidates"]:
        candidate["evidence"]["per_joint_x_floor_after"] = {j: row["x_floor"] for j, row in calm["per_joint"].items()}
    assert other_side(actuator, typed(calm, "body"), "link") is None

    asking = copy.deepcopy(data["body"])  # the other link names a line of its own: its next rung is not this trial
    asking["status"] = "add_effect"
    assert other_side(actuator, typed(asking, "body"), "link") is None

    lag = copy.deepcopy(data["actuator"])  # a line the other link does not fit (an actuation lag): whatever its numbers
    lag["candidates"][0]["effect"] = "actuation_lag"
    harmed = copy.deepcopy(data["body"])
    harmed["candidates"][0]["effect"] = "actuation_lag"
    assert other_side(typed(lag, "actuator"), typed(harmed, "body"), "link") is None


def test_a_drive_line_kept_on_the_actuator_link_stays_off_the_body_link(lab):
    """Behind a link-side sensor a drive's friction is fitted on both links; '- asymmetric_friction: actuator' keeps
    it on the actuator link: the body link neither fits nor tries it, the calibrated joint holds the actuator link's
    value, and ladder.json says so. Runs that cannot fit it there are refused, naming model.yaml's line."""
    from sim2real.errors import InputError
    from sim2real.identification.documents import params_document
    from sim2real.identification.sysid import fit_model

    from sysid_lab import WORKERS

    effects = ["link_inertia", "asymmetric_friction"]
    kept = model_config(effects, kept_on={"asymmetric_friction": "actuator"})
    fitted = fit_model(kept, lab.nominal, lab.prepared(lab.measurement_list("link_side_sensor")), lab.robot,
                       workers=WORKERS)
    document, results = fitted.document, fitted.results
    assert document["ladder"][-1]["effects"] == ["link_inertia"]
    assert document["actuator"]["ladder"][-1]["effects"] == ["asymmetric_friction"]
    assert document["links"]["kept_on"] == {"asymmetric_friction": "actuator"}
    tried = {c["effect"] for c in document["diagnosis"]["candidates"]}
    skipped = {s["effect"] for s in document["diagnosis"].get("skipped", [])}
    assert "asymmetric_friction" not in tried | skipped and "coulomb_friction" in tried | skipped
    params = params_document(results, lab.nominal, document["torque_source"], lab.robot)
    assert params["effects"]["asymmetric_friction"] == document["actuator"]["ladder"][-1]["params"]["asymmetric_friction"]
    assert "asymmetric_friction" not in params.get("by_link", {})
    both = lab.model("link_side_sensor", effects)  # without the line's link: on both
    assert both["ladder"][-1]["effects"] == effects

    with pytest.raises(InputError, match=r"model\.yaml.*asymmetric_friction: actuator.*motor-side"):
        fit_model(kept, lab.nominal, lab.prepared(lab.measurement_list("real_arm_like")), lab.robot)
    with pytest.raises(InputError, match="fit one side only"):
        fit_model(kept, lab.nominal, lab.prepared(lab.without_sensor("link_side_sensor")), lab.robot)


def test_a_line_the_other_link_holds_in_a_kept_line_is_kept_on_the_link_that_names_it():
    """With '- asymmetric_friction: actuator', the body link may name coulomb_friction (the part after the sensor).
    Added as it is, it would also sit on the actuator link beside asymmetric_friction, its more general shape, which
    that link's diagnosis never proposes: the verdict says to write it kept on the body link. Where the other link
    does not hold it, or the line is no drive's, nothing is said."""
    import copy
    import json
    from pathlib import Path

    from sim2real.identification.diagnosis.across import held_on_other_side
    from sim2real.identification.records import Side
    from sim2real.report.verdicts import verdict

    data = json.loads((Path(__file__).parent / "data" / "real_panda_log_round8_diagnoses.json").read_text())
    named = copy.deepcopy(data["actuator"])  # a verdict of the loop's own, its top candidate made coulomb_friction
    named["candidates"][0]["effect"] = "coulomb_friction"
    body = typed(named, "body")
    note = held_on_other_side(body, ["coulomb_friction", "asymmetric_friction"], Side.DRIVE, "link")
    assert note_text(note) == ("The actuator link holds it already (asymmetric_friction, kept there, a more general "
                               "shape of it): write the line as '- coulomb_friction: body', so that it is not fitted "
                               "there beside asymmetric_friction.")
    assert verdict(body.with_notes(note), "panda") == verdict(body, "panda") + " " + note_text(note)

    for other_effects, sensor in ((["coulomb_friction", "rotor_inertia"], "link"),  # not held there
                                  (["asymmetric_friction"], "motor")):  # behind a motor-side sensor: not fitted there
        assert held_on_other_side(body, other_effects, Side.DRIVE, sensor) is None
