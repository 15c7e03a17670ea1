"""The model the loop ends with can be trusted (issue 30, "Done when"), followed from an empty ``effects:``.

Lab arms that differ from their URDF the way real ones do (CAD inertias off, a heavier hand, a wrong armature,
Gaz friction with Stribeck humps, noise, jitter): ``real_arm_like`` (motor-side sensor; followed by
tests/test_consistent_fit.py), ``link_side_sensor``
(after the gearbox, part of the friction after the sensor) and ``sensor_gains`` (each joint's torque sensor a few
percent off, beside the CAD errors; on runs of the demo's 20 s). A user follows every verdict
(:meth:`sysid_lab.Lab.follow`, fast settings, rounds read earlier rungs back as the rule does); at the last rung
of every link: every joint within 1.5x its own floor, no inertia flagged implausible, and the inertial prior's
weight chosen inside its searched range, on every rung.
"""

from __future__ import annotations

import pytest

import sysid_lab
from sysid_lab import Lab

FACTOR = 1.5


@pytest.fixture(scope="module")
def lab(shared_lab: Lab) -> Lab:
    """The suite's lab (conftest): runs made once, scenarios followed once."""
    return shared_lab


@pytest.fixture(scope="module")
def long_lab(tmp_path_factory, monkeypatch_module) -> Lab:
    """Runs of the demo's length (20 s): per-joint sensor gains a few percent off beside bent CAD inertias need
    them; on 8 s runs joint 2 ends at 1.56x its floor, its last excess a slow error the time test sees."""
    monkeypatch_module.setattr(sysid_lab, "LAB_DURATION_S", 20.0)
    return Lab(tmp_path_factory.mktemp("trustworthy_long_lab"))


@pytest.fixture(scope="module")
def monkeypatch_module():
    with pytest.MonkeyPatch.context() as patch:
        yield patch


# real_arm_like, the demo's arm, is followed to the same end by tests/test_consistent_fit.py (its body link; its
# actuator link sits at its floor throughout).
@pytest.mark.parametrize("scenario", ["link_side_sensor", "sensor_gains"])
def test_the_loop_ends_at_the_floor_with_plausible_inertias(request, scenario):
    lab = request.getfixturevalue("long_lab" if scenario == "sensor_gains" else "lab")
    documents = lab.follow(scenario)
    last = documents[-1]
    assert len(documents) > 2, "the loop added effects round after round"
    for name, section in (("body", last), ("actuator", last.get("actuator"))):
        if not section:
            continue
        assert section["diagnosis"]["status"] == "at_noise_floor", (name, section["diagnosis"]["verdict"])
        rung = section["ladder"][-1]
        x_floor = rung["metrics"]["torque_x_floor"]["per_joint"]
        assert all(x <= FACTOR for x in x_floor.values()), (name, x_floor)
        link = (rung.get("params") or {}).get("link_inertia")
        if link:
            assert not link["implausible_bodies"], (name, {b: link["bodies"][b]["implausible"]
                                                           for b in link["implausible_bodies"]})
    for document in documents:
        for rung in document["ladder"]:
            prior = (rung.get("consistency") or {}).get("inertia_prior")
            if prior and "grid" in prior:
                assert prior["inside_searched_range"], (rung["effects"], prior["grid"], prior["scores"])


def test_a_textbook_friction_declared_up_front_is_completed_not_papered_over(lab):
    """A user who starts from the textbook model (link inertias, Coulomb and viscous friction) on the demo's arm, whose
    friction is Gaz's slow sigmoid with Stribeck humps. The diagnosis tries asymmetric_friction on top of it; its
    refinement, with amplitudes free to go negative, settled where the sigmoid fitted only as a negative correction,
    which the consistent fit clipped to nothing: the loop then added a torque bias and a sensor drift, neither of which
    this arm has, to reach the floor. Refined as the consistent fit delivers it (amplitudes at or above zero), the
    sigmoid takes the slow transition, and the loop ends at the floor with effects the arm has."""
    documents = lab.follow("real_arm_like", start=["link_inertia", "coulomb_friction", "viscous_friction"])
    last = documents[-1]
    effects = last["ladder"][-1]["effects"]
    assert "asymmetric_friction" in effects, [d["diagnosis"]["verdict"] for d in documents]
    assert not {"torque_bias", "sensor_drift"} & set(effects), effects
    assert last["diagnosis"]["status"] == "at_noise_floor", last["diagnosis"]["verdict"]
    assert all(x <= FACTOR for x in last["ladder"][-1]["metrics"]["torque_x_floor"]["per_joint"].values())
    assert not last["ladder"][-1]["params"]["link_inertia"]["implausible_bodies"]


def test_a_hysteretic_friction_is_named_and_its_rung_reaches_the_floor(lab):
    """Dahl friction in the drives (the lab's ``hysteresis``): no static law follows it around reversals; the
    diagnosis names hysteretic_friction, and the loop that adds it ends with every joint within 1.5x its floor."""
    documents = lab.follow("hysteresis")
    named = [d["diagnosis"]["candidates"][0]["effect"] for d in documents if d["diagnosis"]["status"] == "add_effect"]
    assert "hysteretic_friction" in named, [d["diagnosis"]["verdict"] for d in documents]
    last = documents[-1]
    assert "hysteretic_friction" in last["ladder"][-1]["effects"]
    assert last["diagnosis"]["status"] == "at_noise_floor", last["diagnosis"]["verdict"]
    assert all(x <= FACTOR for x in last["ladder"][-1]["metrics"]["torque_x_floor"]["per_joint"].values())


def test_a_small_cogging_beside_everything_else_is_named_with_its_periods_and_the_loop_reaches_the_floor(long_lab):
    """The demo's arm with a cogging in two drives, a few percent of their friction (the lab's
    ``real_arm_like_cogging``: 0.12 N m every 0.09 rad on joint 2, 0.06 N m every 0.157 rad on joint 6): the loop
    names the demo's effects first (what is larger), then position_ripple on those two joints, and ends at the floor.
    The periods are found to 1 %; joint 2's amplitude comes out low (0.107): at over 0.9 rad/s it passes its ripple
    faster than the 10 Hz position filter's cutoff, and part of the ripple's torque goes into an acceleration the
    filter removes (with a 40 Hz cutoff it comes out 0.123)."""
    documents = long_lab.follow("real_arm_like_cogging")
    tops = [d["diagnosis"]["candidates"][0] for d in documents if d["diagnosis"]["status"] == "add_effect"]
    ripple = [top for top in tops if top["effect"] == "position_ripple"]
    assert ripple and set(ripple[0]["joints"]) == {"panda_joint2", "panda_joint6"}, [t["effect"] for t in tops]
    last = documents[-1]
    assert last["diagnosis"]["status"] == "at_noise_floor", last["diagnosis"]["verdict"]
    assert all(x <= FACTOR for x in last["ladder"][-1]["metrics"]["torque_x_floor"]["per_joint"].values())
    fitted = last["ladder"][-1]["params"]["position_ripple"]
    assert fitted["period"]["panda_joint2"] == pytest.approx(0.09, rel=0.01)
    assert fitted["period"]["panda_joint6"] == pytest.approx(0.157, rel=0.01)
    assert fitted["amplitude"]["panda_joint6"] == pytest.approx(0.06, rel=0.1)
    assert 0.08 < fitted["amplitude"]["panda_joint2"] <= 0.12


def test_an_effect_that_holds_a_line_of_the_model_replaces_it_and_the_loop_reaches_the_floor(long_lab):
    """Dahl friction and a payload on 20 s runs: the nominal model's verdict names the payload (a heavier hand explains
    most with few parameters), then hysteretic_friction; the link inertias, named next, hold a payload (a special
    case of the last link's inertia), so the verdict says to remove its line, and the trial fitted the model without
    it. Kept beside them, the two fitted the same torque twice: the fits with the rotor inertia went singular (the
    unconstrained one 1e11 N m), and the loop ended "unexplained" at 1.2-2.2x with two links implausible and a torque
    gain named on an arm whose sensors are exact."""
    documents = long_lab.follow("hysteresis")
    tops = [d["diagnosis"]["candidates"][0] for d in documents if d["diagnosis"]["status"] == "add_effect"]
    replacing = [top for top in tops if top.get("replaces")]
    assert [(top["effect"], top["replaces"]) for top in replacing] == [("link_inertia", ["payload"])], tops
    # the payload's term is the link inertias' now by design, no trade: what they add beyond it is their own
    assert not replacing[0]["evidence"].get("trades_with"), replacing[0]["evidence"]["trades_with"]
    named = next(k for k, d in enumerate(documents)
                 if d["diagnosis"]["status"] == "add_effect" and d["diagnosis"]["candidates"][0].get("replaces"))
    verdict = documents[named]["diagnosis"]["verdict"]
    assert "Add the line '- link_inertia'" in verdict and "and remove '- payload': link_inertia holds payload" in verdict
    last = documents[-1]
    effects = last["ladder"][-1]["effects"]
    assert "payload" not in effects and {"link_inertia", "hysteretic_friction"} <= set(effects), effects
    assert last["diagnosis"]["status"] == "at_noise_floor", last["diagnosis"]["verdict"]
    assert all(x <= FACTOR for x in last["ladder"][-1]["metrics"]["torque_x_floor"]["per_joint"].values())
    assert not last["ladder"][-1]["params"]["link_inertia"]["implausible_bodies"]
    # the rung after the replacement delivers what its trial promised (the same model, fitted as its rung is)
    promised = documents[named]["diagnosis"]["candidates"][0]["evidence"]["x_floor_after"]
    delivered = documents[named + 1]["ladder"][-1]["metrics"]["torque_x_floor"]["overall"]
    assert delivered <= promised * 1.05, (promised, delivered)


def test_a_warm_up_drift_is_said_to_be_the_sensors_and_declared_the_loop_reaches_the_floor(lab):
    """Torque sensors that warm up anew in every run (the lab's ``drift``): once nothing of the library is decisive,
    the verdict says the rest drifts with time within each run or sits at each run's own offset, not a function of
    the motion, and advises the line that estimates each run's drift on the run itself. The user adds it
    (:meth:`sysid_lab.Lab.follow`); the effects the drift hid (the rotor inertia) are then named, and both links end
    within 1.5x their floor, every inertia plausible."""
    documents = lab.follow("drift")
    declared = next(k for k, d in enumerate(documents) if "sensor_drift" in d["ladder"][-1]["effects"])
    before = documents[declared - 1]["diagnosis"]
    assert before["status"] == "unexplained", before["verdict"]
    ceiling = before["model_free"]
    assert set(ceiling["torque_rmse"]["per_joint"]) == set(documents[0]["joints"])
    drifting = [j for j, row in ceiling["per_joint"].items() if row["kind"] == "not_motion" and row["follows"] == "time"]
    above = [j for j, row in ceiling["per_joint"].items() if row["kind"] != "at_floor"]
    assert len(drifting) >= len(above) / 2, ceiling["per_joint"]
    assert "No function of the motion explains the rest" in before["verdict"]
    assert "drifts with time within each run" in before["verdict"]
    assert ceiling["declare"]["effect"] == "sensor_drift" and set(drifting) <= set(ceiling["declare"]["joints"])
    assert "add the line '- sensor_drift' under 'effects:' in configs/panda/model.yaml" in before["verdict"]

    last = documents[-1]
    assert "rotor_inertia" in last["ladder"][-1]["effects"], "an effect the drift hid, named once it is declared"
    assert "rotor_inertia" not in documents[declared]["ladder"][-1]["effects"]
    for section in (last, last.get("actuator")):
        assert section is not None and section["diagnosis"]["status"] == "at_noise_floor", section["diagnosis"]["verdict"]
        assert "sensor_drift" in section["ladder"][-1]["effects"], "declared, it sits in every link's model"
        x_floor = section["ladder"][-1]["metrics"]["torque_x_floor"]["per_joint"]
        assert all(x <= FACTOR for x in x_floor.values()), x_floor
    assert not last["ladder"][-1]["params"]["link_inertia"]["implausible_bodies"]
    assert "declare" not in last["diagnosis"]["model_free"]


def test_a_cogging_ripple_is_named_with_its_period_and_its_rung_reaches_the_floor(lab):
    """A position ripple on panda_joint4 (the lab's ``ripple``: 0.3 N m with a period of 0.2 rad, no whole fraction
    of a turn, so no integer harmonic fits it beyond the positions the fit run visits): the diagnosis names
    position_ripple on that joint, the refinement's search finds its period, and the loop that adds it ends with
    every joint within 1.5x its floor. Before the library had it the verdict ended "unexplained", joint 4's
    excess called noise the floor misses."""
    documents = lab.follow("ripple")
    named = [d["diagnosis"]["candidates"][0] for d in documents if d["diagnosis"]["status"] == "add_effect"]
    ripple = [c for c in named if c["effect"] == "position_ripple"]
    assert ripple and ripple[0]["joints"] == ["panda_joint4"], [d["diagnosis"]["verdict"] for d in documents]
    last = documents[-1]
    assert "position_ripple" in last["ladder"][-1]["effects"]
    assert last["diagnosis"]["status"] == "at_noise_floor", last["diagnosis"]["verdict"]
    assert all(x <= FACTOR for x in last["ladder"][-1]["metrics"]["torque_x_floor"]["per_joint"].values())
    fitted = last["ladder"][-1]["params"]["position_ripple"]
    assert fitted["period"]["panda_joint4"] == pytest.approx(0.2, rel=0.01)
    assert fitted["amplitude"]["panda_joint4"] == pytest.approx(0.3, rel=0.1)
    assert max(v for j, v in fitted["amplitude"].items() if j != "panda_joint4") < 0.1  # the others carry none
    # where no joint is above its floor the ripple costs no trial: the actuator link
    skipped = {s["effect"]: s["reason"] for s in documents[0]["actuator"]["diagnosis"]["skipped"]}
    assert "no joint's ripple to search for" in skipped["position_ripple"], skipped
