"""The loop on arms like real ones, joint by joint (issue 18).

A real arm differs from its URDF in every way at once, and its wrist torques are ten times smaller
than its shoulder's. The lab's ``real_arm_like`` (motor-side sensor) and ``link_side_sensor`` (after
the gearbox, like the Panda's tau_J, with part of the friction after the sensor) hide all of it; a user
starts from an empty ``effects:`` and adds what each verdict asks. Every joint must end within 1.5x its
own noise floor, or the report must say, joint by joint, why not. The diagnosis sees only runs.
"""

from __future__ import annotations

import pytest

from sysid_lab import Lab

FACTOR = 1.5


@pytest.fixture(scope="module")
def lab(tmp_path_factory) -> Lab:
    return Lab(tmp_path_factory.mktemp("real_arm_lab"))


def follow(lab: Lab, scenario: str, rounds: int = 7) -> list[dict]:
    """The user's loop over every link the runs have: each round adds what each verdict asks."""
    effects: list[str] = []
    documents = [lab.model(scenario, effects)]
    for _ in range(rounds):
        sections = [documents[-1], documents[-1].get("actuator") or {}]
        wanted = [s["diagnosis"]["candidates"][0]["effect"] for s in sections
                  if s and s["diagnosis"]["status"] == "add_effect"]
        wanted = [w for w in dict.fromkeys(wanted) if w not in effects]
        if not wanted:
            break
        effects += wanted
        documents.append(lab.model(scenario, effects))
    return documents


def sections(document: dict) -> list[dict]:
    return [s for s in (document, document.get("actuator")) if s]


@pytest.mark.parametrize("scenario", ["real_arm_like", "link_side_sensor"])
def test_from_an_empty_model_every_joint_ends_within_its_own_floor(lab, scenario):
    documents = follow(lab, scenario)
    last = documents[-1]
    for section in sections(last):
        x_floor = section["ladder"][-1]["metrics"]["torque_x_floor"]["per_joint"]
        diagnosis = section["diagnosis"]
        above = {j: x for j, x in x_floor.items() if x > FACTOR}
        # Every joint at its floor, and the report says so; where one is not, the report names it and why.
        assert set(diagnosis["above_floor"]) == set(above), (diagnosis["above_floor"], x_floor)
        assert not above, (scenario, section["ladder"][-1]["effects"], x_floor, diagnosis["verdict"])
        assert diagnosis["status"] == "at_noise_floor", diagnosis["verdict"]
        overall = [rung["metrics"]["torque_x_floor"]["overall"] for rung in section["ladder"]]
        assert overall[-1] < overall[0] or overall[0] <= FACTOR, overall


def test_a_friction_hidden_on_the_wrist_alone_is_named_on_that_joint(lab):
    """Joint 7's torques are ten times smaller than the shoulder's: arm-wide in N*m it never decides."""
    documents = follow(lab, "wrist_friction")
    named = [(c["effect"], c["joints"]) for document in documents for section in sections(document)
             for c in section["diagnosis"]["candidates"][:1]
             if section["diagnosis"]["status"] == "add_effect" and "friction" in c["effect"]]
    assert named, [s["diagnosis"]["verdict"] for d in documents for s in sections(d)]
    effect, joints = named[0]
    assert "panda_joint7" in joints, named
    assert set(joints) <= {"panda_joint6", "panda_joint7"}, named  # not smeared over the arm


def test_link_side_torque_that_holds_friction_gets_friction_named(lab):
    """A real Panda log: tau_J only (no commands), link-side, friction in it. The sensor's position words the
    report; it does not stop friction from being tried and named on the body link."""
    documents = follow(lab, "link_side_tau_only")
    assert documents[0]["links"]["torque_sensor"] == "link"
    verdicts = [d["diagnosis"] for d in documents if d["diagnosis"]["status"] == "add_effect"]
    friction = [v for v in verdicts if "friction" in v["candidates"][0]["effect"]]
    assert friction, [v["verdict"] for v in verdicts]
    assert "after it" in friction[0]["verdict"]  # what friction means behind this sensor
    last = documents[-1]
    assert any("friction" in e for e in last["ladder"][-1]["effects"])
    assert last["diagnosis"]["status"] == "at_noise_floor", last["diagnosis"]["verdict"]
